"""The ingest service: a pipeline of stages, each handing the next explicit messages.

    receive ─▶ check ─▶ store ─▶ acknowledge
                         │  └──▶ analyse ─▶ (back to store) ─▶ publish
                         └─────────────────────────────────▶ publish

* **receive** (`ingest.receive`, thread ``ingest-receive``) owns the ZeroMQ
  ROUTER: it checks every message's header and sender, keeps track of links
  and heartbeats, answers ``hello`` with ``welcome`` and what it refuses with
  a ``nack``, and sends the answers the other stages make;
* **check** (`ingest.check`, thread ``ingest-check``) checks the payloads, a
  few milliseconds at a time, the modules in turn;
* **store** (`ingest.storeloop`, thread ``ingest-store``) is the single
  database writer: it commits the checked messages a bounded amount per
  module per turn (`ingest.commit`), stores the analyses (`ingest.results`)
  and runs the once-a-second work (`ingest.housekeeping`);
* **acknowledge** (`ingest.acknowledge`) makes and counts every answer and
  hands it to the receiving thread;
* **analyse** (`ingest.analysis_pool`): one process per core decodes and
  analyses frames; a process that dies is replaced and its frames analysed again;
* **publish** (`ingest.events`): the event log and the events socket (plaintext on
  loopback, CURVE beyond it: `camcal.core.eventport`).

Between the stages every module has its own line (`ingest.fairness`), served
in turns: a module that floods the ship waits behind itself, never in front
of another module, and one that holds too much on the ship is refused
``busy``. The messages between the stages are in `ingest.messages`; the
imports follow the arrows (`lint-imports` checks their order). No message
can stop a thread: each is handled inside a guard that counts, logs
(rate-limited) and answers a failure.

Several ingest processes may share one database (PostgreSQL) and one data
folder, each serving its own set of modules (``modules``; see
``docs/scaling.md``). A process refuses modules it does not serve: their
``hello`` and data get a ``nack`` ``not_served`` (resend later), so a wrongly
wired module keeps everything in its outbox. Recovery after a crash, temporary
files, gaps and alarms are scoped to the served modules; the dive (by name)
and its live run are shared.
"""

from __future__ import annotations

import dataclasses
import logging
import queue
import secrets
import socket
import threading
import time
import uuid
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any

import numpy as np
import zmq

from analysis import FrameConfig
from camcal.core import __version__, wire
from camcal.core.calibrations import setup_of
from camcal.core.eventport import port_keys, use_curve
from ingest.acknowledge import Acknowledge
from ingest.alarms import AlarmEvaluator
from ingest.analysis_pool import AnalysisPool, Job
from ingest.check import Checker
from ingest.commit import frame_meta_from_row
from ingest.config import IngestConfig
from ingest.context import StoreContext
from ingest.counters import Counters
from ingest.events import EventBus, EventPublisher
from ingest.fairness import Credit, FairQueue, sized
from ingest.gatekeeper import Gatekeeper
from ingest.links import Link
from ingest.messages import Analysed, Checked, DataIn, Note
from ingest.receive import Receiver
from ingest.storeloop import StoreLoop
from storage import queries
from storage.models import AnalysisRun, Dive
from storage.store import Store

__all__ = ["IngestConfig", "IngestService"]

log = logging.getLogger("camcal.ingest")


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
        # The module link gets a context of its own: its ZAP handler is per context (a second
        # ingest or any other socket of this process must not share it).
        self.link_ctx: zmq.Context[Any] | None = None
        self.gatekeeper: Gatekeeper | None = None
        #: Which ingest this is: a new id at every start, told to each module in ``welcome``.
        self.instance = secrets.token_hex(8)
        self._stop = threading.Event()
        self.answers_endpoint = f"inproc://ingest-answers-{uuid.uuid4().hex}"
        self.counters = Counters()
        self.credit = Credit(config.window)
        #: The pipeline's lines: received -> check -> store; analyses back to the store.
        self.checkq: FairQueue[DataIn | Note] = FairQueue(sized)
        self.storeq: FairQueue[Checked | Note] = FairQueue(sized)
        self.results_q: queue.SimpleQueue[Analysed] = queue.SimpleQueue()
        self.acknowledge = Acknowledge(self.ctx, self.answers_endpoint, self.counters, self.credit)
        self.receiver: Receiver | None = None
        self.checker: Checker | None = None
        self.store_ctx: StoreContext | None = None
        self.endpoint = ""
        self.events_endpoint = ""
        self.publisher: EventPublisher | None = None
        self.pub: Any = None
        self.events = EventBus(self.store, None)  # publishes once `start` has bound its socket
        self._threads: list[threading.Thread] = []
        thumbs = self.store.files.root / "thumbs"
        self.analysis = AnalysisPool(
            config.n_workers,
            frame_config=lambda module: FrameConfig(**self.config.setup.frame_settings(module)),
            file_of=lambda path: str(self.store.files.resolve(path)),
            thumb_of=lambda frame_id: str(thumbs / f"{frame_id}.jpg") if config.thumbnails else None,
            deliver=self._deliver_result,
            count=self.counters.inc,
        )
        #: Set once every analysis process has started (imported the analysis).
        self.analysis_ready = self.analysis.ready
        self.started = threading.Event()
        self.error: BaseException | None = None

    # ------------------------------------------------------------ lifecycle
    def start(self) -> None:
        """Bind the sockets (so `endpoint` is known), then run the threads."""
        calibration = None
        if self.config.calibration:  # before binding anything: a wrong name leaves nothing open
            calibration = self.store.call(queries.calibration, self.config.calibration)
            if calibration is None:
                raise ValueError(
                    f"no calibration {self.config.calibration!r} in the store (see `camcal calibration list`)"
                )
            self.config = dataclasses.replace(self.config, setup=setup_of(calibration))
        ship_keys = self._link_keys()
        if self.config.events_bind and use_curve(self.config.events_bind, self.config.events_curve):
            port_keys(self.config.events_bind, self.config.keys_dir)  # no keys: say so, bind nothing
        self.store.files.remove_temporaries(self.config.modules)
        self.store.remove_incomplete_sensor_batches(self.config.modules)
        self.link_ctx = zmq.Context()
        try:
            if ship_keys is not None:  # the ZAP handler first: no handshake may pass unasked
                assert self.config.keys_dir is not None
                self.gatekeeper = Gatekeeper(self.link_ctx, self.config.keys_dir, self.counters)
            router = wire.ship_socket(
                self.link_ctx,
                self.config.bind,
                max_message_bytes=self.config.max_payload_bytes + wire.MAX_HEADER_BYTES,
                keys=ship_keys,
            )
        except zmq.ZMQError:
            if self.gatekeeper is not None:
                self.gatekeeper.close()
            self.link_ctx.term()
            raise
        self.endpoint = router.getsockopt(zmq.LAST_ENDPOINT).decode()
        if self.gatekeeper is not None:
            self.gatekeeper.watch(router)
        answers = self.ctx.socket(zmq.PULL)
        answers.bind(self.answers_endpoint)
        self._sockets = [router, answers]
        if self.config.events_bind:  # plaintext on loopback, CURVE beyond it (`camcal.core.eventport`)
            self.publisher = EventPublisher(
                self.config.events_bind,
                ctx=self.ctx,
                keys_dir=self.config.keys_dir,
                curve=self.config.events_curve,
            )
            self.pub = self.publisher.socket
            self.events_endpoint = self.publisher.endpoint
        self.counters.restore(self.store.call(queries.load_counters, self.ingest_id))
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
        self.analysis.start()
        receiver = self.receiver = Receiver(
            self.config,
            self.counters,
            router,
            answers,
            self.checkq,
            dive_name=self.dive.name,
            instance=self.instance,
            window=self.credit,
            gatekeeper=self.gatekeeper,
        )
        checker = self.checker = Checker(self.checkq, self.storeq, self.acknowledge, self.counters)
        self.store_ctx = StoreContext(
            config=self.config,
            store=self.store,
            counters=self.counters,
            events=self.events,
            acknowledge=self.acknowledge,
            alarms=AlarmEvaluator(self.config.alarm_limits),
            dive_id=self.dive.id,
            run_id=self.run.id,
            ingest_id=self.ingest_id,
            links=receiver.links,
            analysis=self.analysis,
            credit=self.credit,
            backlog=self.backlog,
            health=self.health,
        )
        receive_done, check_done = threading.Event(), threading.Event()

        def receive() -> None:
            try:
                receiver.run(self._stop, self.started)
            finally:
                receive_done.set()

        def check() -> None:
            try:
                checker.run(receive_done)
            finally:
                check_done.set()

        threads: list[tuple[str, Callable[[], None]]] = [
            ("ingest-receive", receive),
            ("ingest-check", check),
            ("ingest-store", lambda: self._store_thread(check_done)),
        ]
        for name, target in threads:
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

    def _store_thread(self, check_done: threading.Event) -> None:
        assert self.store_ctx is not None
        self.events.pub = self.pub  # the PUB socket is used by this thread only from now on
        loop = StoreLoop(self.store_ctx, self.storeq, self.results_q, self.analysis.queue)
        self.recover_unanalysed()
        loop.run(self._stop, check_done.is_set)

    def _link_keys(self) -> wire.KeyPair | None:
        """The ship's key pair, or None for a plaintext link, which must be asked for explicitly."""
        if self.config.plaintext:
            log.warning(
                "the module link is PLAINTEXT: anyone who reaches %s can claim any module id and read "
                "every frame; use it on a lab bench only (create keys with `camcal keys create`)",
                self.config.bind,
            )
            return None
        if self.config.keys_dir is None:
            raise ValueError(
                "the module link needs keys: create them with `camcal keys create A B` (or, on a lab "
                "bench only, allow a plaintext link with CAMCAL_LINK_PLAINTEXT=true)"
            )
        return wire.ship_pair(self.config.keys_dir)

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
        """Stop receiving, finish checking and storing what arrived, wait for running analyses."""
        self._stop.set()
        for t in self._threads:
            t.join(timeout)
        self.analysis.stop()
        self.acknowledge.close()
        if self.gatekeeper is not None:
            self._sockets[0].disable_monitor()
            self.gatekeeper.close()
        for sock in getattr(self, "_sockets", []):
            sock.close(0)
        if self.publisher is not None:
            self.publisher.close()
        if self.link_ctx is not None:
            self.link_ctx.term()
        self.store.close()

    def wait(self) -> None:
        while not self._stop.wait(0.5):
            pass
        if self.error is not None:
            raise RuntimeError(f"ingest stopped: {self.error}") from self.error

    def send_to_module(self, module: str, msg: Any) -> None:
        """Send a message to a module (through the receiving thread)."""
        self.acknowledge.send(module, msg)

    def backlog(self) -> int:
        """Messages waiting to be checked, stored or analysed."""
        return len(self.checkq) + len(self.storeq) + len(self.analysis.backlog) + len(self.analysis.suspects)

    @property
    def window(self) -> int:
        return self.credit.value

    # -- analysis pool ---------------------------------------------------
    def _deliver_result(self, job: Job, fut: Future[Any]) -> None:
        """In the pool's thread: a finished analysis goes back to the store thread."""
        self.results_q.put(Analysed(job.frame_id, job.meta, fut))
        self.storeq.wake()

    def recover_unanalysed(self) -> None:
        """Frames committed before a crash but never analysed go back in the queue."""
        for f in self.store.call(
            queries.frames_without_result, self.dive.id, self.run.id, modules=self.config.modules
        ):
            self.analysis.queue(Job(f.id, f.path, frame_meta_from_row(f)))

    # -- status ----------------------------------------------------------
    @property
    def links(self) -> dict[str, Link]:
        return self.receiver.links if self.receiver else {}

    @property
    def latency_s(self) -> Any:
        """Seconds from receiving a frame to storing its analysis (the newest 2000)."""
        return self.store_ctx.latency_s if self.store_ctx else []

    @property
    def disk_free_gb(self) -> float | None:
        return self.store_ctx.disk_free_gb if self.store_ctx else None

    @property
    def malformed(self) -> dict[str, int]:
        return self.counters.snapshot()["malformed"]

    @property
    def refused(self) -> dict[str, int]:
        return self.counters.snapshot()["refused"]

    @property
    def ingest_id(self) -> str:
        """Which ingest this is, for a server that follows several: host, then where modules connect."""
        return f"{socket.gethostname()} {self.config.bind}" + (
            f" ({','.join(self.config.modules)})" if self.config.modules else ""
        )

    def health(self, counts: dict[str, dict[str, int]] | None = None) -> dict[str, Any]:
        """Per-module link state, last packet age, frame rates, queue depths, counters (``counts``: a
        snapshot of the counters to show, the one just saved; default: now).

        ``frames_per_s`` counts the last 10 s; ``frames_last_min`` the last 60 s (between test stops the
        first reads 0 long before the second); ``last_frame_age_s`` is the ship's time since the last frame.
        """
        now = time.monotonic()
        now_unix = time.time()
        modules = {}
        for m, link in sorted(self.links.items()):
            recent = [t for t in link.frames if now - t <= 10.0]
            last_frame = link.last_frame_unix_s
            modules[m] = {
                "link": "up" if link.up else ("signed_off" if link.down_reason == "bye" else "down"),
                "last_packet_age_s": round(now - link.last_seen_mono, 2) if link.last_seen_mono else None,
                "frames_per_s": round(len(recent) / 10.0, 2),
                "frames_last_min": sum(1 for t in link.frames if now - t <= 60.0),
                "last_frame_age_s": round(now_unix - last_frame, 1) if last_frame is not None else None,
                "boot": link.boot,
                "schedule": link.schedule,
                "outbox_pending": link.outbox_pending,
                "card_skipped": link.card_skipped,
                "capture_errors": link.capture_errors,
                "sensor_errors": link.sensor_errors,
                "deferred_shots": link.deferred_shots,
                "in_flight": link.in_flight,
                "clock_offset_s": round(link.clock_offset_s, 3) if link.clock_offset_s is not None else None,
                "last_seq": link.last_seq,
                "unanswered": len(link.unanswered),
                "unanswered_bytes": link.unanswered_bytes,
                "busy_refused": link.busy_refused,
            }
        counts = counts or self.counters.snapshot()
        return {
            "ingest_id": self.ingest_id,
            "instance": self.instance,
            "link_security": "plaintext" if self.gatekeeper is None else "curve",
            "refused_connections": self.gatekeeper.refused.summary() if self.gatekeeper else None,
            "modules": modules,
            "queues": {
                "check": len(self.checkq),
                "store": len(self.storeq),
                "analysis_backlog": len(self.analysis.backlog) + len(self.analysis.suspects),
                "analysis_in_flight": self.analysis.in_flight,
            },
            "analysis_ready": self.analysis_ready.is_set(),
            "window": self.window,
            "counters": counts["counters"],
            "malformed": counts["malformed"],
            "nacked": counts["nacked"],
            "served_modules": list(self.config.modules),
            "refused": counts["refused"],
            "dive": {"id": self.dive.id, "name": self.dive.name},
            "disk_free_gb": self.disk_free_gb,
            "latency_p50_s": _pct(self.latency_s, 50),
            "latency_p95_s": _pct(self.latency_s, 95),
        }


def _pct(values: Any, q: float) -> float | None:
    return round(float(np.percentile(list(values), q)), 4) if values else None
