"""The ingest service: receive, commit, acknowledge, analyse, publish.

Three kinds of worker, each owning what it touches:

* the **network thread** owns the ZeroMQ ROUTER: it decodes and checks
  every message (malformed ones are counted and dropped), answers ``hello``
  with ``welcome``, keeps track of links and heartbeats, and sends whatever
  the other threads hand it (acks, commands) through an inproc socket;
* the **store thread** is the single database writer: it writes each
  frame file (temporary name, fsync, rename), commits a batch of frames and
  sensor samples in one transaction, and only then acknowledges them; it
  also stores analysis results, the rolling λ_att, linearity, attitude and
  alarms, and publishes every new result as an event;
* a **process pool** (one process per core) decodes and analyses frames off
  the receive loop.

Several ingest processes may share one database (PostgreSQL) and one data
folder, each serving its own set of modules (``modules``; see
``docs/scaling.md``). A process refuses modules it does not serve: their
``hello`` gets no ``welcome`` and their data no ``ack``, so a wrongly wired
module keeps everything in its outbox. Recovery after a crash, temporary
files, gaps and alarms are scoped to the served modules; the dive (by name)
and its live run are shared.
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
import os
import queue
import shutil
import socket
import threading
import time
import uuid
from collections import Counter, defaultdict, deque
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import zmq

from analysis import FrameConfig
from analysis.attitude import attitude_from_samples
from camcal import __version__, wire
from camcal.calibrations import setup_of
from camcal.frameset import Setup
from camcal.parallel import process_pool
from ingest.alarms import AlarmEvaluator, AlarmLimits
from ingest.derived import linearity_rows
from ingest.events import EventBus
from ingest.rolling import Changes, Sample, VisitSeries
from ingest.seqtrack import SeqTracker
from ingest.worker import analyse_stored_frame, warm_up
from storage.models import AnalysisRun, Dive
from storage.store import FrameRow, SensorBatchRow, Store

log = logging.getLogger("camcal.ingest")


@dataclass(frozen=True)
class IngestConfig:
    """Settings of one ingest process."""

    data_dir: Path
    bind: str = "tcp://*:5555"
    events_bind: str | None = "tcp://127.0.0.1:5556"
    db_url: str | None = None
    window: int = 8
    heartbeat_s: float = 1.0
    link_timeout_s: float = 5.0
    ack_batch_s: float = 0.02
    workers: int = 0
    max_payload_bytes: int = wire.MAX_PAYLOAD_BYTES
    fsync: bool = True
    sqlite_synchronous: str = "FULL"
    dive_name: str | None = None
    setup: Setup = field(default_factory=Setup)
    visit_idle_close_s: float = 60.0  # no frame result for this long: the open λ_att visits are final
    command_retry_s: float = 3.0
    retention_days: float | None = None
    calibration: str | None = None
    thumbnails: bool = True
    alarm_limits: AlarmLimits = field(default_factory=AlarmLimits)
    modules: tuple[str, ...] = ()  # the modules this process serves; empty: any module

    @property
    def n_workers(self) -> int:
        return self.workers or os.cpu_count() or 1

    def serves(self, module: str) -> bool:
        return not self.modules or module in self.modules


@dataclass
class Link:
    """What the ship knows of one module's connection."""

    module: str
    identity: bytes
    boot: str = ""
    up: bool = False
    last_seen_mono: float = 0.0
    last_seen_unix_s: float = 0.0
    welcomed: bool = False
    schedule: dict[str, Any] = field(default_factory=dict)
    outbox_pending: int = 0
    in_flight: int = 0
    last_seq: int = 0  # the highest sequence number of ``boot`` the module says it has produced
    frames: deque[float] = field(default_factory=lambda: deque(maxlen=200))
    last_heartbeat_sent: float = 0.0
    clock_offset_s: float | None = None


@dataclass
class _Incoming:
    kind: str
    module: str
    msg: Any
    payload: Any = None
    received_unix_s: float = 0.0
    received_mono: float = 0.0


class IngestService:
    """One ingest process; `start` binds and runs it in background threads, `stop` ends it."""

    def __init__(
        self, config: IngestConfig, store: Store | None = None, ctx: zmq.Context[Any] | None = None
    ) -> None:
        self.config = config
        self.store = store or Store.open(
            config.data_dir, config.db_url, sqlite_synchronous=config.sqlite_synchronous
        )
        self.ctx = ctx or zmq.Context.instance()
        self._own_ctx = ctx is None
        self._stop = threading.Event()
        self._q: queue.Queue[_Incoming] = queue.Queue()
        self._out_endpoint = f"inproc://ingest-out-{uuid.uuid4().hex}"
        self.links: dict[str, Link] = {}
        self._links_lock = threading.Lock()
        self.counters: Counter[str] = Counter()
        self.malformed: Counter[str] = Counter()
        self.refused: Counter[str] = Counter()
        self.window = config.window
        self.endpoint = ""
        self.events_endpoint = ""
        self._threads: list[threading.Thread] = []
        self._pool: Any = None
        self._analysis_inflight = 0
        self._analysis_backlog: deque[tuple[int, str, dict[str, Any]]] = deque()
        self.latency_s: deque[float] = deque(maxlen=2000)
        self.started = threading.Event()
        self.error: BaseException | None = None
        self.disk_free_gb: float | None = None

    # ------------------------------------------------------------ lifecycle
    def start(self) -> None:
        """Bind the sockets (so `endpoint` is known), then run the threads."""
        calibration = None
        if self.config.calibration:  # before binding anything: a wrong name leaves nothing open
            calibration = self.store.calibration(self.config.calibration)
            if calibration is None:
                raise ValueError(
                    f"no calibration {self.config.calibration!r} in the store (see `camcal calibration list`)"
                )
            self.config = dataclasses.replace(self.config, setup=setup_of(calibration))
        self.store.files.remove_temporaries(self.config.modules)
        self._router = wire.ship_socket(
            self.ctx,
            self.config.bind,
            max_message_bytes=self.config.max_payload_bytes + wire.MAX_HEADER_BYTES,
        )
        self.endpoint = self._router.getsockopt(zmq.LAST_ENDPOINT).decode()
        self._pull = self.ctx.socket(zmq.PULL)
        self._pull.bind(self._out_endpoint)
        self._pub = None
        if self.config.events_bind:
            self._pub = self.ctx.socket(zmq.PUB)
            self._pub.setsockopt(zmq.SNDHWM, 10000)
            self._pub.setsockopt(zmq.LINGER, 0)
            self._pub.bind(self.config.events_bind)
            self.events_endpoint = self._pub.getsockopt(zmq.LAST_ENDPOINT).decode()
        setup = self.config.setup
        dive = self.store.current_dive(create=True, name=self.config.dive_name, setup=setup.to_json())
        assert dive is not None  # create=True
        self.dive: Dive = dive
        run = self.store.analysis_run(
            dive.id, "live", software_version=__version__, calibration=setup.to_json()
        )
        assert run is not None
        self.run: AnalysisRun = run
        if calibration is not None and self.run.calibration_id != calibration["id"]:
            self.store.use_calibration(self.dive.id, self.run.id, calibration["id"], actor="ingest")
        self._pool = process_pool(self.config.n_workers)
        # Start the fork server and the workers now: started by the first frame, they would make
        # the first results of a dive wait a second or more (the fork server imports the analysis).
        for _ in range(self.config.n_workers):
            self._pool.submit(warm_up)
        for name, target in (("ingest-net", self._net_loop), ("ingest-store", self._store_loop)):
            t = threading.Thread(target=self._guard(target), name=name, daemon=True)
            t.start()
            self._threads.append(t)
        self.started.wait(10)
        log.info(
            "ingest listening on %s, events on %s, dive %s",
            self.endpoint,
            self.events_endpoint,
            self.dive.name,
        )

    def _guard(self, fn: Callable[[], None]) -> Callable[[], None]:
        def run() -> None:
            try:
                fn()
            except BaseException as exc:  # a dead thread must not go unnoticed
                log.exception("ingest thread %s failed", threading.current_thread().name)
                self.error = exc
                self._stop.set()

        return run

    def stop(self, timeout: float = 10.0) -> None:
        """Stop receiving, finish storing what arrived, wait for running analyses."""
        self._stop.set()
        for t in self._threads:
            t.join(timeout)
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
        for sock in (
            getattr(self, "_router", None),
            getattr(self, "_pull", None),
            getattr(self, "_pub", None),
        ):
            if sock is not None:
                sock.close(0)
        self.store.close()

    def wait(self) -> None:
        while not self._stop.wait(0.5):
            pass
        if self.error is not None:
            raise RuntimeError(f"ingest stopped: {self.error}") from self.error

    # ------------------------------------------------------------ network thread
    def _net_loop(self) -> None:
        router, pull = self._router, self._pull
        poller = zmq.Poller()
        poller.register(router, zmq.POLLIN)
        poller.register(pull, zmq.POLLIN)
        self.started.set()
        allowed = wire.MODULE_TYPES
        while not self._stop.is_set():
            events = dict(poller.poll(50))
            if router in events:
                for _ in range(256):
                    try:
                        parts = router.recv_multipart(zmq.NOBLOCK, copy=False)
                    except zmq.Again:
                        break
                    self._on_message(router, parts, allowed)
            if pull in events:
                for _ in range(1024):
                    try:
                        parts = pull.recv_multipart(zmq.NOBLOCK)
                    except zmq.Again:
                        break
                    self._send_to_module(router, parts[0].decode(), parts[1:])
            self._net_timers(router)

    def _on_message(self, router: Any, parts: list[zmq.Frame], allowed: frozenset[str]) -> None:
        identity = parts[0].bytes
        t_mono, t_unix = time.monotonic(), time.time()
        self.counters["messages"] += 1
        try:
            msg, payload = wire.decode(
                parts[1:], allowed=allowed, max_payload_bytes=self.config.max_payload_bytes
            )
        except wire.ProtocolError as exc:
            self.malformed[exc.kind] += 1
            self.counters["malformed"] += 1
            if self.malformed[exc.kind] <= 5 or self.malformed[exc.kind] % 100 == 0:
                log.warning("dropped malformed message from %r: %s", identity[:40], exc)
            return
        module = msg.module
        if not self.config.serves(module):
            self.refused[module] += 1
            self.counters["refused"] += 1
            if self.refused[module] == 1:
                log.warning(
                    "refusing module %s: this ingest serves %s", module, ", ".join(self.config.modules)
                )
            return
        with self._links_lock:
            link = self.links.get(module)
            if link is None or link.identity != identity:
                link = self.links[module] = Link(module, identity, boot=getattr(msg, "boot", ""))
            was_up = link.up
            link.up = True
            link.last_seen_mono, link.last_seen_unix_s = t_mono, t_unix
        if not was_up:
            self._q.put(_Incoming("link", module, {"up": True}, None, t_unix, t_mono))
        kind = msg.type
        if kind == "hello":
            link.boot, link.welcomed = msg.boot, True
            link.schedule = msg.schedule.model_dump()
            link.outbox_pending, link.last_seq = msg.outbox_pending, msg.last_seq
            self._send(
                router,
                identity,
                wire.Welcome(module="ship", window=self.window, heartbeat_s=self.config.heartbeat_s),
            )
            self._q.put(_Incoming("hello", module, msg, None, t_unix, t_mono))
        elif kind == "heartbeat":
            # Module clock minus ship clock (network delay is small on a fibre): smoothed.
            offset = msg.sent_at.timestamp() - t_unix
            link.clock_offset_s = (
                offset if link.clock_offset_s is None else 0.8 * link.clock_offset_s + 0.2 * offset
            )
            link.schedule = msg.schedule.model_dump()
            link.outbox_pending, link.in_flight, link.boot = msg.outbox_pending, msg.in_flight, msg.boot
            link.last_seq = msg.last_seq
            if not link.welcomed:  # the ship restarted under a running module: greet it again
                link.welcomed = True
                self._send(
                    router,
                    identity,
                    wire.Welcome(module="ship", window=self.window, heartbeat_s=self.config.heartbeat_s),
                )
            self._q.put(_Incoming("heartbeat", module, msg, None, t_unix, t_mono))
        elif kind in ("frame", "sensors"):
            self.counters["frames_received" if kind == "frame" else "sensor_batches_received"] += 1
            if kind == "frame":
                link.frames.append(t_mono)
            self._q.put(_Incoming(kind, module, msg, payload, t_unix, t_mono))
        elif kind == "command_status":
            self._q.put(_Incoming(kind, module, msg, None, t_unix, t_mono))
        elif kind == "bye":
            link.up = False
            self._q.put(_Incoming("link", module, self._down(link, "bye"), None, t_unix, t_mono))

    def _send(self, router: Any, identity: bytes, msg: Any) -> None:
        try:
            router.send_multipart([identity, *wire.encode(msg)], zmq.NOBLOCK)
        except zmq.Again:
            self.counters["send_dropped"] += 1

    def _send_to_module(self, router: Any, module: str, frames: list[bytes]) -> None:
        link = self.links.get(module)
        if link is None:
            self.counters["send_unknown_module"] += 1
            return
        try:
            router.send_multipart([link.identity, *frames], zmq.NOBLOCK)
        except zmq.Again:
            self.counters["send_dropped"] += 1

    def _net_timers(self, router: Any) -> None:
        now = time.monotonic()
        for link in list(self.links.values()):
            if link.up and now - link.last_seen_mono > self.config.link_timeout_s:
                link.up, link.welcomed = False, False
                down = self._down(link, "timeout")
                self._q.put(_Incoming("link", link.module, down, None, time.time(), now))
            if link.up and now - link.last_heartbeat_sent >= self.config.heartbeat_s:
                link.last_heartbeat_sent = now
                self._send(router, link.identity, wire.ShipHeartbeat(module="ship", window=self.window))

    @staticmethod
    def _down(link: Link, reason: str) -> dict[str, Any]:
        """A link-down notice, with how far the module said it had got (for the store thread's gaps)."""
        return {"up": False, "reason": reason, "boot": link.boot, "last_seq": link.last_seq}

    # ------------------------------------------------------------ store thread
    def _store_loop(self) -> None:
        push = self.ctx.socket(zmq.PUSH)
        push.setsockopt(zmq.LINGER, 1000)
        push.connect(self._out_endpoint)
        self._push = push
        self.events = EventBus(self.store, self._pub)
        st = _StoreState(self)
        self._recover_unanalysed()
        last_tick = 0.0
        try:
            while True:
                items = self._drain(timeout=0.05)
                if items:
                    st.handle(items)
                self._feed_pool()
                now = time.monotonic()
                if now - last_tick >= 1.0:
                    last_tick = now
                    st.tick()
                self.events.flush()
                if self._stop.is_set() and self._q.empty():
                    break
        finally:
            push.close()

    def _drain(self, timeout: float) -> list[_Incoming]:
        try:
            first = self._q.get(timeout=timeout)
        except queue.Empty:
            return []
        items = [first]
        deadline = time.monotonic() + self.config.ack_batch_s
        while len(items) < 64:
            left = deadline - time.monotonic()
            try:
                items.append(self._q.get(timeout=max(left, 0)) if left > 0 else self._q.get_nowait())
            except queue.Empty:
                break
        return items

    def send_to_module(self, module: str, msg: Any) -> None:
        """Queue a message for a module (from the store thread)."""
        self._push.send_multipart([module.encode(), *wire.encode(msg)])

    # -- analysis pool ---------------------------------------------------
    def _analysis_config(self, module: str) -> FrameConfig:
        return self.config.setup.frame_config(module)

    def queue_analysis(self, frame_id: int, path: str, meta: dict[str, Any]) -> None:
        self._analysis_backlog.append((frame_id, path, meta))

    def _feed_pool(self) -> None:
        limit = 2 * self.config.n_workers
        while self._analysis_backlog and self._analysis_inflight < limit:
            frame_id, path, meta = self._analysis_backlog.popleft()
            config = self._analysis_config(meta["module"])
            thumb = None
            if self.config.thumbnails:
                thumb = str(self.store.files.root / "thumbs" / f"{frame_id}.jpg")
            fut = self._pool.submit(analyse_stored_frame, str(self.store.files.resolve(path)), config, thumb)
            self._analysis_inflight += 1
            fut.add_done_callback(self._result_callback(frame_id, meta))

    def _result_callback(self, frame_id: int, meta: dict[str, Any]) -> Callable[[Future[Any]], None]:
        def done(fut: Future[Any]) -> None:
            self._q.put(
                _Incoming(
                    "result", meta["module"], (frame_id, meta, fut), None, time.time(), time.monotonic()
                )
            )

        return done

    def _recover_unanalysed(self) -> None:
        """Frames committed before a crash but never analysed go back in the queue."""
        for f in self.store.frames_without_result(self.dive.id, self.run.id, modules=self.config.modules):
            self.queue_analysis(f.id, f.path, _frame_meta_from_row(f))

    # -- status ----------------------------------------------------------
    @property
    def ingest_id(self) -> str:
        """Which ingest this is, for a server that follows several: host, then where modules connect."""
        return f"{socket.gethostname()} {self.config.bind}" + (
            f" ({','.join(self.config.modules)})" if self.config.modules else ""
        )

    def health(self) -> dict[str, Any]:
        """Per-module link state, last packet age, frames/s, queue depths, counters."""
        now = time.monotonic()
        modules = {}
        for m, link in sorted(self.links.items()):
            recent = [t for t in link.frames if now - t <= 10.0]
            modules[m] = {
                "link": "up" if link.up else "down",
                "last_packet_age_s": round(now - link.last_seen_mono, 2) if link.last_seen_mono else None,
                "frames_per_s": round(len(recent) / 10.0, 2),
                "boot": link.boot,
                "schedule": link.schedule,
                "outbox_pending": link.outbox_pending,
                "in_flight": link.in_flight,
                "clock_offset_s": round(link.clock_offset_s, 3) if link.clock_offset_s is not None else None,
                "last_seq": link.last_seq,
            }
        return {
            "ingest_id": self.ingest_id,
            "modules": modules,
            "queues": {
                "store": self._q.qsize(),
                "analysis_backlog": len(self._analysis_backlog),
                "analysis_in_flight": self._analysis_inflight,
            },
            "window": self.window,
            "counters": dict(self.counters),
            "malformed": dict(self.malformed),
            "served_modules": list(self.config.modules),
            "refused": dict(self.refused),
            "dive": {"id": self.dive.id, "name": self.dive.name},
            "disk_free_gb": self.disk_free_gb,
            "latency_p50_s": _pct(self.latency_s, 50),
            "latency_p95_s": _pct(self.latency_s, 95),
        }


def _pct(values: deque[float], q: float) -> float | None:
    return round(float(np.percentile(list(values), q)), 4) if values else None


def _frame_meta_from_row(f: Any) -> dict[str, Any]:
    return {
        "module": f.module_id,
        "seq": f.seq,
        "boot": f.boot,
        "wavelength_nm": f.wavelength_nm,
        "exposure_s": f.exposure_s,
        "gain_db": f.gain_db,
        "depth_m": f.depth_m,
        "captured_unix_s": f.captured_unix_s,
        "width_px": f.width_px,
        "height_px": f.height_px,
        "received_mono": None,
    }


class _StoreState:
    """State of the store thread: sequence tracking, rolling λ_att, alarms, sensor buffers."""

    def __init__(self, svc: IngestService) -> None:
        self.svc = svc
        self.store = svc.store
        self.seqs = SeqTracker()
        self.series: VisitSeries | None = None
        self.last_result_mono = time.monotonic()
        try:
            self.series = VisitSeries(svc.config.setup)
        except ValueError:
            log.warning("no λ_att series: the setup has fewer than two cameras with distances")
        if self.series is not None:  # after a restart: the visits of the frames already analysed
            self._store_points(
                self.series.add(
                    Sample.from_result(r) for r in self.store.result_rows(svc.run.id, svc.dive.id)
                )
            )
        self.alarms = AlarmEvaluator(svc.config.alarm_limits)
        self.active_alarms = {
            a.key for a in self.store.active_alarms() if a.module_id is None or svc.config.serves(a.module_id)
        }
        self.sensors: dict[str, deque[tuple[float, float, float, float, float, float, float]]] = defaultdict(
            lambda: deque(maxlen=20000)
        )
        self.linearity: dict[tuple[str, int], dict[tuple[float, float], list[float]]] = defaultdict(
            lambda: defaultdict(list)
        )
        self.linearity_dirty: set[tuple[str, int]] = set()
        self.recent_committed: deque[tuple[str, str, int]] = deque(maxlen=4096)
        self.recent_set: set[tuple[str, str, int]] = set()
        self.last_sensor_event: dict[str, float] = {}
        self.attitude_t: dict[str, float] = {}
        self.gappy: set[tuple[str, str]] = {
            (g.module_id, g.boot) for g in self.store.open_gaps() if svc.config.serves(g.module_id)
        }
        self.last_housekeeping = -1e18
        self.last_purge = -1e18

    # -- batches ---------------------------------------------------------
    def handle(self, items: list[_Incoming]) -> None:
        data = [i for i in items if i.kind in ("frame", "sensors")]
        if data:
            self._commit(data)
        results = [i for i in items if i.kind == "result"]
        if results:
            self._results(results)
        for i in items:
            if i.kind == "link":
                self._link(i)
            elif i.kind in ("hello", "heartbeat"):
                self._module_info(i)
            elif i.kind == "command_status":
                self._command_status(i)

    def _commit(self, items: list[_Incoming]) -> None:
        svc, files = self.svc, self.store.files
        frames: list[FrameRow] = []
        sensors: list[SensorBatchRow] = []
        writes: list[tuple[str, bytes | memoryview]] = []
        for it in items:
            m = it.msg
            key = (m.module, m.boot, m.seq)
            if it.kind == "frame":
                rel = files.relative_path(svc.dive.id, m.module, m.boot, m.seq, m.encoding)
                if key not in self.recent_set:
                    writes.append((rel, it.payload))
                frames.append(
                    FrameRow(
                        module_id=m.module,
                        boot=m.boot,
                        seq=m.seq,
                        captured_unix_s=m.captured_at.timestamp(),
                        received_unix_s=it.received_unix_s,
                        wavelength_nm=m.wavelength_nm,
                        exposure_s=m.exposure_s,
                        gain_db=m.gain_db,
                        depth_m=m.depth_m,
                        width_px=m.width_px,
                        height_px=m.height_px,
                        path=rel,
                        size_bytes=m.size,
                        sha256=m.sha256,
                        schedule_version=m.schedule_version,
                    )
                )
            else:
                try:
                    rows = wire.parse_sensor_rows(m, it.payload)
                except wire.ProtocolError as exc:
                    svc.malformed[exc.kind] += 1
                    svc.send_to_module(
                        m.module, wire.Nack(module="ship", boot=m.boot, seq=m.seq, reason=exc.detail)
                    )
                    continue
                samples = [_sample_columns(r) for r in rows]
                sensors.append(SensorBatchRow(m.module, m.boot, m.seq, it.received_unix_s, samples))
        files.write_many(writes, fsync=svc.config.fsync)  # every file durable before its row
        outcome = self.store.commit_batch(svc.dive.id, frames, sensors)
        svc.counters["frames_stored"] += len(outcome.new_frames)
        svc.counters["duplicates"] += len(outcome.duplicate_frames) + len(outcome.duplicate_sensor_batches)
        self._ack(items)
        by_key = {(f.module_id, f.boot, f.seq): f for f in frames}
        t_done = time.monotonic()
        for it in items:
            m = it.msg
            key = (m.module, m.boot, m.seq)
            self._remember(key)
            gap = (
                self.seqs.add(m.module, m.boot, m.seq)
                if self.seqs.known(m.module, m.boot)
                else self._seed(m.module, m.boot, m.seq)
            )
            if gap:
                self.store.record_gap(m.module, m.boot, *gap)
                self.gappy.add((m.module, m.boot))
                svc.events.emit(
                    "gap",
                    {"boot": m.boot, "first_seq": gap[0], "last_seq": gap[1]},
                    module=m.module,
                    dive_id=svc.dive.id,
                )
            if it.kind == "frame" and key in outcome.new_frames:
                fid = outcome.new_frames[key]
                f = by_key[key]
                meta = {
                    "module": m.module,
                    "seq": m.seq,
                    "boot": m.boot,
                    "wavelength_nm": m.wavelength_nm,
                    "exposure_s": m.exposure_s,
                    "gain_db": m.gain_db,
                    "depth_m": m.depth_m,
                    "captured_unix_s": f.captured_unix_s,
                    "width_px": m.width_px,
                    "height_px": m.height_px,
                    "received_mono": it.received_mono,
                }
                svc.queue_analysis(fid, f.path, meta)
                svc.events.emit(
                    "frame",
                    {
                        "frame_id": fid,
                        **{k: v for k, v in meta.items() if k != "received_mono"},
                        "schedule_version": m.schedule_version,
                        "stored_latency_s": round(t_done - it.received_mono, 4),
                    },
                    module=m.module,
                    dive_id=svc.dive.id,
                )
        for b in sensors:
            if (b.module_id, b.boot, b.seq) in outcome.new_sensor_batches:
                self._sensor_samples(b)
        for mod, boot in {(i.msg.module, i.msg.boot) for i in items} & self.gappy:
            for gid in self.store.fill_gaps(mod, boot, self.seqs.arrived(mod, boot)):
                svc.events.emit("gap_filled", {"gap_id": gid, "boot": boot}, module=mod, dive_id=svc.dive.id)
            if not self.seqs.missing(mod, boot):
                self.gappy.discard((mod, boot))

    def _seed(self, module: str, boot: str, seq: int) -> tuple[int, int] | None:
        known = self.store.known_seqs(module, boot)
        known.discard(seq)
        self.seqs.seed(module, boot, known)
        return self.seqs.add(module, boot, seq)

    def _remember(self, key: tuple[str, str, int]) -> None:
        if key in self.recent_set:
            return
        if len(self.recent_committed) == self.recent_committed.maxlen:
            self.recent_set.discard(self.recent_committed[0])
        self.recent_committed.append(key)
        self.recent_set.add(key)

    def _ack(self, items: list[_Incoming]) -> None:
        """Acknowledge every committed message, new or duplicate, as ranges per module."""
        per_module: dict[str, dict[str, list[int]]] = defaultdict(lambda: defaultdict(list))
        for it in items:
            per_module[it.msg.module][it.msg.boot].append(it.msg.seq)
        for module, boots in per_module.items():
            ranges: list[tuple[str, int, int]] = []
            for boot, seqs in boots.items():
                seqs = sorted(set(seqs))
                start = prev = seqs[0]
                for q in seqs[1:]:
                    if q != prev + 1:
                        ranges.append((boot, start, prev))
                        start = q
                    prev = q
                ranges.append((boot, start, prev))
            self.svc.send_to_module(
                module, wire.Ack(module="ship", ranges=tuple(ranges), window=self.svc.window)
            )
            self.svc.counters["acks_sent"] += 1

    def _sensor_samples(self, b: SensorBatchRow) -> None:
        buf = self.sensors[b.module_id]
        for s in b.samples:
            t = s.get("t_unix_s")
            ax, ay, az = s.get("acc_x_m_s2"), s.get("acc_y_m_s2"), s.get("acc_z_m_s2")
            if t is None or ax is None or ay is None or az is None:
                continue
            buf.append(
                (
                    t,
                    ax,
                    ay,
                    az,
                    s.get("gyro_x_dps") or 0.0,
                    s.get("gyro_y_dps") or 0.0,
                    s.get("gyro_z_dps") or 0.0,
                )
            )
            if s.get("humidity_pct") is not None:
                self.alarms.observe_humidity(b.module_id, t, s["humidity_pct"])
        if b.samples:
            last = b.samples[-1]
            tlast = last.get("t_unix_s") or 0.0
            if tlast - self.last_sensor_event.get(b.module_id, -1e18) >= 0.5:
                self.last_sensor_event[b.module_id] = tlast
                self.svc.events.transient("sensors", {k: v for k, v in last.items()}, module=b.module_id)

    # -- results ---------------------------------------------------------
    def _results(self, items: list[_Incoming]) -> None:
        svc = self.svc
        rows = []
        done = []
        for it in items:
            frame_id, meta, fut = it.msg
            svc._analysis_inflight -= 1
            try:
                row = fut.result()
            except Exception as exc:  # the worker died or raised: record it, keep going
                log.exception("analysis of frame %s failed", frame_id)
                row = {"status": "rejected", "reason": "analysis_error", "detail": str(exc)[:500]}
            analysis_s = row.pop("analysis_s", None)
            row.pop("width_px", None)
            row.pop("height_px", None)
            rows.append({**row, "frame_id": frame_id, "analysed_unix_s": time.time()})
            done.append((frame_id, meta, row, analysis_s))
        self.store.save_results(svc.run.id, rows)
        now_mono = time.monotonic()
        samples = []
        for frame_id, meta, row, analysis_s in done:
            module = meta["module"]
            if meta.get("received_mono") is not None:
                svc.latency_s.append(now_mono - meta["received_mono"])
            svc.counters["frames_analysed"] += 1
            svc.counters[f"result_{row['status'] if row['status'] == 'ok' else row['reason']}"] += 1
            centroid = (
                (row["centroid_x_px"], row["centroid_y_px"]) if row.get("centroid_x_px") is not None else None
            )
            self.alarms.observe_frame(
                module,
                row["status"],
                row.get("reason"),
                centroid,
                row.get("radius_px"),
                (meta.get("width_px") or 1, meta.get("height_px") or 1),
            )
            svc.events.emit(
                "result",
                {
                    "frame_id": frame_id,
                    "seq": meta["seq"],
                    "wavelength_nm": meta["wavelength_nm"],
                    "exposure_s": meta["exposure_s"],
                    "gain_db": meta["gain_db"],
                    "depth_m": meta["depth_m"],
                    "captured_unix_s": meta["captured_unix_s"],
                    "status": row["status"],
                    "reason": row.get("reason"),
                    "centroid_px": list(centroid) if centroid else None,
                    "radius_px": row.get("radius_px"),
                    "i_center_gray": row.get("i_center_gray"),
                    "i_center_err_gray": row.get("i_center_err_gray"),
                    "background_gray": row.get("background_gray"),
                    "width_px": meta.get("width_px"),
                    "height_px": meta.get("height_px"),
                    "thumb": f"/api/frames/{frame_id}/thumbnail",
                    "analysis_s": round(analysis_s, 4) if analysis_s else None,
                },
                module=module,
                dive_id=svc.dive.id,
            )
            if row.get("center_gray") is not None:
                key = (module, meta["wavelength_nm"])
                self.linearity[key][(meta["exposure_s"], meta["gain_db"])].append(row["center_gray"])
                self.linearity_dirty.add(key)
            samples.append(Sample.from_result({**meta, **row, "frame_id": frame_id}))
        if self.series is not None:
            self.last_result_mono = now_mono
            self._store_points(self.series.add(samples))

    def _store_points(self, changes: Changes) -> None:
        """Store the λ_att visits a batch changed and publish them (``final`` false: provisional)."""
        svc = self.svc
        if not changes:
            return
        rows = [{**r, "run_id": svc.run.id, "dive_id": svc.dive.id} for r in changes.upserts]
        ids = self.store.save_visit_points(svc.run.id, rows, changes.deletes)
        for key in changes.deletes:
            svc.events.emit("attenuation", {"visit_key": key, "deleted": True}, dive_id=svc.dive.id)
        for r in rows:
            svc.events.emit(
                "attenuation",
                {"point_id": ids.get(r["visit_key"]), **{k: v for k, v in r.items() if k != "details"}},
                dive_id=svc.dive.id,
            )

    # -- links and modules ----------------------------------------------
    def _link(self, it: _Incoming) -> None:
        info = it.msg
        self.svc.events.emit(
            "link",
            {"state": "up" if info["up"] else "down", "reason": info.get("reason")},
            module=it.module,
            dive_id=self.svc.dive.id,
        )
        if not info["up"] and info.get("boot") and info.get("last_seq"):
            self._tail_gap(it.module, info["boot"], int(info["last_seq"]))

    def _tail_gap(self, module: str, boot: str, last_seq: int) -> None:
        """Record as a gap what the module said it had produced but the ship does not have.

        Everything received before the link went down is committed by now
        (the notice queued behind it), so numbers above the highest stored
        one, up to the module's ``last_seq``, are in its outbox only: after a
        link lost for good they arrive only by `camcal import`, and the open
        gap says so. A reconnect that resends them fills it.
        """
        if not self.seqs.known(module, boot):
            self.seqs.seed(module, boot, self.store.known_seqs(module, boot))
        gap = self.seqs.expect(module, boot, last_seq)
        if gap is None:
            return
        self.store.record_gap(module, boot, *gap)
        self.gappy.add((module, boot))
        self.svc.events.emit(
            "gap",
            {"boot": boot, "first_seq": gap[0], "last_seq": gap[1], "reason": "link_lost"},
            module=module,
            dive_id=self.svc.dive.id,
        )

    def _module_info(self, it: _Incoming) -> None:
        m = it.msg
        sched = m.schedule
        self.store.touch_module(
            m.module,
            seen_unix_s=it.received_unix_s,
            boot=m.boot,
            software=getattr(m, "software", None) or None,
            schedule_name=sched.name,
            schedule_version=sched.version,
            schedule_state=sched.state,
            distance_m=(
                self.svc.config.setup.cameras[m.module].distance_m
                if m.module in self.svc.config.setup.cameras
                else None
            ),
        )

    # -- disk ------------------------------------------------------------
    def _housekeeping(self, now: float) -> None:
        """Free disk (an alarm when it runs low) and, hourly, the retention of old frame files."""
        svc = self.svc
        free_gb = shutil.disk_usage(svc.store.files.root).free / 1e9
        svc.disk_free_gb = round(free_gb, 2)
        self.alarms.observe_disk(free_gb)
        days = svc.config.retention_days
        if days and time.monotonic() - self.last_purge >= 3600.0:
            self.last_purge = time.monotonic()
            n, freed = self.store.purge_frame_files(now - days * 86400.0, svc.config.modules)
            if n:
                log.info(
                    "retention: deleted %d frame files older than %g days (%.1f MB)", n, days, freed / 1e6
                )
                svc.events.emit(
                    "retention", {"files": n, "bytes": freed, "older_than_days": days}, dive_id=svc.dive.id
                )

    # -- commands --------------------------------------------------------
    def _command_status(self, it: _Incoming) -> None:
        m = it.msg
        cmd = self.store.update_command(m.command_id, m.state, m.reason, actor=f"module:{m.module}")
        self._module_info(it)
        if cmd is not None:
            self.svc.events.emit(
                "command",
                {
                    "command_id": cmd["id"],
                    "state": cmd["state"],
                    "reason": cmd["reason"],
                    "action": cmd["action"],
                    "target_version": cmd["target_version"],
                },
                module=m.module,
                dive_id=self.svc.dive.id,
            )

    def _deliver_commands(self) -> None:
        """Send queued commands to linked modules, oldest first; repeat until the module answers.

        Oldest first: commands queued while a module was offline (pause, then
        resume) must reach it in the order the operator issued them.
        """
        svc = self.svc
        now = time.time()
        for cmd in reversed(self.store.commands(states=("pending", "sent", "accepted"))):
            link = svc.links.get(cmd["module"])
            if link is None or not link.up:
                continue  # stays pending: delivered when the module is back
            if cmd["state"] == "accepted" or (
                cmd["attempts"] and now - cmd["updated_unix_s"] < svc.config.command_retry_s
            ):
                continue
            schedule = (cmd["payload"] or {}).get("schedule")
            svc.send_to_module(
                cmd["module"],
                wire.Command(
                    module="ship",
                    command_id=cmd["id"],
                    action=cmd["action"],
                    target_version=cmd["target_version"],
                    schedule=schedule,
                    apply=cmd["apply"],
                    issued_by=cmd["issued_by"],
                ),
            )
            self.store.mark_command_sent(cmd["id"])
            if not cmd["attempts"]:
                svc.events.emit(
                    "command",
                    {
                        "command_id": cmd["id"],
                        "state": "sent",
                        "action": cmd["action"],
                        "target_version": cmd["target_version"],
                    },
                    module=cmd["module"],
                    dive_id=svc.dive.id,
                )

    # -- once a second ---------------------------------------------------
    def tick(self) -> None:
        svc = self.svc
        now = time.time()
        mono = time.monotonic()
        att_rows = []
        for module, buf in self.sensors.items():
            if len(buf) < 5 or self.attitude_t.get(module) == buf[-1][0]:
                continue  # too few samples, or none new since the last tick
            self.attitude_t[module] = buf[-1][0]
            recent = _tail(buf, ATTITUDE_WINDOW_S)
            est = attitude_from_samples(recent[:, 0], recent[:, 1:4], recent[:, 4:7])
            self.alarms.observe_tilt(module, est.tilt_deg)
            row = {
                "module_id": module,
                "dive_id": svc.dive.id,
                "t_unix_s": float(recent[-1, 0]),
                "tilt_deg": est.tilt_deg,
                "tilt_x_deg": est.tilt_x_deg,
                "tilt_y_deg": est.tilt_y_deg,
                "rotation_rate_dps": est.rotation_rate_dps,
                "heave_period_s": est.heave_period_s,
                "heave_amplitude_m_s2": est.heave_amplitude_m_s2,
            }
            att_rows.append(row)
            svc.events.transient(
                "attitude", {k: v for k, v in row.items() if k != "module_id"}, module=module
            )
        svc.store.add_attitude(att_rows)
        for link in list(svc.links.values()):
            age_up = link.up and mono - link.last_seen_mono <= svc.config.link_timeout_s
            self.alarms.observe_link(link.module, age_up, link.last_seen_unix_s or None)
        gaps: dict[str, list[tuple[int, int, float]]] = defaultdict(list)
        for g in self.store.open_gaps():  # one query for every module, not one per module
            if svc.config.serves(g.module_id):
                gaps[g.module_id].append((g.first_seq, g.last_seq, g.detected_unix_s))
        for module in set(gaps) | set(svc.links):
            self.alarms.observe_gaps(module, gaps.get(module, []))
        if mono - self.last_housekeeping >= 30.0:
            self.last_housekeeping = mono
            self._housekeeping(now)
        self._apply_alarms(self.alarms.evaluate(now))
        self._update_linearity()
        if (
            self.series is not None
            and time.monotonic() - self.last_result_mono > svc.config.visit_idle_close_s
        ):
            self._store_points(self.series.close_all())  # the modules went quiet: their visits are over
        self._deliver_commands()
        self._adapt_window()
        svc.events.transient("health", svc.health())

    def _apply_alarms(self, conditions: dict[str, Any]) -> None:
        svc = self.svc
        for key, c in conditions.items():
            alarm, changed = self.store.raise_alarm(key, c.kind, c.severity, c.message, c.module)
            if changed or key not in self.active_alarms:
                svc.events.emit(
                    "alarm",
                    {
                        "alarm_id": alarm.id,
                        "state": "raised",
                        "kind": c.kind,
                        "severity": c.severity,
                        "message": c.message,
                    },
                    module=c.module,
                    dive_id=svc.dive.id,
                )
            self.active_alarms.add(key)
        for key in list(self.active_alarms - set(conditions)):
            alarm = self.store.clear_alarm(key)
            self.active_alarms.discard(key)
            if alarm is not None:
                svc.events.emit(
                    "alarm",
                    {
                        "alarm_id": alarm.id,
                        "state": "cleared",
                        "kind": alarm.kind,
                        "severity": alarm.severity,
                        "message": alarm.message,
                    },
                    module=alarm.module_id,
                    dive_id=svc.dive.id,
                )

    def _update_linearity(self) -> None:
        svc = self.svc
        lr = tuple(svc.config.setup.linear_range)
        for module, wl in list(self.linearity_dirty):
            points = {k: float(np.mean(v)) for k, v in self.linearity[(module, wl)].items()}
            for row in linearity_rows(points, lr):  # type: ignore[arg-type]
                self.store.upsert_linearity(
                    {
                        **row,
                        "run_id": svc.run.id,
                        "module_id": module,
                        "wavelength_nm": wl,
                        "updated_unix_s": time.time(),
                    }
                )
        self.linearity_dirty.clear()

    def _adapt_window(self) -> None:
        """Credit: shrink the window while the store queue or analysis backlog is deep."""
        svc = self.svc
        backlog = svc._q.qsize() + len(svc._analysis_backlog)
        base = svc.config.window
        svc.window = base if backlog < 4 * base else max(1, base // 4)


#: Seconds of sensor samples the attitude (tilt, rotation, heave period) is estimated from.
ATTITUDE_WINDOW_S = 120.0


def _tail(buf: deque[tuple[float, ...]], window_s: float) -> np.ndarray:
    """The samples of the last ``window_s`` seconds (rows in time order), without copying the rest.

    Once a second per module: converting the whole buffer (20 000 samples)
    would cost ~13 ms a module, which 100 modules on one ingest cannot afford.
    """
    t_from = buf[-1][0] - window_s
    n = 0
    for row in reversed(buf):
        if row[0] < t_from:
            break
        n += 1
    return np.array(list(itertools.islice(reversed(buf), n))[::-1])


def _sample_columns(row: dict[str, Any]) -> dict[str, Any]:
    keys = (
        "t_unix_s",
        "temperature_c",
        "humidity_pct",
        "acc_x_m_s2",
        "acc_y_m_s2",
        "acc_z_m_s2",
        "gyro_x_dps",
        "gyro_y_dps",
        "gyro_z_dps",
        "depth_m",
    )
    return {k: row.get(k) for k in keys}
