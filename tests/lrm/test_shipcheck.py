"""The module's check of its peer, against a real TCP peer whose handshake fails in changing ways."""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import zmq

from camcal.core.wire import module_keys
from camcal.core.wire.keys import create_module_key, create_ship_key
from lrm.shipcheck import ShipCheck

#: A ZMTP 3.0 greeting offering the NULL mechanism: a plaintext ZeroMQ peer, to a CURVE module.
NULL_GREETING = b"\xff" + bytes(8) + b"\x7f" + bytes([3, 0]) + b"NULL".ljust(20, b"\0") + b"\0" + bytes(31)
HTTP_ERROR = b"HTTP/1.1 400 Bad Request\r\n\r\n"


@contextlib.contextmanager
def alternating_peer() -> Iterator[str]:
    """A TCP port that greets one connection as a plaintext ZeroMQ peer, the next with HTTP, and so on."""
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen()
    srv.settimeout(0.1)
    stop = threading.Event()

    def serve() -> None:
        n = 0
        while not stop.is_set():
            try:
                conn, _ = srv.accept()
            except TimeoutError:
                continue
            n += 1
            with contextlib.suppress(OSError):
                conn.sendall(NULL_GREETING if n % 2 else HTTP_ERROR)
                time.sleep(0.2)  # long enough for the module to read the greeting
            conn.close()

    t = threading.Thread(target=serve, daemon=True)
    t.start()
    try:
        yield f"tcp://127.0.0.1:{srv.getsockname()[1]}"
    finally:
        stop.set()
        t.join(2)
        srv.close()


def test_a_refusal_counts_from_the_first_failure_whatever_reasons_follow(tmp_path: Path) -> None:
    """A simulated module gives a refusing peer a grace before it gives up. Two defects kept one
    trying a port that answers HTTP for over a minute under load (twice in CI): a new reason (a
    mechanism mismatch, then a dropped greeting) restarted the grace, and a monitor attached after
    the connect could miss CONNECTED, so a peer that hung up looked like no failure and no new
    socket was ever made. The refusal's start stays the first failure's; every failure renews."""
    create_ship_key(tmp_path)
    create_module_key(tmp_path, "A")
    ctx = zmq.Context()
    with alternating_peer() as endpoint:
        check = ShipCheck("A", endpoint, None, module_keys(tmp_path, "A"))
        sock = check.open(ctx)
        reasons: list[str] = []
        starts: set[float] = set()
        sockets, deadline = 1, time.monotonic() + 40
        try:
            while sockets < 6 and time.monotonic() < deadline:
                check.watch()
                if check.refusal is not None:
                    starts.add(check.refusal.since_mono)
                    if not reasons or reasons[-1] != check.refusal.reason:
                        reasons.append(check.refusal.reason)
                if check.renew_due():  # as the agent does: a new socket after a failed handshake
                    check.close(sock)
                    sock = check.open(ctx)
                    sockets += 1
                time.sleep(0.02)
        finally:
            check.close(sock)
            ctx.term()
    assert sockets == 6, "the module did not try the peer again"
    assert len(starts) == 1, f"the refusal restarted {len(starts) - 1} times; reasons seen: {reasons}"
    # Each failure said once, as it is: the disconnect after a refused mechanism is not another one.
    assert reasons[:4] == ["plaintext", "no_handshake", "plaintext", "no_handshake"], reasons
