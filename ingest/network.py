"""The ingest's network thread: the only owner of the ROUTER socket.

It decodes and checks every message, answers ``hello`` with ``welcome`` and
every refused message with a ``nack`` (reason, and whether resending can
help), keeps track of links and heartbeats, and sends what the store thread
hands it (acks, nacks, commands) through an inproc socket. With CURVE it
also answers the link's ZAP requests (`ingest.gatekeeper`), and it believes
a message's ``module`` only when the connection's key belongs to that module. Nothing a
message holds can stop this thread: a failure while handling one message
is caught at the message's boundary, counted, logged (rate-limited) and
answered with ``internal_error``.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import zmq

from camcal.core import wire
from camcal.core.ratelog import RateLimitedLog
from camcal.core.wire.reasons import REASONS
from camcal.core.wire.sockets import route_module

if TYPE_CHECKING:
    from ingest.gatekeeper import Gatekeeper
    from ingest.service import IngestService

log = logging.getLogger("camcal.ingest")


#: Heartbeats the module's clock offset is estimated over (`Link.clock_offset_s`), and how many
#: it needs before it says anything.
CLOCK_BEATS = 30
CLOCK_MIN_BEATS = 5


@dataclass
class Link:
    """What the ship knows of one module's connection."""

    module: str
    identity: bytes
    boot: str = ""
    up: bool = False
    down_reason: str = ""  # "bye" (signed off) or "timeout" while down
    last_seen_mono: float = 0.0
    last_seen_unix_s: float = 0.0
    welcomed: bool = False
    schedule: dict[str, Any] = field(default_factory=dict)
    outbox_pending: int = 0
    in_flight: int = 0
    last_seq: int = 0  # the highest sequence number of ``boot`` the module says it has produced
    card_skipped: int = 0  # messages the module could not keep on its SD card (not taken) this boot
    card_error: str | None = None
    capture_errors: int = 0  # camera captures that failed this boot (the module retries them)
    camera_error: str | None = None
    sensor_errors: int = 0  # sensor reads that failed this boot
    sensor_error: str | None = None
    deferred_shots: int = 0  # shots its runner took at a later turn of their colour this boot
    frames: deque[float] = field(default_factory=lambda: deque(maxlen=2000))
    last_frame_unix_s: float | None = None
    last_heartbeat_sent: float = 0.0
    clock_offset_s: float | None = None
    clock_readings: deque[float] = field(default_factory=lambda: deque(maxlen=CLOCK_BEATS))


@dataclass
class Incoming:
    """Something for the store thread: a message, a link change, or an analysis result."""

    kind: str
    module: str
    msg: Any
    payload: Any = None
    received_unix_s: float = 0.0
    received_mono: float = 0.0


def _user_id(frame: zmq.Frame) -> str:
    """The module the connection's key belongs to ("" if the handshake named none)."""
    try:
        value = frame.get("User-Id")
    except zmq.ZMQError:
        return ""
    return value if isinstance(value, str) else ""


def nack(reason: str, detail: str, ref: dict[str, Any] | None = None) -> wire.Nack:
    """The refusal of a message, naming it as far as ``ref`` (type, boot, seq) could be read."""
    ref = ref or {}
    return wire.Nack(
        module="ship",
        boot=ref.get("boot"),
        seq=ref.get("seq"),
        of=ref.get("type"),
        reason=reason,
        retry=REASONS[reason].retry,
        detail=detail[:500],
    )


class Network:
    """Runs in the ``ingest-net`` thread; see the module docstring."""

    def __init__(
        self,
        svc: IngestService,
        router: Any,
        pull: Any,
        q: queue.Queue[Incoming],
        gatekeeper: Gatekeeper | None = None,
    ) -> None:
        self.svc = svc
        self.gatekeeper = gatekeeper  # None: a plaintext link (lab bench)
        self.config = svc.config
        self.counters = svc.counters
        self.router = router
        self.pull = pull
        self.q = q
        self.links: dict[str, Link] = {}
        self.links_lock = threading.Lock()
        self.warn = RateLimitedLog(log)

    def run(self, stop: threading.Event, started: threading.Event) -> None:
        poller = zmq.Poller()
        poller.register(self.router, zmq.POLLIN)
        poller.register(self.pull, zmq.POLLIN)
        gate = self.gatekeeper.sockets if self.gatekeeper else ()
        for sock in gate:
            poller.register(sock, zmq.POLLIN)
        started.set()
        while not stop.is_set():
            events = dict(poller.poll(50))
            if self.gatekeeper and any(sock in events for sock in gate):
                self._guarded("gatekeeper", self.gatekeeper.handle)
            if self.router in events:
                for _ in range(256):
                    try:
                        parts = self.router.recv_multipart(zmq.NOBLOCK, copy=False)
                    except zmq.Again:
                        break
                    self.on_message(parts)
            if self.pull in events:
                for _ in range(1024):
                    try:
                        parts = self.pull.recv_multipart(zmq.NOBLOCK)
                    except zmq.Again:
                        break
                    self._guarded("send", self._send_to_module, parts[0].decode(), parts[1:])
            self._guarded("timers", self._timers)

    def _guarded(self, what: str, fn: Any, *args: Any) -> None:
        try:
            fn(*args)
        except Exception:
            self.counters.inc("handler_errors")
            self.warn(logging.ERROR, what, "ingest network thread: %s failed", what, exc_info=True)

    # -- one message -----------------------------------------------------
    def on_message(self, parts: list[zmq.Frame]) -> None:
        """Handle one message from a ROUTER: nothing in it may escape as an exception."""
        identity = parts[0].bytes
        self.counters.inc("messages")
        try:
            # With CURVE, who sent it is the module its key belongs to (the ZAP handler's user id).
            user = _user_id(parts[0]) if self.gatekeeper else None
            self._handle(identity, parts[1:], user)
        except Exception as exc:
            self.counters.refuse("internal_error", malformed=False)
            self.warn(logging.ERROR, "internal", "ingest failed on a message: %s", exc, exc_info=True)
            self._send(identity, nack("internal_error", f"the ship failed on this message: {exc}"))

    def refuse(
        self, identity: bytes, reason: str, detail: str, ref: dict[str, Any], *, malformed: bool = False
    ) -> None:
        """Count a refused message, log it (rate-limited) and answer it with a ``nack``."""
        self.counters.refuse(reason, malformed=malformed)
        who = ref.get("module") or identity[:40]
        self.warn(
            logging.WARNING, f"refused:{reason}", "refused a message from %r: %s: %s", who, reason, detail
        )
        self._send(identity, nack(reason, detail, ref))

    def _handle(self, identity: bytes, frames: list[zmq.Frame], user: str | None = None) -> None:
        t_mono, t_unix = time.monotonic(), time.time()
        try:
            msg, payload = wire.decode(
                frames, allowed=wire.MODULE_TYPES, max_payload_bytes=self.config.max_payload_bytes
            )
        except wire.ProtocolError as exc:
            self.refuse(identity, exc.kind, exc.detail, exc.ref, malformed=True)
            return
        module = msg.module
        ref = {
            "type": msg.type,
            "module": module,
            "boot": getattr(msg, "boot", None),
            "seq": getattr(msg, "seq", None),
        }
        if user is not None and module != user:
            self.counters.inc("impostor_messages")
            self.refuse(
                identity,
                "wrong_identity",
                f"module {module!r} on a connection whose key belongs to module {user!r}",
                ref,
            )
            return
        if route_module(identity) != module:
            self.refuse(
                identity,
                "wrong_identity",
                f"module {module!r} on a connection whose routing id is {identity[:64]!r}: a module "
                "sets its socket's routing id to its module id, '/' and random digits",
                ref,
            )
            return
        if not self.config.serves(module):
            if self.counters.not_served(module) == 1:
                log.warning(
                    "refusing module %s: this ingest serves %s", module, ", ".join(self.config.modules)
                )
            self.refuse(
                identity,
                "not_served",
                f"this ingest serves {', '.join(self.config.modules)}, not {module}",
                ref,
            )
            return
        dive = self.svc.dive.name
        if msg.dive is not None and msg.dive != dive:
            self.refuse(
                identity,
                "wrong_dive",
                f"this ingest ({self.svc.instance}) records dive {dive!r}; module {module} was started "
                f"for dive {msg.dive!r}: nothing of it is stored here",
                ref,
            )
            return
        with self.links_lock:
            link = self.links.get(module)
            if link is None:
                link = self.links[module] = Link(module, identity, boot=getattr(msg, "boot", ""))
            link.identity = identity  # the route of the module's newest connection
            was_up = link.up
            link.up, link.down_reason = True, ""
            link.last_seen_mono, link.last_seen_unix_s = t_mono, t_unix
        if not was_up:
            self.q.put(Incoming("link", module, {"up": True}, None, t_unix, t_mono))
        kind = msg.type
        if kind == "hello":
            link.boot, link.welcomed = msg.boot, True
            link.schedule = msg.schedule.model_dump()
            link.outbox_pending, link.last_seq = msg.outbox_pending, msg.last_seq
            self._welcome(link)
            self.q.put(Incoming("hello", module, msg, None, t_unix, t_mono))
        elif kind == "heartbeat":
            # Module clock minus ship clock. A heartbeat queued behind frames on a busy link (a
            # catch-up after an outage) arrives late and reads as a clock behind, never ahead: the
            # least delayed of the recent beats (the largest reading) is the estimate, as NTP's
            # minimum-delay filter does.
            link.clock_readings.append(msg.sent_at.timestamp() - t_unix)
            if len(link.clock_readings) >= CLOCK_MIN_BEATS:  # (before: not known yet)
                link.clock_offset_s = max(link.clock_readings)
            link.schedule = msg.schedule.model_dump()
            link.outbox_pending, link.in_flight, link.boot = msg.outbox_pending, msg.in_flight, msg.boot
            link.last_seq = msg.last_seq
            link.card_skipped, link.card_error = msg.card_skipped, msg.card_error
            link.capture_errors, link.camera_error = msg.capture_errors, msg.camera_error
            link.sensor_errors, link.sensor_error = msg.sensor_errors, msg.sensor_error
            link.deferred_shots = msg.deferred_shots
            if not link.welcomed:  # the ship restarted under a running module: greet it again
                self._welcome(link)
            self.q.put(Incoming("heartbeat", module, msg, None, t_unix, t_mono))
        elif kind in ("frame", "sensors"):
            self.counters.inc("frames_received" if kind == "frame" else "sensor_batches_received")
            if kind == "frame":
                link.frames.append(t_mono)
                link.last_frame_unix_s = t_unix
            self.q.put(Incoming(kind, module, msg, payload, t_unix, t_mono))
        elif kind == "command_status":
            self.q.put(Incoming(kind, module, msg, None, t_unix, t_mono))
        elif kind == "bye":
            link.up, link.welcomed, link.down_reason = False, False, "bye"
            self.q.put(Incoming("link", module, self.down_notice(link, "bye"), None, t_unix, t_mono))

    def _welcome(self, link: Link) -> None:
        link.welcomed = True
        self._send(
            link.identity,
            wire.Welcome(
                module="ship",
                window=self.svc.window,
                heartbeat_s=self.config.heartbeat_s,
                ingest=self.svc.instance,
                dive=self.svc.dive.name,
            ),
        )

    # -- sending ---------------------------------------------------------
    def _send(self, identity: bytes, msg: Any) -> None:
        try:
            self.router.send_multipart([identity, *wire.encode(msg)], zmq.NOBLOCK)
        except zmq.Again:
            self.counters.inc("send_dropped")

    def _send_to_module(self, module: str, frames: list[bytes]) -> None:
        link = self.links.get(module)
        if link is None:
            self.counters.inc("send_unknown_module")
            return
        try:
            self.router.send_multipart([link.identity, *frames], zmq.NOBLOCK)
        except zmq.Again:
            self.counters.inc("send_dropped")

    def _timers(self) -> None:
        now = time.monotonic()
        for link in list(self.links.values()):
            if link.up and now - link.last_seen_mono > self.config.link_timeout_s:
                link.up, link.welcomed, link.down_reason = False, False, "timeout"
                down = self.down_notice(link, "timeout")
                self.q.put(Incoming("link", link.module, down, None, time.time(), now))
            if link.up and now - link.last_heartbeat_sent >= self.config.heartbeat_s:
                link.last_heartbeat_sent = now
                self._send(link.identity, wire.ShipHeartbeat(module="ship", window=self.svc.window))

    @staticmethod
    def down_notice(link: Link, reason: str) -> dict[str, Any]:
        """A link-down notice, with how far the module said it had got (for the store thread's gaps)."""
        return {"up": False, "reason": reason, "boot": link.boot, "last_seq": link.last_seq}
