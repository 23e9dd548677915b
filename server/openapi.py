"""The OpenAPI document says every answer the API can give.

Routes declare what is special to them (`NOT_FOUND`, `CONFLICT`, `GONE`,
`BUSY`, ...); `install` adds what follows from a route's shape, so that no
route can forget it: an operator route may answer 401, 403 and 429 and
carries the bearer security requirement; a route with a body may answer 400 (a
body that is not UTF-8 JSON) and 413;
a route with a path parameter may answer 404; every route may answer
429 (too many requests of one address at once, `server.guard`) and, but
the health checks, 503 (the database cannot be used now, `server.errors`). Every error
has the one shape of `server.errors`.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

from fastapi import FastAPI
from fastapi.openapi.utils import get_openapi
from fastapi.routing import APIRoute
from pydantic import BaseModel


class ErrorDetail(BaseModel):
    code: str
    message: str
    detail: Any = None


class ErrorResponse(BaseModel):
    """Every error of the API: ``{"error": {"code": ..., "message": ..., "detail": ...}}``."""

    error: ErrorDetail


def _error(status: int, description: str) -> dict[int | str, dict[str, Any]]:
    return {status: {"model": ErrorResponse, "description": description}}


NOT_FOUND = _error(404, "No such thing (the message names it)")
CONFLICT = _error(409, "In conflict with the current state (e.g. a schedule version not newer)")
GONE = _error(410, "The frame's file is no longer in the data folder (removed by retention)")
UNREADABLE = _error(422, "The request is invalid, or the stored file is not the image it claims to be")
BUSY = _error(
    503, "At the bound for this kind of work (exports, queued re-analyses, previews): see Retry-After"
)

_GENERIC = {
    "400": "The request body is not UTF-8 (code not_utf8) or cannot be read as JSON (code bad_body)",
    "401": "No operator token: send 'Authorization: Bearer <token>'",
    "403": "The operator token is not valid",
    "413": "The request body is over the route's limit (1 MiB unless the route says otherwise)",
    "429": "Too many requests of this address at once, or too many wrong tokens: see Retry-After",
    "404": "No such thing (the message names it)",
    "503": "The database cannot be used now (code database_unavailable; the message says what to do): "
    "see Retry-After",
}
#: Routes that answer without the database (`/api/health` says its state in its body).
_NO_DATABASE = {"/healthz", "/api/health"}


def api_routes(routes: Any, prefix: str = "") -> Iterator[tuple[APIRoute, str]]:
    """Every API route of an app with its full path, included routers walked into."""
    for r in routes:
        inner = getattr(r, "original_router", None)
        if inner is not None:
            yield from api_routes(inner.routes, prefix + inner.prefix)
        elif isinstance(r, APIRoute):
            yield r, prefix + r.path


def _add(op: dict[str, Any], status: str) -> None:
    responses = op.setdefault("responses", {})
    if status not in responses:
        responses[status] = {
            "description": _GENERIC[status],
            "content": {"application/json": {"schema": {"$ref": "#/components/schemas/ErrorResponse"}}},
        }


def install(app: FastAPI) -> None:
    """Make ``app.openapi()`` document the answers every route can give (see the module docstring)."""
    from server.deps import needs_operator

    def openapi() -> dict[str, Any]:
        if app.openapi_schema:
            return app.openapi_schema
        schema = get_openapi(
            title=app.title, version=app.version, description=app.description, routes=app.routes
        )
        schema.setdefault("components", {}).setdefault("schemas", {})["ErrorResponse"] = (
            ErrorResponse.model_json_schema(ref_template="#/components/schemas/{model}")
        )
        for name, sub in (
            ErrorResponse.model_json_schema(ref_template="#/components/schemas/{model}")
            .get("$defs", {})
            .items()
        ):
            schema["components"]["schemas"].setdefault(name, sub)
        schema["components"]["schemas"]["ErrorResponse"].pop("$defs", None)
        for route, path in api_routes(app.routes):
            if not route.include_in_schema:
                continue
            for method in route.methods or ():
                op = schema["paths"].get(path, {}).get(method.lower())
                if op is None:
                    continue
                _add(op, "429")
                if path not in _NO_DATABASE:
                    _add(op, "503")
                    if "database_unavailable" not in op["responses"]["503"]["description"]:
                        op["responses"]["503"]["description"] += f"; or: {_GENERIC['503']}"
                # a path's id, or a dive or run named in the query (`queries.dive_and_run`), may not exist
                if route.dependant.path_params or {q.name for q in route.dependant.query_params} & {
                    "dive",
                    "run",
                }:
                    _add(op, "404")
                if route.dependant.body_params:
                    _add(op, "400")
                    _add(op, "413")
                if needs_operator(route):
                    for status in ("401", "403"):
                        _add(op, status)
        app.openapi_schema = schema
        return schema

    app.openapi = openapi  # type: ignore[method-assign]
