"""The store thread: the single database writer of an ingest.

It drains what the network thread and the analysis pool hand it, in
batches, and routes each item to its worker: `ingest.commit` (frames and
sensor messages), `ingest.results` (analysis results), `ingest.housekeeping`
(links, module state, commands, and the once-a-second tick). Every worker
call is guarded: a failure is counted and logged (rate-limited) and the
thread goes on. Data messages are answered by `ingest.commit` even when
their storing fails.
"""

from __future__ import annotations

import itertools
import logging
import queue
import time
from collections import defaultdict, deque
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
import zmq

from camcal.core.events import EventKind
from camcal.core.ratelog import RateLimitedLog
from ingest.alarms import AlarmEvaluator
from ingest.commit import Committer
from ingest.gaps import Gaps
from ingest.housekeeping import Housekeeping
from ingest.network import Incoming
from ingest.results import Results
from storage.store import SensorBatchRow

if TYPE_CHECKING:
    from ingest.service import IngestService

log = logging.getLogger("camcal.ingest")
Attitude = tuple[float, float, float, float, float, float, float]  # t, acc xyz, gyro xyz
#: Results stored in one transaction at most, and how long one may wait for others (`store_results`).
RESULT_BATCH = 16
RESULT_HOLD_S = 0.25


def results_due(pending: int, waited_s: float, busy: bool) -> bool:
    """Whether ``pending`` results, the oldest ``waited_s`` old, are to be stored now: when no
    other analysis is running or waiting (``busy`` false), else once they are `RESULT_BATCH` or
    the oldest has waited `RESULT_HOLD_S`."""
    return pending > 0 and (not busy or pending >= RESULT_BATCH or waited_s >= RESULT_HOLD_S)


class StoreState:
    """What the store thread's workers share: the service, the store, alarms, sensor buffers."""

    def __init__(self, svc: IngestService) -> None:
        self.svc = svc
        self.store = svc.store
        self.warn = RateLimitedLog(log)
        self.alarms = AlarmEvaluator(svc.config.alarm_limits)
        self.sensors: dict[str, deque[Attitude]] = defaultdict(lambda: deque(maxlen=20000))
        self.last_sensor_event: dict[str, float] = {}
        self.gaps = Gaps(self)
        self.results = Results(self)
        self.housekeeping = Housekeeping(self)
        self.committer = Committer(self)
        self.pending_results: list[Incoming] = []  # back from the analysis, not stored yet
        self.pending_since = 0.0

    def guarded(self, what: str, fn: Callable[..., Any], *args: Any) -> bool:
        """Run ``fn(*args)``; a failure is counted and logged, never raised. Returns whether it ran."""
        try:
            fn(*args)
            return True
        except Exception as exc:
            self.svc.counters.inc("handler_errors")
            self.warn(
                logging.ERROR,
                f"{what}:{type(exc).__name__}",
                "ingest: %s failed: %s",
                what,
                exc,
                exc_info=True,
            )
            return False

    def handle(self, items: list[Incoming]) -> None:
        data = [i for i in items if i.kind in ("frame", "sensors")]
        if data:
            self.guarded("commit", self.committer.commit, data)
        results = [i for i in items if i.kind == "result"]
        if results:
            self.svc.analysis_done(len(results))
            if not self.pending_results:
                self.pending_since = time.monotonic()
            self.pending_results += results
            self.store_results()
        hk = self.housekeeping
        for i in items:
            if i.kind == "link":
                self.guarded("link", hk.link, i)
            elif i.kind in ("hello", "heartbeat"):
                self.guarded("module state", hk.module_info, i)
            elif i.kind == "command_status":
                self.guarded("command status", hk.command_status, i)

    def store_results(self, *, now: bool = False) -> None:
        """Store the results that came back, in one transaction, unless more are about to come.

        A result waits while other analyses are still running, up to `RESULT_BATCH`
        results or `RESULT_HOLD_S`: at full speed a transaction carries a dozen
        results instead of one or two (each costs ~10 ms of this thread's CPU
        beside its fsync); at a module's pace, nothing else is running and a
        result is stored as soon as it comes.
        """
        pending = self.pending_results
        if not pending:
            return
        if not now and not results_due(
            len(pending), time.monotonic() - self.pending_since, self.svc.analysis_busy()
        ):
            return
        self.pending_results = []
        self.guarded("results", self.results.handle, pending)  # a bad result costs only itself

    # -- sensor samples --------------------------------------------------
    def sensor_samples(self, b: SensorBatchRow) -> None:
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
                self.svc.events.transient(EventKind.SENSORS, dict(last), module=b.module_id)

    def sensor_tail(self, module: str, window_s: float) -> np.ndarray:
        """The samples of the last ``window_s`` seconds (rows in time order), without copying the rest.

        Once a second per module: converting the whole buffer (20 000 samples)
        would cost ~13 ms a module, which 100 modules on one ingest cannot afford.
        """
        buf = self.sensors[module]
        t_from = buf[-1][0] - window_s
        n = 0
        for row in reversed(buf):
            if row[0] < t_from:
                break
            n += 1
        return np.array(list(itertools.islice(reversed(buf), n))[::-1])


def run_store_loop(svc: IngestService, q: queue.Queue[Incoming], stop: Any) -> None:
    """The store thread's loop: drain, handle, feed the analysis pool, tick, publish; until stopped."""
    push = svc.ctx.socket(zmq.PUSH)
    push.setsockopt(zmq.LINGER, 1000)
    push.connect(svc.out_endpoint)
    svc.push = push
    svc.events.pub = svc.pub
    st = StoreState(svc)
    svc.recover_unanalysed()
    last_tick = 0.0
    try:
        while True:
            items = _drain(q, svc.config.ack_batch_s, timeout=0.05)
            if items:
                st.handle(items)
            st.guarded("analysis queue", svc.feed_pool)
            st.store_results()
            now = time.monotonic()
            if now - last_tick >= 1.0:
                last_tick = now
                st.housekeeping.tick()
            st.guarded("events", svc.events.flush)
            if stop.is_set() and q.empty():
                st.store_results(now=True)
                break
        st.guarded("counters", st.housekeeping.save_counters)
    finally:
        push.close()


def _drain(q: queue.Queue[Incoming], batch_s: float, timeout: float) -> list[Incoming]:
    try:
        first = q.get(timeout=timeout)
    except queue.Empty:
        return []
    items = [first]
    deadline = time.monotonic() + batch_s
    while len(items) < 64:
        left = deadline - time.monotonic()
        try:
            items.append(q.get(timeout=max(left, 0)) if left > 0 else q.get_nowait())
        except queue.Empty:
            break
    return items
