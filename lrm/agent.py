"""The LRM agent: runs the schedule, samples the sensors, writes the outbox, talks to the ship.

Three threads: **capture** (the schedule runner on the camera backend, or a
replayed frame set), **sensors** (samples at 10 Hz or more, one message a
second), both in `lrm.producing`, and **comm**, which alone owns the ZeroMQ
DEALER socket. Every
frame and sensor packet goes to the outbox (SD card) first and is sent
afterwards; it stays pending until the ship acknowledges it, and everything
pending is sent again after a reconnect or when its acknowledgement is late.
Commands from the ship are answered and applied exactly once. Before it
sends anything but ``hello``, the comm thread checks that the peer is the
right ship (`lrm.shipcheck`): one that speaks the protocol, over CURVE with
the ship's key, and records the dive the module was started for.
"""

from __future__ import annotations

import logging
import queue
import secrets
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import zmq
from pydantic import ValidationError

from camcal.core import __version__, wire
from camcal.core.ratelog import RateLimitedLog
from camcal.core.schedule import CameraLimits, Schedule
from lrm.commands import CommandHandling
from lrm.outbox import Outbox
from lrm.producing import Producing
from lrm.runner import Capture, ScheduleRunner
from lrm.shipcheck import ShipCheck

log = logging.getLogger("camcal.lrm")


def new_boot_id(now: datetime | None = None) -> str:
    """A boot id: UTC start time and random digits, unique per start of the agent."""
    t = (now or datetime.now(UTC)).strftime("%Y%m%dT%H%M%S")
    return f"{t}-{secrets.token_hex(3)}"


#: Resends of a message the ship refused with ``retry``, before the module gives up on it (not for
#: a reason that is the ship's own state, ``until_it_works``: those are resent until they are stored).
MAX_RESENDS = 5
#: Seconds before a message the ship refused as ``busy`` (it holds enough of this module's data) is
#: sent again; it is not a failed try.
BUSY_RETRY_S = 1.0


@dataclass(frozen=True)
class AgentConfig:
    module: str
    connect: str
    outbox: Path
    heartbeat_s: float = 1.0
    link_timeout_s: float = 5.0
    ack_timeout_s: float = 15.0
    hello_interval_s: float = 1.0
    sensor_rate_hz: float = 10.0
    sensor_batch_s: float = 1.0
    initial_window: int = 2
    fsync: bool = True
    #: Resends of a message refused with ``retry`` before giving up on it (`MAX_RESENDS`).
    max_resends: int = MAX_RESENDS
    #: The dive this module is started for: it refuses an ingest of another dive (None: any).
    dive: str | None = None
    #: The link's CURVE keys (`camcal.core.wire.keys`); without them the link is plaintext, which must
    #: be asked for (``plaintext``): a lab bench only.
    keys: wire.ModuleKeys | None = None
    plaintext: bool = False


class Agent(CommandHandling, Producing):
    """One module's agent. `start` runs it in background threads; `stop` ends it cleanly."""

    def __init__(
        self,
        config: AgentConfig,
        *,
        clock: Any,
        runner: ScheduleRunner | None = None,
        source: Callable[[threading.Event], Capture | None] | None = None,
        sensors: Any | None = None,
        camera_limits: CameraLimits | Callable[[], CameraLimits | None] | None = None,
        ctx: zmq.Context[Any] | None = None,
        depth: Callable[[], float | None] | None = None,
        simulated_clock_error_s: float = 0.0,
        camera_info: Callable[[], dict[str, Any] | None] | None = None,
    ) -> None:
        if (runner is None) == (source is None):
            raise ValueError("give the agent either a schedule runner or a replay source")
        if config.keys is None and not config.plaintext:
            raise ValueError(
                "the module link needs keys (camcal keys create, then --keys) or, on a lab bench "
                "only, plaintext=True"
            )
        self.config = config
        self.check = ShipCheck(config.module, config.connect, config.dive, config.keys)
        self.clock = clock
        self.runner = runner
        self._source = source or (lambda stop: runner.next_capture(stop))  # type: ignore[union-attr]
        self.sensors = sensors
        self.camera_limits = camera_limits
        #: What the ship is told of the camera (`wire.CameraInfo`'s fields), asked at every message.
        self.camera_info = camera_info
        self.ctx = ctx or zmq.Context.instance()
        self.depth = depth
        #: Simulation only: a module clock (its real-time clock) this far off, in what the module
        #: stamps and sends (capture and sample times, `sent_at`); the simulated world is not moved.
        self.clock_error = timedelta(seconds=simulated_clock_error_s)
        #: Module-clock seconds per real second: a simulated clock's speed (its hello says so and
        #: what its real-time clock read, so that the ship maps its times onto the ship's own).
        self.clock_rate = float(getattr(clock, "speed", 1.0))
        self.warn = RateLimitedLog(log)
        self.boot = new_boot_id()
        self.outbox = Outbox(config.outbox, config.module, fsync=config.fsync)
        self._seq = 0
        self._seq_lock = threading.RLock()
        self.device_errors: dict[str, str] = {}
        self._device_streak: dict[str, int] = {}
        self._new: queue.SimpleQueue[tuple[str, int]] = queue.SimpleQueue()
        self._stop = threading.Event()
        self._produce_stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self.counters: Counter[str] = Counter()
        self.linked = threading.Event()
        #: When the comm loop last went round (monotonic): a loop that stops is a hung agent (`alive`).
        self.comm_beat = time.monotonic()
        self._commands: dict[str, dict[str, Any]] = {  # (a damaged line of the card is skipped)
            c["command_id"]: c
            for c in self.outbox.read_jsonl("commands.jsonl")
            if isinstance(c, dict) and isinstance(c.get("command_id"), str)
        }
        self._status_out: queue.SimpleQueue[Any] = queue.SimpleQueue()
        if runner is not None:
            saved = self.outbox.load_json("schedule.json")
            if isinstance(saved, dict) and saved.get("schedule"):
                try:
                    sched = Schedule.model_validate(saved["schedule"])
                    if sched.version >= runner.schedule.version:
                        runner.set_schedule(sched)
                        if saved.get("state") in ("paused", "stopped"):
                            runner._set_state(saved["state"])
                except ValidationError:
                    log.warning("ignoring an unreadable saved schedule")
            self._restore_pending(runner)
            runner.on_change = self._schedule_changed
            self._schedule_changed(runner.schedule, runner.state)

    # ------------------------------------------------------------ lifecycle
    def start(self) -> None:
        for name, fn in (
            ("lrm-comm", self._comm_loop),
            ("lrm-capture", self._capture_loop),
            ("lrm-sensors", self._sensor_loop),
        ):
            if fn == self._sensor_loop and self.sensors is None:
                continue
            t = threading.Thread(target=self._guard(fn), name=f"{name}-{self.config.module}", daemon=True)
            t.start()
            self._threads.append(t)

    def _guard(self, fn: Callable[[], None]) -> Callable[[], None]:
        def run() -> None:
            try:
                fn()
            except Exception:
                log.exception("agent thread %s failed", threading.current_thread().name)
                self._stop.set()

        return run

    def stop_producing(self) -> None:
        """Take no more frames or sensor samples; keep sending what the outbox holds."""
        self._produce_stop.set()

    def stop(self, timeout: float = 10.0) -> None:
        self._produce_stop.set()
        self._stop.set()
        for t in self._threads:
            t.join(timeout)
        self.outbox.close()

    @property
    def stopped(self) -> bool:
        return self._stop.is_set()

    def alive(self, within_s: float = 10.0) -> bool:
        """Whether the agent works: not stopped, every thread it started running (a replay's capture
        thread may have finished) and its comm loop round within ``within_s``. A service manager's
        watchdog is fed only while this holds (`camcal.cli.lrm_run`)."""
        running = all(t.is_alive() for t in self._threads if not t.name.startswith("lrm-capture"))
        return not self.stopped and running and time.monotonic() - self.comm_beat <= within_s

    def _camera(self) -> wire.CameraInfo | None:
        """The camera as the ship is told of it (None: not known, or not one a message can carry)."""
        if self.camera_info is None:
            return None
        try:
            info = self.camera_info()
            return wire.CameraInfo(**info) if info else None
        except (ValidationError, TypeError, ValueError) as exc:
            self.warn(logging.WARNING, "camera_info", "camera info not sent: %s", str(exc).splitlines()[0])
            return None

    @property
    def refusal(self) -> Any:
        """Why the module refuses the peer it is connected to (`lrm.shipcheck.Refusal`), or None."""
        return self.check.refusal

    def capture_done(self) -> bool:
        """True when the capture thread has finished (a replay reached its end)."""
        return not any(t.is_alive() for t in self._threads if t.name.startswith("lrm-capture"))

    def wait_drained(self, timeout: float) -> bool:
        """Wait until the ship has acknowledged everything in the outbox."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if self.outbox.pending_count() == 0:
                return True
            time.sleep(0.05)
        return self.outbox.pending_count() == 0

    # ------------------------------------------------------------ comm
    def _comm_loop(self) -> None:
        cfg = self.config
        check = self.check
        sock = check.open(self.ctx)
        send_q: deque[tuple[str, int]] = deque((e.boot, e.seq) for e in self.outbox.pending())
        queued = set(send_q)
        in_flight: dict[tuple[str, int], float] = {}
        retry_at: dict[tuple[str, int], float] = {}  # nacked with retry: resend after a back-off
        tries: Counter[tuple[str, int]] = Counter()
        window = cfg.initial_window
        welcomed = False
        last_ship = last_hello = last_beat = 0.0
        poller = zmq.Poller()
        poller.register(sock, zmq.POLLIN)
        dive = {"dive": cfg.dive} if cfg.dive else {}

        def requeue(keys: list[tuple[str, int]]) -> None:
            for k in sorted(keys, reverse=True):
                in_flight.pop(k, None)
                if k not in queued:
                    send_q.appendleft(k)
                    queued.add(k)
            self.counters["resends_queued"] += len(keys)

        try:
            while not self._stop.is_set():
                self.comm_beat = time.monotonic()
                while True:
                    try:
                        k = self._new.get_nowait()
                    except queue.Empty:
                        break
                    if k not in queued and k not in in_flight:
                        send_q.append(k)
                        queued.add(k)
                now = time.monotonic()
                check.watch()
                if check.renew_due():  # a failed handshake libzmq may not retry: a new socket
                    poller.unregister(sock)
                    check.close(sock)
                    sock = check.open(self.ctx)
                    poller.register(sock, zmq.POLLIN)
                if dict(poller.poll(20)).get(sock):
                    for _ in range(256):
                        try:
                            parts = sock.recv_multipart(zmq.NOBLOCK)
                        except zmq.Again:
                            break
                        try:
                            msg, _ = wire.decode(parts, allowed=wire.SHIP_TYPES)
                        except wire.ProtocolError as exc:
                            self.counters[f"bad_{exc.kind}"] += 1
                            check.foreign_message(welcomed)
                            continue
                        last_ship = time.monotonic()
                        if msg.type == "welcome":
                            if not check.accept_welcome(msg):
                                welcomed = False
                                self.linked.clear()
                                requeue(list(in_flight))
                                continue
                            window = msg.window
                            if in_flight:
                                requeue(list(in_flight))
                            welcomed = True
                            self.linked.set()
                        elif msg.type == "ack":
                            window = msg.window
                            for boot, first, last in msg.ranges:
                                self._card_record("an acknowledgement", self.outbox.ack, boot, first, last)
                                for q in range(first, last + 1):
                                    if in_flight.pop((boot, q), None) is not None:
                                        self.counters["acked"] += 1
                        elif msg.type == "nack":
                            self._on_nack(msg, in_flight, retry_at, tries)
                            if msg.reason == "wrong_dive":
                                check.wrong_dive(msg)
                            if msg.reason in ("not_served", "wrong_dive"):
                                # The wrong ingest: keep everything, say hello until the right one.
                                welcomed = False
                                self.linked.clear()
                                requeue(list(in_flight))
                        elif msg.type == "ship_heartbeat":
                            window = msg.window
                        elif msg.type == "command":
                            self._on_command(msg)
                now = time.monotonic()
                if welcomed and now - last_ship > cfg.link_timeout_s:
                    welcomed = False
                    self.linked.clear()
                    self.counters["link_lost"] += 1
                    requeue(list(in_flight))
                if not welcomed and now - last_hello >= cfg.hello_interval_s:
                    last_hello = now
                    self._send(
                        sock,
                        wire.Hello(
                            module=cfg.module,
                            boot=self.boot,
                            software=f"camcal {__version__}",
                            schedule=self._schedule_state(),
                            outbox_pending=self.outbox.pending_count(),
                            last_seq=self._seq,
                            camera=self._camera(),
                            **dive,
                        ),
                    )
                if now - last_beat >= cfg.heartbeat_s:
                    last_beat = now
                    self._send(
                        sock,
                        wire.ModuleHeartbeat(
                            module=cfg.module,
                            boot=self.boot,
                            schedule=self._schedule_state(),
                            outbox_pending=self.outbox.pending_count(),
                            in_flight=len(in_flight),
                            last_seq=self._seq,
                            card_skipped=self.counters["card_skipped"],
                            card_error=self.device_errors.get("card"),
                            capture_errors=self.counters["capture_errors"],
                            camera_error=self.device_errors.get("camera"),
                            sensor_errors=self.counters["sensor_errors"],
                            sensor_error=self.device_errors.get("sensors"),
                            deferred_shots=self.runner.deferred_shots if self.runner is not None else 0,
                            camera=self._camera(),
                            waiting=self._waiting(),
                            **dive,
                        ),
                    )
                late = [k for k, t in in_flight.items() if now - t > cfg.ack_timeout_s]
                if late:
                    requeue(late)
                due = [k for k, t in retry_at.items() if t <= now]
                for k in due:
                    del retry_at[k]
                if due:
                    requeue(due)
                while True:
                    try:
                        status = self._status_out.get_nowait()
                    except queue.Empty:
                        break
                    self._send(sock, status)
                while welcomed and send_q and len(in_flight) < window:
                    key = send_q.popleft()
                    queued.discard(key)
                    entry = self.outbox.get(*key)
                    if entry is None:  # acknowledged meanwhile
                        continue
                    try:
                        header, payload = self.outbox.message(entry, cfg.module)
                        if dive:  # the ship refuses a message of another dive than its own
                            header = header.model_copy(update=dive)
                    except (OSError, ValueError) as exc:  # the SD card lost or damaged it
                        why = " ".join(str(exc).split())  # (a validation error's lines, on one)
                        self.warn(
                            logging.ERROR,
                            "unsendable",
                            "outbox entry %s/%d cannot be sent, skipped: %s",
                            key[0],
                            key[1],
                            why,
                        )
                        self.outbox.discard(*key)
                        self.counters["unsendable"] += 1
                        continue
                    try:
                        sock.send_multipart(wire.encode(header, payload), zmq.NOBLOCK)
                    except zmq.Again:
                        send_q.appendleft(key)
                        queued.add(key)
                        break
                    in_flight[key] = time.monotonic()
                    self.counters["sent"] += 1
            if welcomed:
                self._send(sock, wire.Bye(module=cfg.module, boot=self.boot, **dive))
                time.sleep(0.05)
        finally:
            check.close(sock)

    def _on_nack(
        self,
        msg: wire.Nack,
        in_flight: dict[tuple[str, int], float],
        retry_at: dict[tuple[str, int], float],
        tries: Counter[tuple[str, int]],
    ) -> None:
        """The ship refused a message: resend later if that can help, else settle it as refused.

        A resend backs off (1, 2, 4 ... 30 s) and gives up after ``max_resends``
        tries: an SD copy that is damaged would otherwise be sent for ever. A
        reason that is the ship's own state (a full disk, a database being
        restarted: ``internal_error``) is resent every 30 s at most until it is
        stored, however long the ship needs. A refused entry stays on the card
        (``refused.jsonl`` says why).
        """
        self.counters["nacked"] += 1
        self.counters[f"nacked_{msg.reason}"] += 1
        if msg.reason == "wrong_dive":  # nothing to settle: the message waits for the right ingest
            if msg.boot is not None and msg.seq is not None:
                in_flight.pop((msg.boot, msg.seq), None)
            return
        if msg.boot is None or msg.seq is None:  # not one of our data messages (a hello, a heartbeat...)
            log.warning("ship refused a %s: %s: %s", msg.of or "message", msg.reason, msg.detail)
            return
        key = (msg.boot, msg.seq)
        in_flight.pop(key, None)
        if msg.reason == "busy":  # the ship holds enough of ours for now: again in a second, no try lost
            retry_at[key] = time.monotonic() + BUSY_RETRY_S
            return
        tries[key] += 1
        reason = wire.REASONS.get(msg.reason)
        until_it_works = reason is not None and reason.until_it_works
        if msg.retry and (tries[key] <= self.config.max_resends or until_it_works):
            retry_at[key] = time.monotonic() + min(2.0 ** (tries[key] - 1), 30.0)
            return
        self.warn(  # (a clock never set has every message refused alike: a line per 10 s, not each)
            logging.ERROR,
            f"refused:{msg.reason}",
            "ship refused %s/%d for good: %s: %s (kept on the card)",
            *key,
            msg.reason,
            msg.detail,
        )
        self._card_record("a refusal", self.outbox.refuse, msg.boot, msg.seq, msg.reason, msg.detail)
        self.counters["refused"] += 1
        retry_at.pop(key, None)

    def _waiting(self) -> wire.Waiting | None:
        """Why the schedule runner takes no picture now (None: it does, or it does not run)."""
        w = self.runner.waiting() if self.runner is not None else None
        return wire.Waiting(**w) if w else None

    def _send(self, sock: Any, msg: Any) -> None:
        if self.clock_rate != 1.0 or self.clock_error:  # (simulation only) its own clock, not the host's
            update: dict[str, Any] = {"sent_at": self.clock.now() + self.clock_error}
            if msg.type == "hello" and self.clock_rate != 1.0:  # its clock and real time at one instant
                clock = wire.SimulatedClock(rate=self.clock_rate, reads=self.clock.now(), at=wire.utc_now())
                update["clock"] = clock
            msg = msg.model_copy(update=update)
        try:
            sock.send_multipart(wire.encode(msg), zmq.NOBLOCK)
        except zmq.Again:
            self.counters["control_dropped"] += 1
