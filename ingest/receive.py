"""Receive: the ingest's receiving thread, the only owner of the ROUTER socket.

It reads every message and checks what its header says (`wire.decode_header`:
framing, sizes, the JSON dialect, the fields; never the payload, whose checks
can take seconds and belong to `ingest.check`), who sent it (the connection's
key, its routing id), whether this ingest serves the module and records its
dive. It keeps track of links and heartbeats, answers ``hello`` with
``welcome`` and every message it refuses with a ``nack``, and sends the
answers the other stages hand it (`ingest.acknowledge`) in the order they come.

A data message it takes in goes to the checking stage's line of its module
(`ingest.fairness`): taking in never waits for a check or a store. A module
that already has `IngestConfig.module_queue_bytes` of data waiting on the
ship is refused ``busy`` (resend after a pause), so that a module that floods
the ship holds a bounded part of its memory and time, and every other module
is served as usual. With CURVE it also answers the link's ZAP requests
(`ingest.gatekeeper`). Nothing a message holds can stop this thread: a
failure while handling one message is caught at the message's boundary,
counted, logged (rate-limited) and answered with ``internal_error``.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import zmq

from camcal.core import wire
from camcal.core.clockmap import handshake_clock
from camcal.core.ratelog import RateLimitedLog
from camcal.core.wire.sockets import route_is_safe, route_module
from ingest.counters import Counters
from ingest.fairness import FairQueue
from ingest.links import Link
from ingest.messages import DataIn, Note, nack

if TYPE_CHECKING:
    from ingest.config import IngestConfig
    from ingest.gatekeeper import Gatekeeper

log = logging.getLogger("camcal.ingest")


class Receiver:
    """Runs in the ``ingest-receive`` thread; see the module docstring."""

    def __init__(
        self,
        config: IngestConfig,
        counters: Counters,
        router: Any,
        answers: Any,
        checkq: FairQueue[DataIn | Note],
        *,
        dive_name: str,
        instance: str,
        window: Callable[[str], int],
        gatekeeper: Gatekeeper | None = None,
    ) -> None:
        self.config = config
        self.counters = counters
        self.router = router
        self.answers = answers  # the PULL end of `ingest.acknowledge`
        self.checkq = checkq
        self.dive_name = dive_name
        self.instance = instance
        self.window = window
        self.gatekeeper = gatekeeper  # None: a plaintext link (lab bench)
        self.links: dict[str, Link] = {}
        self.links_lock = threading.Lock()
        self.warn = RateLimitedLog(log)

    def run(self, stop: threading.Event, started: threading.Event) -> None:
        poller = zmq.Poller()
        poller.register(self.router, zmq.POLLIN)
        poller.register(self.answers, zmq.POLLIN)
        gate = self.gatekeeper.sockets if self.gatekeeper else ()
        for sock in gate:
            poller.register(sock, zmq.POLLIN)
        started.set()
        while not stop.is_set():
            events = dict(poller.poll(50))
            if self.gatekeeper and any(sock in events for sock in gate):
                self._guarded("gatekeeper", self.gatekeeper.handle)
            if self.answers in events:  # answers first: they free the modules' windows
                for _ in range(1024):
                    try:
                        parts = self.answers.recv_multipart(zmq.NOBLOCK)
                    except zmq.Again:
                        break
                    self._guarded("send", self._answer, parts)
            if self.router in events:
                for _ in range(256):
                    try:
                        parts = self.router.recv_multipart(zmq.NOBLOCK, copy=False)
                    except zmq.Again:
                        break
                    self.on_message(parts)
            self._guarded("timers", self._timers)

    def _guarded(self, what: str, fn: Any, *args: Any) -> None:
        try:
            fn(*args)
        except Exception:
            self.counters.inc("handler_errors")
            self.warn(logging.ERROR, what, "ingest receiving thread: %s failed", what, exc_info=True)

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
            msg, payload = wire.decode_header(
                frames, allowed=wire.MODULE_TYPES, max_payload_bytes=self.config.max_payload_bytes
            )
        except wire.ProtocolError as exc:
            self.refuse(identity, exc.kind, exc.detail, exc.ref, malformed=True)
            return
        module = msg.module
        ref = wire.message_ref(msg)
        if user is not None and module != user:
            self.counters.inc("impostor_messages")
            self.refuse(
                identity,
                "wrong_identity",
                f"module {module!r} on a connection whose key belongs to module {user!r}",
                ref,
            )
            return
        if route_module(identity) != module or not route_is_safe(identity):
            self.refuse(
                identity,
                "wrong_identity",
                f"module {module!r} on a connection whose routing id is {identity[:64]!r}: a module "
                "sets its socket's routing id to its module id, '/' and 32 random hex digits, new at "
                "every start (a route that can be guessed can be taken over)",
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
        dive = self.dive_name
        if msg.dive is not None and msg.dive != dive:
            self.refuse(
                identity,
                "wrong_dive",
                f"this ingest ({self.instance}) records dive {dive!r}; module {module} was started "
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
            self._note(Note("link", module, info={"up": True}, received_unix_s=t_unix, received_mono=t_mono))
        kind = msg.type
        if kind in ("frame", "sensors"):
            self._take_data(link, identity, msg, payload, t_unix, t_mono)
            return
        if kind == "hello":
            if msg.boot != link.clock_boot:  # a new boot: its clock as it describes it
                c = msg.clock
                link.clock = handshake_clock(c and c.rate, c and c.reads.timestamp(), c and c.at.timestamp())
            link.clock_reading(msg.boot, msg.sent_at.timestamp(), t_unix)
            link.boot, link.welcomed = msg.boot, True
            link.schedule = msg.schedule.model_dump()
            link.outbox_pending, link.last_seq = msg.outbox_pending, msg.last_seq
            self._welcome(link)
        elif kind == "heartbeat":
            self._heartbeat(link, msg, t_unix)
        elif kind == "bye":
            if msg.boot != link.boot:  # an old boot's goodbye (or someone else's): the module stays
                self.refuse(
                    identity,
                    "invalid_field",
                    f"bye for boot {msg.boot!r}, but module {module}'s link is boot {link.boot!r}: "
                    "it stays linked",
                    ref,
                )
                return
            link.up, link.welcomed, link.down_reason = False, False, "bye"
            self._note(Note("link", module, info=down_notice(link, "bye"), received_unix_s=t_unix))
            return
        self._note(Note(kind, module, msg, received_unix_s=t_unix, received_mono=t_mono))

    def _heartbeat(self, link: Link, msg: Any, t_unix: float) -> None:
        # Module clock minus what the ship expects of it (`camcal.core.clockmap`). A heartbeat queued
        # behind frames on a busy link (a catch-up after an outage) arrives late and reads as a clock
        # behind, never ahead: the least delayed of the recent beats (the largest reading) is the
        # estimate, as NTP's minimum-delay filter does.
        link.clock_reading(msg.boot, msg.sent_at.timestamp(), t_unix)
        link.schedule = msg.schedule.model_dump()
        link.outbox_pending, link.in_flight, link.boot = msg.outbox_pending, msg.in_flight, msg.boot
        link.last_seq = msg.last_seq
        link.card_skipped, link.card_error = msg.card_skipped, msg.card_error
        link.capture_errors, link.camera_error = msg.capture_errors, msg.camera_error
        link.sensor_errors, link.sensor_error = msg.sensor_errors, msg.sensor_error
        link.deferred_shots = msg.deferred_shots
        link.waiting = msg.waiting.model_dump() if msg.waiting else None
        if not link.welcomed:  # the ship restarted under a running module: greet it again
            self._welcome(link)

    def _take_data(
        self, link: Link, identity: bytes, msg: Any, payload: Any, t_unix: float, t_mono: float
    ) -> None:
        """Hand a data message to the checking stage, unless the module holds too much on the ship."""
        key, nbytes = (msg.boot, msg.seq), len(payload)
        if not link.welcomed:
            self.refuse(
                identity,
                "no_hello",
                f"module {link.module} sent data before hello (or since its link was lost, or the ship "
                "restarted): say hello, wait for welcome, then resend",
                wire.message_ref(msg),
            )
            return
        if key not in link.unanswered and len(link.unanswered) >= self.config.window:
            self.refuse(
                identity,
                "over_window",
                f"module {link.module} has {len(link.unanswered)} data messages unanswered, the window is "
                f"{self.config.window}: send the next once an answer came",
                wire.message_ref(msg),
            )
            return
        if (
            link.unanswered
            and key not in link.unanswered
            and link.unanswered_bytes + nbytes > self.config.module_queue_bytes
        ):
            link.busy_refused += 1
            self.refuse(
                identity,
                "busy",
                f"the ship holds {link.unanswered_bytes / 1e6:.1f} MB of module {link.module}'s data not "
                f"yet stored (at most {self.config.module_queue_bytes / 1e6:.0f} MB a module): resend "
                "it once those are acknowledged",
                wire.message_ref(msg),
            )
            return
        self.counters.inc("frames_received" if msg.type == "frame" else "sensor_batches_received")
        if msg.type == "frame":
            link.frames.append(t_mono)
            link.last_frame_unix_s = t_unix
        if key not in link.unanswered:
            link.unanswered[key] = nbytes
            link.unanswered_bytes += nbytes
        self.checkq.put(link.module, DataIn(msg, payload, t_unix, t_mono, nbytes, link.clock_map()))

    def _note(self, note: Note) -> None:
        self.checkq.put(note.module, note)  # behind the module's data received before it

    def _welcome(self, link: Link) -> None:
        link.welcomed = True
        self._send(
            link.identity,
            wire.Welcome(
                module="ship",
                window=self.window(link.module),
                heartbeat_s=self.config.heartbeat_s,
                ingest=self.instance,
                dive=self.dive_name,
            ),
        )

    # -- sending ---------------------------------------------------------
    def _send(self, identity: bytes, msg: Any) -> None:
        try:
            self.router.send_multipart([identity, *wire.encode(msg)], zmq.NOBLOCK)
        except zmq.Again:
            self.counters.inc("send_dropped")

    def _answer(self, parts: list[bytes]) -> None:
        """An answer (or a command) another stage made: settle the data messages it answers, send it."""
        module = parts[0].decode()
        link = self.links.get(module)
        if link is None:
            self.counters.inc("send_unknown_module")
            return
        for boot, seq in json.loads(parts[1]):
            link.settle(boot, seq)
        try:
            self.router.send_multipart([link.identity, *parts[2:]], zmq.NOBLOCK)
        except zmq.Again:
            self.counters.inc("send_dropped")

    def _timers(self) -> None:
        now = time.monotonic()
        for link in list(self.links.values()):
            if link.up and now - link.last_seen_mono > self.config.link_timeout_s:
                link.up, link.welcomed, link.down_reason = False, False, "timeout"
                self._note(
                    Note("link", link.module, info=down_notice(link, "timeout"), received_unix_s=time.time())
                )
            if link.up and now - link.last_heartbeat_sent >= self.config.heartbeat_s:
                link.last_heartbeat_sent = now
                self._send(link.identity, wire.ShipHeartbeat(module="ship", window=self.window(link.module)))


def down_notice(link: Link, reason: str) -> dict[str, Any]:
    """A link-down notice, with how far the module said it had got (for the store's gaps)."""
    return {"up": False, "reason": reason, "boot": link.boot, "last_seq": link.last_seq}


def _user_id(frame: zmq.Frame) -> str:
    """The module the connection's key belongs to ("" if the handshake named none)."""
    try:
        value = frame.get("User-Id")
    except zmq.ZMQError:
        return ""
    return value if isinstance(value, str) else ""
