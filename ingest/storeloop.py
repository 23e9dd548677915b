"""Store: the store thread, the single database writer of an ingest.

It serves the modules in turns (`ingest.fairness`): each turn takes, from
each module's line, checked data messages worth at most `TURN_ROWS` sensor
rows (a frame counts `FRAME_ROWS`, a part of a large sensor batch its rows)
and the module's notes behind them, and commits them in one transaction
(`ingest.commit`, which answers each through `ingest.acknowledge` and hands
new frames to the analysis, `ingest.analysis_pool`). A module's batch of
100 000 rows is stored over fifty turns, and another module's frame is
stored in the next one. It also stores the analyses that come back
(`ingest.results`), and does the once-a-second work (`ingest.housekeeping`).
Every worker call is guarded: a failure is counted and logged
(rate-limited) and the thread goes on. Data messages are answered by
`ingest.commit` even when their storing fails.
"""

from __future__ import annotations

import logging
import queue
import time
from collections.abc import Callable
from typing import Any

from ingest.analysis_pool import Job
from ingest.commit import Committer
from ingest.context import StoreContext
from ingest.fairness import FairQueue
from ingest.gaps import Gaps
from ingest.housekeeping import Housekeeping
from ingest.messages import PART_ROWS, Analysed, Checked, Note
from ingest.results import Results
from ingest.sensorbuf import SensorBuffers

log = logging.getLogger("camcal.ingest")
#: Results stored in one transaction at most, and how long one may wait for others (`store_results`).
RESULT_BATCH = 16
RESULT_HOLD_S = 0.25
#: A module's share of one turn of the store, in sensor rows; what a frame counts.
TURN_ROWS = PART_ROWS
FRAME_ROWS = 100


def results_due(pending: int, waited_s: float, busy: bool) -> bool:
    """Whether ``pending`` results, the oldest ``waited_s`` old, are to be stored now: when no
    other analysis is running or waiting (``busy`` false), else once they are `RESULT_BATCH` or
    the oldest has waited `RESULT_HOLD_S`."""
    return pending > 0 and (not busy or pending >= RESULT_BATCH or waited_s >= RESULT_HOLD_S)


def turn_cost(item: Checked | Note) -> int:
    """What an item costs of a module's turn (`TURN_ROWS`)."""
    if isinstance(item, Note):
        return 1
    if item.kind == "frame":
        return FRAME_ROWS
    return max(1, item.part[1] if item.part is not None else len(item.payload))


class StoreLoop:
    """The store thread (see the module docstring)."""

    def __init__(
        self,
        ctx: StoreContext,
        storeq: FairQueue[Checked | Note],
        results_q: queue.SimpleQueue[Analysed],
        analyse: Callable[[Job], None],
    ) -> None:
        self.ctx = ctx
        self.storeq = storeq
        self.results_q = results_q
        self.sensors = SensorBuffers(ctx.alarms, ctx.events)
        self.gaps = Gaps(ctx.store, ctx.events, ctx.dive_id, ctx.config.serves)
        self.results = Results(ctx)
        self.housekeeping = Housekeeping(ctx, self.gaps, self.sensors)
        self.committer = Committer(
            ctx.store,
            dive_id=ctx.dive_id,
            ingest_id=ctx.ingest_id,
            fsync=ctx.config.fsync,
            counters=ctx.counters,
            alarms=ctx.alarms,
            acknowledge=ctx.acknowledge,
            events=ctx.events,
            gaps=self.gaps,
            sensors=self.sensors,
            analyse=analyse,
            guarded=ctx.guarded,
        )
        self.pending_results: list[Analysed] = []  # back from the analysis, not stored yet
        self.pending_since = 0.0

    def run(self, stop: Any, upstream_done: Callable[[], bool]) -> None:
        """Until stopped and everything upstream is stored: take turns, store results, tick, publish."""
        ctx = self.ctx
        last_tick = 0.0
        while True:
            if self.storeq.wait(0.05):
                time.sleep(ctx.config.ack_batch_s)  # (a few more messages: one fsync for all of them)
                self.handle(self.storeq.take(TURN_ROWS, cost=turn_cost))
            self.take_results()
            ctx.guarded("analysis queue", ctx.analysis.feed)
            self.store_results()
            now = time.monotonic()
            if now - last_tick >= 1.0:
                last_tick = now
                self.tick()
            ctx.guarded("events", ctx.events.flush)
            if stop.is_set() and upstream_done() and not len(self.storeq) and self.results_q.empty():
                self.store_results(now=True)
                break
        ctx.guarded("counters", self.housekeeping.save_counters)

    def handle(self, items: list[Checked | Note]) -> None:
        data = [i for i in items if isinstance(i, Checked)]
        if data:
            self.ctx.guarded("commit", self.committer.commit, data)
        hk, g = self.housekeeping, self.ctx.guarded
        for i in items:
            if not isinstance(i, Note):
                continue
            if i.kind == "link":
                g("link", hk.link, i)
            elif i.kind in ("hello", "heartbeat"):
                g("module state", hk.module_info, i)
            elif i.kind == "command_status":
                g("command status", hk.command_status, i)

    def take_results(self) -> None:
        results = []
        while True:
            try:
                results.append(self.results_q.get_nowait())
            except queue.Empty:
                break
        if results:
            self.ctx.analysis.done(len(results))
            if not self.pending_results:
                self.pending_since = time.monotonic()
            self.pending_results += results

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
            len(pending), time.monotonic() - self.pending_since, self.ctx.analysis.busy()
        ):
            return
        self.pending_results = []
        self.ctx.guarded("results", self.results.handle, pending)  # a bad result costs only itself

    def tick(self) -> None:
        """The once-a-second work; each step guarded apart."""
        g = self.ctx.guarded
        self.housekeeping.tick()
        g("unsaved results", self.results.store_unsaved)
        g("linearity", self.results.update_linearity)
        g("visits", self.results.close_idle_visits)
        # The counters are saved, then published as saved: what anyone saw survives a crash.
        counts = self.ctx.counters.snapshot()
        g("counters", self.housekeeping.save_counters, counts)
        g("health", self.housekeeping.publish_health, counts)
