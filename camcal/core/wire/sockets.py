"""The sockets of the link: the ship's ROUTER and a module's DEALER, with the recommended options.

With keys (`camcal.core.wire.keys`) both speak ZeroMQ CURVE: the ship is the
CURVE server and asks its ZAP handler (``inproc://zeromq.zap.01`` of its
context, domain ``camcal``) which module each client key belongs to; a
module is a CURVE client that knows the ship's public key. Without keys the
link is plaintext, for a lab bench only.
"""

from __future__ import annotations

import re
import secrets
from collections.abc import Callable
from typing import Any

import zmq

from camcal.core.wire.keys import KeyPair, ModuleKeys
from camcal.core.wire.limits import MAX_PAYLOAD_BYTES

#: The ZAP domain of the module link.
ZAP_DOMAIN = b"camcal"
#: A handshake (TCP connected, ZMTP greeting and CURVE) must end within this many milliseconds.
HANDSHAKE_MS = 5000


def ship_socket(
    ctx: zmq.Context[Any],
    endpoint: str,
    *,
    max_message_bytes: int = 2 * MAX_PAYLOAD_BYTES,
    keys: KeyPair | None = None,
) -> Any:
    """The ship's ROUTER, bound to ``endpoint`` (``tcp://*:PORT``); a CURVE server with ``keys``.

    ``ROUTER_HANDOVER`` lets a module that reconnects (a new TCP connection
    under the same routing id) take its route over at once; ``MAXMSGSIZE``
    caps what a misbehaving peer can make the ship buffer. With keys, a
    client must pass the ZAP handler of ``ctx`` before it can send anything.
    """
    sock = ctx.socket(zmq.ROUTER)
    if keys is not None:
        sock.setsockopt(zmq.CURVE_SERVER, 1)
        sock.setsockopt(zmq.CURVE_PUBLICKEY, keys.public)
        sock.setsockopt(zmq.CURVE_SECRETKEY, keys.secret)
        sock.setsockopt(zmq.ZAP_DOMAIN, ZAP_DOMAIN)
    sock.setsockopt(zmq.ROUTER_HANDOVER, 1)
    sock.setsockopt(zmq.ROUTER_MANDATORY, 0)
    sock.setsockopt(zmq.MAXMSGSIZE, max_message_bytes)
    sock.setsockopt(zmq.HANDSHAKE_IVL, HANDSHAKE_MS)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.RCVHWM, 1000)
    sock.setsockopt(zmq.SNDHWM, 1000)
    sock.bind(endpoint)
    return sock


def new_route(module: str) -> bytes:
    """A module's routing id: its id, ``/`` and 32 random hex digits, new at every start.

    Nobody else can guess it, so no other client can take the module's
    route over (``ROUTER_HANDOVER``) and receive what the ship sends it.
    """
    return f"{module}/{secrets.token_hex(16)}".encode()


def route_module(route: bytes) -> str:
    """The module id a routing id names (the part before ``/``; all of it for a route without one)."""
    return route.split(b"/", 1)[0].decode("utf-8", errors="replace")


#: A module's routing id: its id, ``/`` and at least 32 random hex digits (`new_route`).
_ROUTE = re.compile(rb"[A-Za-z0-9_.-]{1,64}/[0-9a-f]{32,128}")


def route_is_safe(route: bytes) -> bool:
    """Whether a routing id is a module's fresh one (`new_route`): a bare module id, or one with too few
    random digits, could be guessed, and with ``ROUTER_HANDOVER`` whoever connects under it takes the
    route over (the ship's answers go to them). The ship refuses such a route (``wrong_identity``)."""
    return _ROUTE.fullmatch(route) is not None


def module_socket(
    ctx: zmq.Context[Any],
    endpoint: str,
    module: str,
    *,
    keys: ModuleKeys | None = None,
    before_connect: Callable[[Any], None] | None = None,
) -> Any:
    """A module's DEALER, connected to the ship under a fresh route (`new_route`); CURVE with ``keys``.

    ``before_connect(sock)`` runs before the connect starts: a monitor attached later can miss the
    connection's first events (a peer that then fails the handshake went unnoticed).

    ZeroMQ reconnects by itself after a broken link; ``IMMEDIATE`` keeps
    messages from queueing for a peer that is not connected (the outbox holds
    them instead), and ZMTP heartbeats detect a dead TCP link within seconds.
    """
    sock = ctx.socket(zmq.DEALER)
    if keys is not None:
        sock.setsockopt(zmq.CURVE_SERVERKEY, keys.ship_public)
        sock.setsockopt(zmq.CURVE_PUBLICKEY, keys.pair.public)
        sock.setsockopt(zmq.CURVE_SECRETKEY, keys.pair.secret)
    sock.setsockopt(zmq.ROUTING_ID, new_route(module))
    sock.setsockopt(zmq.IMMEDIATE, 1)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.SNDHWM, 64)
    sock.setsockopt(zmq.RECONNECT_IVL, 200)
    sock.setsockopt(zmq.RECONNECT_IVL_MAX, 2000)
    sock.setsockopt(zmq.HANDSHAKE_IVL, HANDSHAKE_MS)
    sock.setsockopt(zmq.HEARTBEAT_IVL, 1000)
    sock.setsockopt(zmq.HEARTBEAT_TIMEOUT, 3000)
    if before_connect is not None:
        before_connect(sock)
    sock.connect(endpoint)
    return sock
