"""Who may connect to the ingest: the ZAP handler of the module link, and what it turned away.

With CURVE (`camcal.core.wire.sockets`), libzmq asks a ZAP handler about every
client that completes the CURVE handshake: the client proves it holds the
secret of a public key, and the handler says whether that key may in, and
as which module (the ZAP "user id", which every message of the connection
then carries as its ``User-Id`` property). `Gatekeeper` is that handler:
it maps each public key of ``keys/modules/*.key`` to its module id, reloads
the folder when it changes (a module added with ``camcal keys create`` is
let in without a restart), and refuses every other key.

It also watches the ROUTER's own handshake failures (a plaintext client, or
something that does not speak ZMTP at all). Each refused connection is
counted and remembered by its source, so the dashboard shows "refused
connections" once, with counts, instead of a module or an alarm per try;
the log says each source once and then at most once every ten seconds.
Both sockets are polled by the receiving thread (`ingest.receive`): nothing
here runs on a thread of its own.
"""

from __future__ import annotations

import logging
import os
import socket
import time
from collections import OrderedDict, deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import zmq
from zmq.utils.monitor import parse_monitor_message

from camcal.core.ratelog import RateLimitedLog
from camcal.core.wire.keys import authorised_modules, fingerprint, z85_of
from camcal.core.wire.sockets import ZAP_DOMAIN
from ingest.counters import Counters

log = logging.getLogger("camcal.ingest")

ZAP_ENDPOINT = "inproc://zeromq.zap.01"
#: Sources of refused connections remembered for the dashboard (the oldest are forgotten).
MAX_SOURCES = 16
#: The window of the "in the last minute" count.
RECENT_S = 60.0


@dataclass
class Source:
    """One source of refused connections: an address and, for a refused key, the key."""

    reason: str
    address: str
    key: str
    count: int = 0
    first_unix_s: float = 0.0
    last_unix_s: float = 0.0


class RefusedConnections:
    """Counts of refused connections by reason and by source; bounded whatever the flood."""

    def __init__(self, counters: Counters) -> None:
        self.counters = counters
        self.sources: OrderedDict[tuple[str, str, str], Source] = OrderedDict()
        self.recent: deque[float] = deque(maxlen=100_000)
        self.warn = RateLimitedLog(log)

    def add(self, reason: str, address: str = "", key: str = "") -> None:
        now = time.time()
        self.counters.inc("refused_connections")
        self.counters.inc(f"refused_connections_{reason}")
        self.recent.append(now)
        host = _host(address)
        k = (reason, host, key)
        src = self.sources.pop(k, None) or Source(reason, address, key, first_unix_s=now)
        src.count += 1
        src.address, src.last_unix_s = address, now
        self.sources[k] = src
        while len(self.sources) > MAX_SOURCES:
            self.sources.popitem(last=False)
        who = " ".join(x for x in (address or "an unknown address", f"key {key}" if key else "") if x)
        # Rate-limited per source (reason and host), not per key: a flood of fresh keys is one line.
        self.warn(logging.WARNING, f"conn:{reason}:{host}", "refused a connection from %s: %s", who, reason)

    def summary(self) -> dict[str, Any]:
        """For the ingest's health: totals, the last minute, and the newest sources first."""
        now = time.time()
        while self.recent and now - self.recent[0] > RECENT_S:
            self.recent.popleft()
        by_reason: dict[str, int] = {}
        for (reason, _, _), src in self.sources.items():
            by_reason[reason] = by_reason.get(reason, 0) + src.count
        return {
            "total": self.counters.get("refused_connections"),
            "last_minute": len(self.recent),
            "sources": [
                {
                    "reason": s.reason,
                    "address": s.address,
                    "key": s.key,
                    "count": s.count,
                    "last_unix_s": round(s.last_unix_s, 3),
                }
                for s in reversed(self.sources.values())
            ],
        }


#: Handshake failures of the ROUTER itself, as a reason a person can read.
_MISMATCH = getattr(zmq, "PROTOCOL_ERROR_ZMTP_MECHANISM_MISMATCH", 0x11000002)


def _host(address: str) -> str:
    """The host of an address ("10.0.0.7", "10.0.0.7:51234", "[::1]:51234" -> "10.0.0.7", "::1")."""
    if address.startswith("["):
        return address[1:].split("]", 1)[0]
    return address.rsplit(":", 1)[0] if address.count(":") == 1 else address


def _peer_address(fd: int) -> str:
    """The remote address of an accepted TCP connection ("host:port"; "" if it cannot be read: the
    connection may be gone already when a busy receiving thread reads its ACCEPTED event)."""
    try:
        with socket.socket(fileno=os.dup(fd)) as s:  # a duplicate (closing it is safe), its family read
            host, port = s.getpeername()[:2]
            return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
    except OSError:
        return ""


class Gatekeeper:
    """The ZAP handler and handshake watcher of one ingest's link (see the module docstring)."""

    def __init__(self, ctx: zmq.Context[Any], keys_dir: Path, counters: Counters) -> None:
        """Bind the ZAP handler in ``ctx``: before the link's ROUTER binds, so no client can ever
        complete a handshake unasked (libzmq lets every CURVE client in while no handler is bound)."""
        self.keys_dir = Path(keys_dir)
        self.refused = RefusedConnections(counters)
        self._modules_dir = self.keys_dir / "modules"
        self._stamp: int | None = None
        self.keys: dict[bytes, str] = {}
        self._reload()
        self.zap = ctx.socket(zmq.ROUTER)
        self.zap.setsockopt(zmq.LINGER, 0)
        self.zap.bind(ZAP_ENDPOINT)
        self.monitor: Any = None
        self.sockets: tuple[Any, ...] = (self.zap,)
        self._peers: dict[int, str] = {}  # the ROUTER's accepted connections: socket -> "host:port"
        self._failed: deque[tuple[str, float]] = deque()  # handshakes that failed, their ends to come

    def watch(self, router: Any) -> None:
        """Count the ROUTER's own handshake failures (plaintext clients, garbage) too, with the address
        of each (its connection's, from the accepted socket: the failure events do not say)."""
        self.monitor = router.get_monitor_socket(
            zmq.EVENT_ACCEPTED
            | zmq.EVENT_DISCONNECTED
            | zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL
            | zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL
        )
        self.sockets = (self.zap, self.monitor)

    def _mtime(self) -> int | None:
        try:
            return os.stat(self._modules_dir).st_mtime_ns
        except OSError:
            return None

    def _reload(self) -> None:
        stamp = self._mtime()
        if stamp == self._stamp and self._stamp is not None:
            return
        try:
            self.keys = authorised_modules(self.keys_dir)
        except Exception as exc:  # a damaged key file: keep the keys known so far, say so
            log.error("cannot read the module keys in %s: %s", self._modules_dir, exc)
        self._stamp = stamp

    def module_of(self, public_z85: bytes) -> str | None:
        """The module a public key belongs to (re-reading the keys folder if it changed)."""
        module = self.keys.get(public_z85)
        if module is None:
            self._reload()
            module = self.keys.get(public_z85)
        return module

    def handle(self) -> None:
        """Answer every ZAP request waiting, and count the handshake failures reported; never blocks."""
        for _ in range(256):
            try:
                req = self.zap.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                break
            self._answer(req)
        for _ in range(256 if self.monitor is not None else 0):
            try:
                event = parse_monitor_message(self.monitor.recv_multipart(zmq.NOBLOCK))
            except zmq.Again:
                break
            kind, value = event["event"], event["value"]
            if kind == zmq.EVENT_ACCEPTED:
                self._peers[value] = _peer_address(value)
            elif kind == zmq.EVENT_DISCONNECTED:
                # libzmq reports a failed handshake, then the connection's end (with its socket).
                address = self._peers.pop(value, "")
                if self._failed:
                    self.refused.add(self._failed.popleft()[0], address)
            elif kind == zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL and value == _MISMATCH:
                self._failed.append(("plaintext", time.monotonic()))  # no CURVE (or another mechanism)
            else:  # garbage, a timeout, a broken handshake, or a plaintext client that hung up first
                self._failed.append(("no_handshake", time.monotonic()))
        while self._failed and time.monotonic() - self._failed[0][1] > 1.0:  # its end never came
            self.refused.add(self._failed.popleft()[0])

    def _answer(self, req: list[bytes]) -> None:
        # [peer, "", version, request id, domain, address, identity, mechanism, credentials...]
        if len(req) < 8:
            return
        peer, version, request_id = req[0], req[2], req[3]
        domain, address, mechanism = req[4], req[5].decode(errors="replace"), req[7]
        status, text, user = b"400", b"refused", b""
        if version != b"1.0":
            status, text = b"500", b"unsupported ZAP version"
        elif domain != ZAP_DOMAIN or mechanism != b"CURVE" or len(req) < 9 or len(req[8]) != 32:
            self.refused.add("not_curve", address)
        else:
            public = z85_of(req[8])
            module = self.module_of(public)
            if module is None:
                self.refused.add("unknown_key", address, fingerprint(public))
                text = b"unknown key"
            else:
                status, text, user = b"200", b"OK", module.encode()
        self.zap.send_multipart([peer, b"", b"1.0", request_id, status, text, user, b""])

    def close(self) -> None:
        for sock in self.sockets:
            sock.close(0)
        self.sockets = ()
