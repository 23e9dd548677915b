"""The sockets of the link: the ship's ROUTER and a module's DEALER, with the recommended options."""

from __future__ import annotations

from typing import Any

import zmq

from camcal.wire.limits import MAX_PAYLOAD_BYTES


def ship_socket(
    ctx: zmq.Context[Any], endpoint: str, *, max_message_bytes: int = 2 * MAX_PAYLOAD_BYTES
) -> Any:
    """The ship's ROUTER, bound to ``endpoint`` (``tcp://*:PORT``).

    ``ROUTER_HANDOVER`` lets a module that reconnects (a new TCP connection
    under the same identity) take its identity over at once; ``MAXMSGSIZE``
    caps what a misbehaving peer can make the ship buffer.
    """
    sock = ctx.socket(zmq.ROUTER)
    sock.setsockopt(zmq.ROUTER_HANDOVER, 1)
    sock.setsockopt(zmq.ROUTER_MANDATORY, 0)
    sock.setsockopt(zmq.MAXMSGSIZE, max_message_bytes)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.RCVHWM, 1000)
    sock.setsockopt(zmq.SNDHWM, 1000)
    sock.bind(endpoint)
    return sock


def module_socket(ctx: zmq.Context[Any], endpoint: str, module: str) -> Any:
    """A module's DEALER, connected to the ship with the module id as its identity.

    ZeroMQ reconnects by itself after a broken link; ``IMMEDIATE`` keeps
    messages from queueing for a peer that is not connected (the outbox holds
    them instead), and ZMTP heartbeats detect a dead TCP link within seconds.
    """
    sock = ctx.socket(zmq.DEALER)
    sock.setsockopt(zmq.ROUTING_ID, module.encode())
    sock.setsockopt(zmq.IMMEDIATE, 1)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.SNDHWM, 64)
    sock.setsockopt(zmq.RECONNECT_IVL, 200)
    sock.setsockopt(zmq.RECONNECT_IVL_MAX, 2000)
    sock.setsockopt(zmq.HEARTBEAT_IVL, 1000)
    sock.setsockopt(zmq.HEARTBEAT_TIMEOUT, 3000)
    sock.connect(endpoint)
    return sock
