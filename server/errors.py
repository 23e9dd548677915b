"""One JSON error shape for every failure of the API.

    {"error": {"code": "not_found", "message": "no frame 12", "detail": {...}}}

Typed domain exceptions are raised in routes; one set of handlers turns them
(and FastAPI's own validation and HTTP errors) into that shape.
"""

from __future__ import annotations

import logging
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from storage.db import database_unavailable
from storage.queries import RunLookupError

log = logging.getLogger("camcal.server")


class ApiError(Exception):
    """An error with an HTTP status, a stable code and a message a person can act on."""

    status = 400
    code = "bad_request"

    def __init__(self, message: str, detail: Any = None) -> None:
        super().__init__(message)
        self.message = message
        self.detail = detail


class NotFound(ApiError):
    status, code = 404, "not_found"


class Unauthorized(ApiError):
    status, code = 401, "unauthorized"


class Forbidden(ApiError):
    status, code = 403, "forbidden"


class Conflict(ApiError):
    status, code = 409, "conflict"


class Invalid(ApiError):
    status, code = 422, "invalid"


class Gone(ApiError):
    """A stored thing whose file is no longer there (removed by retention, or never readable)."""

    status, code = 410, "gone"


class Unreadable(ApiError):
    """A stored file that cannot be decoded as what it claims to be."""

    status, code = 422, "unreadable"


class Unavailable(ApiError):
    status, code = 503, "unavailable"


def error_body(code: str, message: str, detail: Any = None) -> dict[str, Any]:
    return {"error": {"code": code, "message": message, "detail": detail}}


def _reason(error: Any) -> str:
    """A validation error's message for a person: without pydantic's "Value error, " and, for a value
    of the wrong type, naming the value given ("... as a number (got 'abc')")."""
    msg = str(error.get("msg", ""))
    for prefix in ("Value error, ", "Assertion failed, "):
        msg = msg.removeprefix(prefix)
    given = error.get("input")
    if str(error.get("type", "")).endswith(("_parsing", "_type")) and isinstance(given, str | int | float):
        shown = repr(given) if len(repr(given)) <= 40 else repr(given)[:37] + "..."
        msg = f"{msg} (got {shown})"
    return msg


def body_error(exc: StarletteHTTPException) -> tuple[str, str] | None:
    """(code, message) for FastAPI's 400 "There was an error parsing the body", by its cause: a
    body that is not UTF-8 (``not_utf8``; JSON is UTF-8, RFC 8259) or not readable (``bad_body``)."""
    if exc.status_code != 400:
        return None
    cause = exc.__cause__
    if isinstance(cause, UnicodeDecodeError):
        bad = cause.object[cause.start : cause.start + 1]
        return "not_utf8", f"the request body is not UTF-8 (byte {cause.start}: {bad!r}): send JSON in UTF-8"
    if cause is not None:
        return "bad_body", f"the request body cannot be read as JSON ({type(cause).__name__}): send JSON"
    return None


def install(app: FastAPI) -> None:
    """Register the handlers that give every error the one shape."""

    @app.exception_handler(ApiError)
    async def api_error(_: Request, exc: ApiError) -> JSONResponse:
        headers = getattr(exc, "headers", None)
        if not headers and exc.status == 401:
            headers = {"WWW-Authenticate": "Bearer"}
        return JSONResponse(
            error_body(exc.code, exc.message, exc.detail), status_code=exc.status, headers=headers
        )

    @app.exception_handler(RunLookupError)
    async def lookup_error(_: Request, exc: RunLookupError) -> JSONResponse:
        return JSONResponse(error_body("not_found", str(exc)), status_code=404)

    @app.exception_handler(RequestValidationError)
    async def validation_error(_: Request, exc: RequestValidationError) -> JSONResponse:
        problems = [
            {"field": ".".join(str(p) for p in e.get("loc", ()) if p != "body"), "reason": _reason(e)}
            for e in exc.errors()
        ]
        first = problems[0] if problems else {"field": "", "reason": "invalid request"}
        message = f"{first['field']}: {first['reason']}" if first["field"] else first["reason"]
        return JSONResponse(error_body("invalid", message, problems), status_code=422)

    @app.exception_handler(StarletteHTTPException)
    async def http_error(_: Request, exc: StarletteHTTPException) -> JSONResponse:
        unreadable = body_error(exc)
        if unreadable is not None:
            return JSONResponse(error_body(*unreadable), status_code=400)
        codes = {404: "not_found", 405: "method_not_allowed", 413: "too_large"}
        code = codes.get(exc.status_code, "http_error")
        return JSONResponse(
            error_body(code, str(exc.detail)),
            status_code=exc.status_code,
            headers=getattr(exc, "headers", None),
        )

    @app.exception_handler(Exception)
    async def unexpected(_: Request, exc: Exception) -> JSONResponse:
        message = database_unavailable(exc)
        if message is not None:  # the database, not the request: 503, and what to do
            log.warning("database unavailable: %s", message)
            return JSONResponse(
                error_body("database_unavailable", message), status_code=503, headers={"Retry-After": "5"}
            )
        log.exception("unexpected error")
        return JSONResponse(
            error_body("internal", "internal error; the server log has the details"), status_code=500
        )
