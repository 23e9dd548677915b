"""The ingest's analysis processes: frames handed to them, results back, a dead process survived.

The store thread queues every committed frame (`AnalysisPool.queue`) and
hands them to a process pool (`AnalysisPool.feed`, at most
`ANALYSES_QUEUED_PER_WORKER` per process); each finished analysis goes back
to the store thread's queue as a ``result`` item.

**A process that dies** (the kernel's OOM killer, a decoder crashing on a
frame, a stray ``kill``) breaks Python's whole pool: every analysis running
or queued in it fails, and the pool takes no more work. Without care the
ship would store frames for the rest of the dive and analyse none. Here the
pool is replaced at once (`AnalysisPool.crashed`), and the frames that were
in it are analysed again, *one at a time* (the suspects), before anything
else: a frame that kills a process on its own is then known for certain,
and only that frame is stored as rejected (``analysis_crashed``); every
other one gets its result. Each crash is kept (`AnalysisPool.crashes`) for
the alarm the deck crew sees (`ingest.alarms`) and counted
(``analysis_restarts``). Everything here runs on the store thread except
the start of the processes (`ready` is set from a thread of its own once
every process has imported the analysis).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import CancelledError, Future
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Any

from analysis import FrameConfig
from camcal.core.parallel import process_pool
from ingest.worker import analyse_stored_frame, warm_up

log = logging.getLogger("camcal.ingest")

#: Analyses handed to the pool per worker process at most: enough that a worker never waits for
#: the store thread to come back for its next frame (at 2 per worker the pool idled ~25 % of a
#: full-speed run, bench_ingest.py); the rest wait in the backlog, where a stop leaves them for
#: the next start (`IngestService.recover_unanalysed`).
ANALYSES_QUEUED_PER_WORKER = 8
#: Crashes kept for the alarm (the newest).
CRASHES_KEPT = 100
#: A pool that dies within a minute of the last death is started again only this long after it
#: (processes that cannot start at all would otherwise be started again and again at once).
RESTART_PAUSE_S = 5.0


@dataclass(frozen=True)
class Job:
    """One frame to analyse: its row id, its stored file (relative path) and its header's meta."""

    frame_id: int
    path: str
    meta: dict[str, Any]


class AnalysisPool:
    """The analysis processes of one ingest, fed by its store thread."""

    def __init__(
        self,
        n_workers: int,
        frame_config: Callable[[str], FrameConfig],
        file_of: Callable[[str], str],
        thumb_of: Callable[[int], str | None],
        deliver: Callable[[Job, Future[Any]], None],
        count: Callable[[str], None],
        analyse: Callable[..., dict[str, Any]] = analyse_stored_frame,
        restart_pause_s: float = RESTART_PAUSE_S,
    ) -> None:
        self.n_workers = n_workers
        self._analyse = analyse  # run in a worker process: (file, FrameConfig, thumbnail path) -> result
        self._frame_config = frame_config  # a module's FrameConfig
        self._file_of = file_of  # a frame's absolute path from its relative one
        self._thumb_of = thumb_of  # where a frame's thumbnail goes (None: no thumbnails)
        self._deliver = deliver  # called in the pool's thread when an analysis is done
        self._count = count  # a counter of the ingest by name
        self.pool: Any = None
        #: Set once every analysis process has started (imported the analysis).
        self.ready = threading.Event()
        self.backlog: deque[Job] = deque()
        self.suspects: deque[Job] = deque()  # in a pool that broke: analysed again one at a time
        self.in_flight = 0
        self._running: dict[Future[Any], tuple[Job, bool, Any]] = {}  # future -> job, alone, its pool
        self.crashes: deque[tuple[float, str]] = deque(maxlen=CRASHES_KEPT)  # (unix time, what died)
        self._restart_pause_s = restart_pause_s
        self._start_at = 0.0  # monotonic time after which a dead pool is replaced

    # -- lifecycle ---------------------------------------------------------
    def start(self) -> None:
        """Start the processes now, in a thread: started by the first frame they would make the
        first results wait a second or more (each imports the analysis), and the ingest is ready
        (bound, storing) without them."""
        self.ready.clear()
        self.pool = pool = process_pool(self.n_workers)
        threading.Thread(target=self._warm, args=(pool,), name="ingest-pool-start", daemon=True).start()

    def _warm(self, pool: Any) -> None:
        try:
            started = [pool.submit(warm_up) for _ in range(self.n_workers)]
            for fut in started:
                fut.result()
        except (RuntimeError, CancelledError, BrokenProcessPool):  # stopped or broken before it was up
            return
        if pool is self.pool:
            self.ready.set()

    def stop(self) -> None:
        """Wait for the running analyses; what has not started stays for the next start."""
        if self.pool is not None:
            self.pool.shutdown(wait=True, cancel_futures=True)

    # -- the store thread's side -------------------------------------------
    def queue(self, job: Job) -> None:
        self.backlog.append(job)

    def done(self, n: int) -> None:
        """``n`` results were taken off the store thread's queue."""
        self.in_flight -= n

    def busy(self) -> bool:
        """Whether analyses are running or waiting (more results are on their way)."""
        return self.in_flight > 0 or bool(self.backlog) or bool(self.suspects)

    def feed(self) -> None:
        """Hand waiting frames to the processes: the suspects of a crash alone, then the backlog."""
        if self.pool is None:  # died: replaced once its pause is over
            if time.monotonic() < self._start_at:
                return
            self.start()
        if self.suspects:
            if self.in_flight == 0:
                self._submit(self.suspects[0], alone=True)
                self.suspects.popleft()
            return
        limit = ANALYSES_QUEUED_PER_WORKER * self.n_workers
        while self.backlog and self.in_flight < limit:
            if not self._submit(self.backlog[0], alone=False):
                return
            self.backlog.popleft()  # only once the pool took it: a refused submit loses nothing

    def _submit(self, job: Job, *, alone: bool) -> bool:
        args = (self._file_of(job.path), self._frame_config(job.meta["module"]), self._thumb_of(job.frame_id))
        pool = self.pool
        try:
            fut = pool.submit(self._analyse, *args)
        except BrokenProcessPool as exc:  # broke before any of its results came back
            self._restart(pool, f"the pool refused work: {exc}")
            return False
        self._running[fut] = (job, alone, pool)
        self.in_flight += 1
        fut.add_done_callback(lambda f: self._deliver(job, f))
        return True

    def crashed(self, fut: Future[Any]) -> bool:
        """For a finished analysis: whether it died with its process and goes to the suspects.

        False for a result (or an error of the analysis itself) to store as it is, and for a frame
        that was analysed alone and killed its process: that frame's result is the crash. The pool
        is replaced the first time one of its analyses reports the crash.
        """
        job, alone, pool = self._running.pop(fut, (None, False, None))
        if fut.cancelled() or not isinstance(fut.exception(), BrokenProcessPool):
            return False
        what = f"frame {job.frame_id}" if job is not None else "a frame"
        self._restart(pool, f"an analysis process died while analysing {what}" + (" alone" if alone else ""))
        if job is None or alone:
            return False
        self.suspects.append(job)
        return True

    def _restart(self, broken: Any, why: str) -> None:
        """Replace the pool ``broken`` (unless it was already): at once, or after a pause when the
        last death was less than a minute ago."""
        if broken is not self.pool:
            return
        now, mono = time.time(), time.monotonic()
        again = bool(self.crashes) and now - self.crashes[-1][0] < 60.0
        self.crashes.append((now, why))
        self._count("analysis_restarts")
        log.error(
            "ingest: %s; starting new analysis processes%s. Every frame is kept: the ones in the dead "
            "pool are analysed again one at a time, and one that kills a process alone is stored as "
            "rejected (analysis_crashed). If this repeats, look for the OOM killer (`dmesg`) and run "
            "`camcal analyze` on a rejected frame's file",
            why,
            f" in {self._restart_pause_s:g} s" if again else "",
        )
        broken.shutdown(wait=False, cancel_futures=True)
        self.pool = None
        self.ready.clear()
        self._start_at = mono + (self._restart_pause_s if again else 0.0)
        if not again:
            self.start()
