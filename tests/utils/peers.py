"""TCP peers that are not a camcal ship: what a module may find at the end of ``--connect``."""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from collections.abc import Callable, Iterator

#: A ZMTP 3.0 greeting offering the NULL mechanism: a plaintext ZeroMQ peer, to a CURVE module.
NULL_GREETING = b"\xff" + bytes(8) + b"\x7f" + bytes([3, 0]) + b"NULL".ljust(20, b"\0") + b"\0" + bytes(31)
HTTP_ERROR = b"HTTP/1.1 400 Bad Request\r\n\r\n"


@contextlib.contextmanager
def tcp_peer(answer: Callable[[int], bytes], hold_s: float = 0.0) -> Iterator[str]:
    """A local TCP port (its ``tcp://`` endpoint yielded) that sends the ``n``-th connection
    ``answer(n)`` (from 1), waits ``hold_s`` and hangs up."""
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
                conn.sendall(answer(n))
                time.sleep(hold_s)
            conn.close()

    t = threading.Thread(target=serve, daemon=True)
    t.start()
    try:
        yield f"tcp://127.0.0.1:{srv.getsockname()[1]}"
    finally:
        stop.set()
        t.join(2)
        srv.close()
