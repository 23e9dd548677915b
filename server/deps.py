"""Dependencies of the routes, as ``Annotated`` aliases (swapped in tests via dependency_overrides)."""

from __future__ import annotations

import hmac
from collections.abc import Iterator
from typing import Annotated, Any

from fastapi import Depends, Path, Query, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from camcal.core.wire.models import ID_PATTERN
from server.errors import ApiError
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


class TokenRefused(ApiError):
    """A request refused for its operator token: 401 (none), 403 (wrong) or 429 (too many wrong)."""

    def __init__(self, status: int, code: str, message: str, headers: dict[str, str] | None = None) -> None:
        super().__init__(message)
        self.status, self.code = status, code
        self.headers = headers or {}


def check_token(
    settings: ServerSettings, throttle: Any, client: str, authorization: bytes | str | None
) -> str:
    """The operator named by a ``Bearer`` token, or `TokenRefused`.

    Tokens are compared in constant time (`hmac.compare_digest`), each one
    against every configured token, so timing reveals nothing about them. An
    address that sent too many wrong tokens is refused (429) before its
    token is even looked at.
    """
    wait = throttle.retry_after_s(client)
    if wait is not None:
        raise TokenRefused(
            429,
            "too_many_failures",
            f"too many wrong operator tokens from this address: try again in {wait:.0f} s",
            {"Retry-After": str(int(wait + 0.999))},
        )
    if isinstance(authorization, bytes):
        authorization = authorization.decode("latin-1")
    if not authorization or not authorization.lower().startswith("bearer "):
        raise TokenRefused(
            401,
            "unauthorized",
            "this action needs an operator token: send 'Authorization: Bearer <token>'",
            {"WWW-Authenticate": "Bearer"},
        )
    given = authorization[7:].strip().encode()
    who = None
    for name, token in settings.operator_tokens.items():
        if hmac.compare_digest(given, token.encode()):
            who = name
    if who is None:
        throttle.failed(client)
        if not settings.operator_tokens:
            raise TokenRefused(
                403,
                "forbidden",
                "no operator tokens are configured on this server (set CAMCAL_OPERATOR_TOKENS)",
            )
        raise TokenRefused(403, "forbidden", "the operator token is not valid")
    return who


_bearer = HTTPBearer(auto_error=False, description="An operator token (CAMCAL_OPERATOR_TOKENS)")


def operator(
    request: Request,
    settings: SettingsDep,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)] = None,
) -> str:
    """The operator named by a ``Bearer`` token; 401 without one, 403 with a wrong one, 429 after
    too many wrong ones (`check_token`)."""
    client = request.client.host if request.client else "unknown"
    header = f"Bearer {credentials.credentials}" if credentials else request.headers.get("authorization")
    return check_token(settings, request.app.state.throttle, client, header)


OperatorDep = Annotated[str, Depends(operator)]


def preview_slot(request: Request, settings: SettingsDep) -> Iterator[None]:
    """A slot to compute a schedule's preview in (`server.jobs.PreviewSlots`; 503 when none is
    free): an operator's own when the request carries a valid token. A wrong token is counted as
    on any route (`check_token`) and gets an anonymous slot."""
    client = request.client.host if request.client else "unknown"
    is_operator = False
    if request.headers.get("authorization"):
        try:
            check_token(settings, request.app.state.throttle, client, request.headers["authorization"])
            is_operator = True
        except TokenRefused:
            pass
    with request.app.state.previews.slot(is_operator):
        yield


PreviewSlotDep = Annotated[None, Depends(preview_slot)]


def needs_operator(route: Any) -> bool:
    """Whether a route depends on `operator` (it changes something and needs a token)."""

    def walk(dependant: Any) -> bool:
        return any(d.call is operator or walk(d) for d in dependant.dependencies)

    return walk(route.dependant)


# Parameter types with bounds: what the database can take, so no input can make a query fail.
MAX_ID = 2**62
IdPath = Annotated[int, Path(ge=0, le=MAX_ID)]
IdQuery = Annotated[int | None, Query(ge=0, le=MAX_ID)]
FloatQuery = Annotated[float | None, Query(ge=-1e12, le=1e12, allow_inf_nan=False)]
WavelengthQuery = Annotated[int | None, Query(ge=1, le=100_000)]
#: A module id in a path: what the wire allows (1-64 letters, digits, _ . -, not only dots).
ModuleId = Annotated[str, Path(min_length=1, max_length=64, pattern=ID_PATTERN)]
