"""A client that speaks the protocol badly on purpose, and a probe of a real ingest's state.

`Rogue` is a DEALER with a chosen routing id that sends raw frames and
collects the ship's replies: by default over CURVE with a key the ship lets
in as the module of that id (made on the fly in the ingest's keys folder),
or with any key pair, or none (plaintext). `IngestProbe` starts a real
``camcal ingest`` process, follows its event stream (for its health:
counters) and reads its database.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import sqlite3
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import zmq

from camcal.core import wire
from camcal.core.wire.keys import KeyPair, create_module_key, ship_public
from camcal.core.wire.sockets import new_route
from tests.utils.live import link_keys, start_ingest
from tests.utils.system import free_ports


class Rogue:
    """A DEALER connected to the ship as ``identity``; `send` returns the ship's replies.

    ``keys_dir``: the ingest's keys folder; the rogue gets (a new if need be) key of module
    ``key_of`` (default ``identity``) from it. ``pair``: any key pair instead (an unknown key).
    Neither: a plaintext client. ``route``: its routing id (default: a module's, ``identity/`` and
    32 random hex digits).
    """

    def __init__(
        self,
        ctx: zmq.Context[Any],
        endpoint: str,
        identity: str,
        *,
        keys_dir: Path | None = None,
        key_of: str | None = None,
        pair: KeyPair | None = None,
        route: bytes | None = None,
    ) -> None:
        self.sock = ctx.socket(zmq.DEALER)
        if keys_dir is not None and pair is None:
            module = key_of or identity
            create_module_key(keys_dir, module)
            pair = wire.module_keys(keys_dir, module).pair
        if pair is not None:
            assert keys_dir is not None, "an encrypted rogue needs the ship's public key (keys_dir)"
            self.sock.setsockopt(zmq.CURVE_SERVERKEY, ship_public(keys_dir))
            self.sock.setsockopt(zmq.CURVE_PUBLICKEY, pair.public)
            self.sock.setsockopt(zmq.CURVE_SECRETKEY, pair.secret)
        # A module's routing id: its id, '/' and random digits (``route``: any other, to test the ship).
        self.sock.setsockopt(zmq.ROUTING_ID, route if route is not None else new_route(identity))
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.connect(endpoint)
        self.replies: list[Any] = []

    def send(
        self,
        parts: list[bytes],
        *,
        wait_s: float = 2.0,
        expect: int = 1,
        skip: tuple[str, ...] = ("ship_heartbeat",),
    ) -> list[Any]:
        """Send one message; collect replies until ``expect`` arrived or ``wait_s`` (``skip``: ignored).

        A message the socket cannot send (no connection: the ship refused the handshake) is dropped.
        """
        with contextlib.suppress(zmq.Again):
            self.sock.send_multipart(parts, zmq.NOBLOCK)
        return self.collect(wait_s, expect, skip)

    def collect(
        self, wait_s: float, expect: int = 1, skip: tuple[str, ...] = ("ship_heartbeat",)
    ) -> list[Any]:
        got: list[Any] = []
        end = time.monotonic() + wait_s
        while len(got) < expect and time.monotonic() < end:
            if not self.sock.poll(20):
                continue
            msg, _ = wire.decode(self.sock.recv_multipart(), allowed=wire.SHIP_TYPES)
            if msg.type not in skip:
                got.append(msg)
        self.replies += got
        return got

    def close(self) -> None:
        self.sock.close(0)


class IngestProbe:
    """A real ``camcal ingest`` process on free ports, its event stream and its SQLite file."""

    def __init__(self, data: Path, *extra: str, ports: tuple[int, int] | None = None) -> None:
        self.data = data
        self.port, self.events_port = ports or free_ports(2)
        self.endpoint = f"tcp://127.0.0.1:{self.port}"
        self.keys = link_keys(data)
        self.proc = start_ingest(data, self.port, self.events_port, *extra)
        self.ctx = zmq.Context.instance()
        self.sub = self.ctx.socket(zmq.SUB)
        self.sub.setsockopt(zmq.SUBSCRIBE, b"health")
        self.sub.setsockopt(zmq.LINGER, 0)
        self.sub.connect(f"tcp://127.0.0.1:{self.events_port}")

    def health(self, timeout_s: float = 10.0) -> dict[str, Any]:
        """The ingest's next health report (it sends one a second), read from its event stream.

        Reports queued before this call are skipped: the one returned was made after it.
        """
        asked = time.time()
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if self.sub.poll(100):
                _, body = self.sub.recv_multipart()
                event = json.loads(body)
                if event["t"] >= asked:
                    return event["payload"]
        raise AssertionError(f"no health report from the ingest in {timeout_s} s; alive: {self.alive()}")

    def wait_ready(self, timeout_s: float = 30.0) -> None:
        self.health(timeout_s)

    def rogue(self, identity: str, **kw: Any) -> Rogue:
        """A rogue client of this ingest, over CURVE with a key of module ``identity`` (see `Rogue`)."""
        return Rogue(zmq.Context.instance(), self.endpoint, identity, keys_dir=self.keys, **kw)

    def alive(self) -> bool:
        return self.proc.poll() is None

    def db(self) -> sqlite3.Connection:
        return sqlite3.connect(self.data / "camcal.db", timeout=30)

    def rows(self, sql: str, *args: Any) -> list[tuple[Any, ...]]:
        with contextlib.closing(self.db()) as con:
            return con.execute(sql, args).fetchall()

    def stop(self) -> int | None:
        self.sub.close(0)
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(20)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait(10)
        return self.proc.returncode


def invalid_json_events(probe: IngestProbe) -> Iterator[tuple[int, str]]:
    """Event rows whose payload is not strict JSON (NaN, Infinity)."""

    def refuse(name: str) -> Any:
        raise ValueError(name)

    for eid, text in probe.rows("SELECT id, payload FROM events"):
        try:
            json.loads(text, parse_constant=refuse)
        except ValueError:
            yield eid, text
