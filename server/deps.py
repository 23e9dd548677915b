"""Dependencies of the routes, as ``Annotated`` aliases (swapped in tests via dependency_overrides)."""

from __future__ import annotations

import hmac
from typing import Annotated

from fastapi import Depends, Header, Path, Query, Request

from server.errors import Forbidden, Unauthorized
from server.relay import LiveHub
from server.settings import ServerSettings
from storage.store import Store


def get_settings(request: Request) -> ServerSettings:
    return request.app.state.settings


def get_store(request: Request) -> Store:
    return request.app.state.store


def get_hub(request: Request) -> LiveHub:
    return request.app.state.hub


SettingsDep = Annotated[ServerSettings, Depends(get_settings)]
StoreDep = Annotated[Store, Depends(get_store)]
HubDep = Annotated[LiveHub, Depends(get_hub)]


def operator(settings: SettingsDep, authorization: Annotated[str | None, Header()] = None) -> str:
    """The operator named by a ``Bearer`` token; 401 without one, 403 with a wrong one.

    Tokens are compared in constant time (`hmac.compare_digest`), each one
    against every configured token, so timing reveals nothing about them.
    """
    if not authorization or not authorization.lower().startswith("bearer "):
        raise Unauthorized("this action needs an operator token: send 'Authorization: Bearer <token>'")
    given = authorization[7:].strip().encode()
    who = None
    for name, token in settings.operator_tokens.items():
        if hmac.compare_digest(given, token.encode()):
            who = name
    if who is None:
        if not settings.operator_tokens:
            raise Forbidden("no operator tokens are configured on this server (set CAMCAL_OPERATOR_TOKENS)")
        raise Forbidden("the operator token is not valid")
    return who


OperatorDep = Annotated[str, Depends(operator)]


# Parameter types with bounds: what the database can take, so no input can make a query fail.
MAX_ID = 2**62
IdPath = Annotated[int, Path(ge=0, le=MAX_ID)]
IdQuery = Annotated[int | None, Query(ge=0, le=MAX_ID)]
FloatQuery = Annotated[float | None, Query(ge=-1e12, le=1e12, allow_inf_nan=False)]
WavelengthQuery = Annotated[int | None, Query(ge=1, le=100_000)]
