"""The server's outer wall: one ASGI middleware that every request and WebSocket passes first.

Before a route sees a request, `Guard`:

* **adds the security headers** to every response (pages, API, errors,
  static files): a strict Content-Security-Policy (everything from this
  origin only, no inline scripts, no framing), ``nosniff``,
  ``X-Frame-Options: DENY`` and ``Referrer-Policy: no-referrer``;
* **bounds the body**: a ``Content-Length`` over the route's limit (1 MiB by
  default; a route may raise it with ``openapi_extra={"x-max-body-bytes":
  N}``) is answered 413 at once, before a byte of the body is read; a
  chunked body is counted as it arrives and cut off at the limit;
* **checks the operator token first** on routes that need one: a request
  without a token (401) or with a wrong one (403) is answered before its
  body is read, and an address that sent too many wrong tokens is held off
  (429, `TokenThrottle`);
* **caps the requests of one client** in flight at once (429);
* **knows the client**: the peer's address, or, when the peer is one of the
  configured reverse proxies (``trusted_proxies``), the address the proxies
  put in ``X-Forwarded-For`` (`TrustedProxies`). Every limit per address
  (wrong tokens, requests and WebSockets at once) counts that address, and
  an ``X-Forwarded-For`` from anyone else is ignored: a client that rotates
  it is still one client;
* **keeps answers out of caches**: an API answer (``/api/...``) or any JSON
  without a ``Cache-Control`` of its own gets ``Cache-Control: no-store``
  (no browser, proxy or shared tablet keeps an operator's data).

Everything it refuses has the API's one error shape (`server.errors`).
"""

from __future__ import annotations

import ipaddress
import json
import re
import time
from collections import OrderedDict, deque
from collections.abc import Awaitable, Callable, Iterable, MutableMapping
from dataclasses import dataclass
from typing import Any

from starlette.exceptions import HTTPException as StarletteHTTPException

from server.errors import error_body

Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]

#: The policy of every page: this origin only; no inline or injected scripts; styles may be inline
#: (plotly, Swagger UI and ReDoc set element styles); images from data: and blob: URLs (thumbnails,
#: plot exports); workers from blob: (ReDoc's search); never framed; no plugins; no <base>.
CSP = (
    "default-src 'self'; script-src 'self'; style-src 'self' 'unsafe-inline'; "
    "img-src 'self' data: blob:; font-src 'self' data:; connect-src 'self'; worker-src 'self' blob:; "
    "object-src 'none'; base-uri 'none'; form-action 'self'; frame-ancestors 'none'"
)
SECURITY_HEADERS = [
    (b"content-security-policy", CSP.encode()),
    (b"x-content-type-options", b"nosniff"),
    (b"x-frame-options", b"DENY"),
    (b"referrer-policy", b"no-referrer"),
    (b"cross-origin-opener-policy", b"same-origin"),
]
#: The OpenAPI extension by which a route raises its body limit.
MAX_BODY_KEY = "x-max-body-bytes"


class TooLarge(StarletteHTTPException):
    """A request body over its route's limit (413)."""

    def __init__(self, limit: int) -> None:
        super().__init__(413, f"the request body is over this route's limit of {limit} bytes")


class TokenThrottle:
    """Wrong operator tokens per client address: after ``max_failures`` within ``window_s`` the
    address is refused (429) until the oldest of them is ``window_s`` old. Bounded memory."""

    def __init__(self, max_failures: int = 10, window_s: float = 60.0, max_clients: int = 10_000) -> None:
        self.max_failures, self.window_s, self.max_clients = max_failures, window_s, max_clients
        self._failures: OrderedDict[str, deque[float]] = OrderedDict()

    def retry_after_s(self, client: str) -> float | None:
        """Seconds until ``client`` may try again, or None if it may now."""
        times = self._failures.get(client)
        if not times:
            return None
        now = time.monotonic()
        while times and now - times[0] > self.window_s:
            times.popleft()
        if len(times) < self.max_failures:
            return None
        return max(1.0, self.window_s - (now - times[0]))

    def failed(self, client: str) -> None:
        times = self._failures.pop(client, None) or deque(maxlen=self.max_failures)
        times.append(time.monotonic())
        self._failures[client] = times
        while len(self._failures) > self.max_clients:
            self._failures.popitem(last=False)


class TrustedProxies:
    """The reverse proxies whose ``X-Forwarded-For`` (and ``X-Forwarded-Proto``) the server believes:
    IP addresses or networks (``10.0.0.5``, ``10.0.0.0/24``, ``::1``). None by default: the client is
    the peer of the TCP connection, whatever its headers say."""

    def __init__(self, entries: Iterable[str] = ()) -> None:
        self.networks = tuple(ipaddress.ip_network(e.strip(), strict=False) for e in entries)

    def trusts(self, host: str) -> bool:
        try:
            address = ipaddress.ip_address(host)
        except ValueError:
            return False
        return any(address in n for n in self.networks)

    def client(self, peer: str, forwarded_for: bytes | None) -> str:
        """The client of a request from ``peer``: the last address of ``X-Forwarded-For`` that no
        trusted proxy added (the one the first proxy saw), when ``peer`` is a trusted proxy."""
        if not forwarded_for or not self.networks or not self.trusts(peer):
            return peer
        hops = [h.strip() for h in forwarded_for.decode("latin-1").split(",") if h.strip()]
        for hop in reversed(hops):
            if not self.trusts(hop):
                return hop[:64]
        return hops[0][:64] if hops else peer


@dataclass(frozen=True)
class RouteRule:
    methods: frozenset[str]
    path: re.Pattern[str]
    needs_token: bool
    max_body_bytes: int | None


def _json_error(status: int, code: str, message: str, headers: list[tuple[bytes, bytes]] | None = None):
    body = json.dumps(error_body(code, message)).encode()

    async def respond(send: Send) -> None:
        await send(
            {
                "type": "http.response.start",
                "status": status,
                "headers": [
                    (b"content-type", b"application/json"),
                    (b"content-length", str(len(body)).encode()),
                    (b"connection", b"close"),
                    *(headers or []),
                ],
            }
        )
        await send({"type": "http.response.body", "body": body})

    return respond


class Guard:
    """See the module docstring; ``fastapi_app`` is the app whose routes' rules it applies."""

    def __init__(self, app: ASGIApp, *, fastapi_app: Any) -> None:
        self.app = app
        self.fastapi_app = fastapi_app
        self._rules: list[RouteRule] | None = None
        self._in_flight: dict[str, int] = {}
        self._proxies: TrustedProxies | None = None

    # -- route rules, read once from the app's routes --------------------
    def rules(self) -> list[RouteRule]:
        if self._rules is None:
            from starlette.routing import compile_path

            from server.deps import needs_operator
            from server.openapi import api_routes

            out = []
            for route, path in api_routes(self.fastapi_app.routes):
                extra = route.openapi_extra or {}
                out.append(
                    RouteRule(
                        frozenset(route.methods or ()),
                        compile_path(path)[0],
                        needs_operator(route),
                        extra.get(MAX_BODY_KEY),
                    )
                )
            self._rules = out
        return self._rules

    def rule_for(self, method: str, path: str) -> RouteRule | None:
        for rule in self.rules():
            if method in rule.methods and rule.path.match(path):
                return rule
        return None

    # -- ASGI ------------------------------------------------------------
    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return

        settings = self.fastapi_app.state.settings
        client = self._client(scope, settings)
        api = scope["path"].startswith("/api/")

        async def send_with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                headers = message.get("headers", [])
                names = {k.lower(): v for k, v in headers}
                extra = [(k, v) for k, v in SECURITY_HEADERS if k not in names]
                json_body = names.get(b"content-type", b"").startswith(b"application/json")
                if (api or json_body) and b"cache-control" not in names:
                    extra.append((b"cache-control", b"no-store"))
                message["headers"] = [*headers, *extra]
            await send(message)

        if scope["type"] == "websocket":
            await self.app(scope, receive, send)
            return
        refusal = self._refuse(scope, client, settings)
        if refusal is not None:
            await refusal(send_with_headers)
            return
        busy = self._in_flight.get(client, 0)
        if busy >= settings.max_requests_per_client:
            await _json_error(
                429,
                "too_many_requests",
                f"{busy} requests of this address are in progress; wait for them to finish",
                [(b"retry-after", b"1")],
            )(send_with_headers)
            return
        self._in_flight[client] = busy + 1
        try:
            await self.app(scope, self._bounded(scope, receive, settings), send_with_headers)
        finally:
            left = self._in_flight.get(client, 1) - 1
            if left > 0:
                self._in_flight[client] = left
            else:
                self._in_flight.pop(client, None)

    def _client(self, scope: Scope, settings: Any) -> str:
        """The request's client address (`TrustedProxies`), written into the scope for the routes."""
        peer = scope.get("client") or ("unknown", 0)
        if self._proxies is None:
            self._proxies = TrustedProxies(settings.trusted_proxies)
        if not self._proxies.networks or not self._proxies.trusts(peer[0]):
            return str(peer[0])
        headers = scope.get("headers") or []
        hops = b",".join(v for k, v in headers if k == b"x-forwarded-for")  # several lines: one list
        client = self._proxies.client(peer[0], hops)
        scope["client"] = (client, 0 if client != peer[0] else peer[1])
        proto = dict(headers).get(b"x-forwarded-proto", b"").decode("latin-1").strip().lower()
        if proto in ("http", "https"):
            secure = proto == "https"
            scope["scheme"] = ("wss" if secure else "ws") if scope["type"] == "websocket" else proto
        return client

    @staticmethod
    def _limit(rule: RouteRule | None, settings: Any) -> int:
        if rule is not None and rule.max_body_bytes is not None:
            return int(rule.max_body_bytes)
        return int(settings.max_body_bytes)

    def _refuse(self, scope: Scope, client: str, settings: Any):
        """An early answer for this request (413, 401, 403, 429), or None to let it in."""
        headers = dict(scope.get("headers") or [])
        length = headers.get(b"content-length")
        rule = self.rule_for(scope["method"], scope["path"])
        limit = self._limit(rule, settings)
        if length is not None:
            try:
                n = int(length)
            except ValueError:
                return _json_error(400, "bad_request", "Content-Length is not a number")
            if n > limit:
                return _json_error(413, "too_large", f"the request body is over the limit of {limit} bytes")
        if rule is None or not rule.needs_token:
            return None
        from server.deps import TokenRefused, check_token

        try:
            check_token(settings, self.fastapi_app.state.throttle, client, headers.get(b"authorization"))
        except TokenRefused as exc:
            extra = [(k.lower().encode(), v.encode()) for k, v in exc.headers.items()]
            return _json_error(exc.status, exc.code, exc.message, extra)
        return None

    def _bounded(self, scope: Scope, receive: Receive, settings: Any) -> Receive:
        """``receive`` that counts the body and stops it at the route's limit."""
        limit = self._limit(self.rule_for(scope["method"], scope["path"]), settings)
        seen = 0

        async def bounded() -> Message:
            nonlocal seen
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > limit:
                    raise TooLarge(limit)
            return message

        return bounded
