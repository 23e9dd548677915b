"""Expensive work the API starts, kept within bounds: re-analyses queued, exports a few at a time.

A re-analysis costs tens of seconds of CPU on every core it gets; a dive's
export reads every row of the dive. Neither may be started as often as
someone can click (or script) the button: `ReanalysisQueue` runs
re-analyses one at a time, in the order they were asked for, and refuses
more than a few waiting (503); `ExportSlots` lets ``n`` exports run at once
and refuses the next (503, try again later). Both are made by the app's
lifespan and stopped with it. A schedule's preview is open to every browser
(no token) and costs up to a few tenths of a second of CPU and megabytes of
answer: `PreviewSlots` lets a few be computed at once and keeps some for
operators.
"""

from __future__ import annotations

import contextlib
import logging
import queue
import threading
from collections.abc import Callable, Iterator

from ingest.reanalysis import RunBeats
from server.errors import Unavailable
from storage.store import Store

log = logging.getLogger("camcal.server")


class Busy(Unavailable):
    """The server is at its bound for this kind of work: try again later (503, ``Retry-After``)."""

    def __init__(self, message: str, retry_after_s: int) -> None:
        super().__init__(message)
        self.headers = {"Retry-After": str(retry_after_s)}


class ReanalysisQueue:
    """Re-analyses run on one worker thread, one at a time, oldest first; at most ``max_queued`` wait.

    A queued run has the status ``queued`` until its turn, and beats while it waits
    (`ingest.reanalysis.RunBeats`; the running one beats itself). When the server stops, runs still
    queued are marked ``cancelled``, and the running one is asked to stop after its current batch
    (``interrupted``; it is waited for at most `STOP_WAIT_S`). Runs left queued or running by a
    server that was killed are marked ``interrupted`` when the next one starts.
    """

    #: How long a stopping server waits for the running re-analysis to store its batch and end.
    STOP_WAIT_S = 10.0

    def __init__(self, store: Store, max_queued: int) -> None:
        self.store = store
        try:
            orphans = store.interrupt_stale_runs()
        except Exception as exc:  # the database away at start: the runs API still reads them so
            log.warning("could not mark the re-analyses a stopped server left: %s", exc)
            orphans = []
        for run in orphans:
            log.warning(
                "re-analysis run %s of dive %s (%s) was left unfinished by a server that stopped: "
                "marked interrupted; start it again to complete it",
                run["id"],
                run["dive_id"],
                run["label"] or "no label",
            )
        self._q: queue.Queue[tuple[int, Callable[[threading.Event], None]] | None] = queue.Queue(max_queued)
        self._cancel = threading.Event()
        self._beats = RunBeats(store)
        self._thread = threading.Thread(target=self._run, name="reanalysis-queue", daemon=True)
        self._thread.start()

    def submit(self, run_id: int, job: Callable[[threading.Event], None]) -> None:
        """Queue ``job`` (which fills run ``run_id``, stopping when the event it is given is set);
        `Busy` if too many wait already."""
        self.store.finish_run(run_id, "queued")
        self._beats.hold(run_id)
        try:
            self._q.put_nowait((run_id, job))
        except queue.Full:
            self._beats.release(run_id)
            self.store.finish_run(run_id, "cancelled")
            raise Busy(
                f"{self._q.maxsize} re-analyses are waiting already: try again when one has finished",
                60,
            ) from None

    def _run(self) -> None:
        while True:
            item = self._q.get()
            if item is None:
                return
            run_id, job = item
            self._beats.release(run_id)  # from here the run beats itself (or is over)
            if self._cancel.is_set():  # taken just as the server began to stop
                self.store.finish_run(run_id, "cancelled")
                continue
            self.store.finish_run(run_id, "running")
            try:
                job(self._cancel)
            except Exception:  # recorded as a failed or interrupted run (and logged); the queue goes on
                log.debug("re-analysis run %s ended early", run_id, exc_info=True)

    def stop(self) -> None:
        """Cancel what waits; ask the running one to stop after its batch, and wait for it a little."""
        self._cancel.set()
        while True:
            try:
                item = self._q.get_nowait()
            except queue.Empty:
                break
            if item is not None:
                self._beats.release(item[0])
                self.store.finish_run(item[0], "cancelled")
        with contextlib.suppress(queue.Full):
            self._q.put_nowait(None)
        self._thread.join(self.STOP_WAIT_S)
        self._beats.stop()


class ExportSlots:
    """At most ``n`` exports at once; the next is refused with `Busy`."""

    def __init__(self, n: int) -> None:
        self._slots = threading.BoundedSemaphore(max(1, n))
        self.n = max(1, n)

    def take(self) -> None:
        if not self._slots.acquire(blocking=False):
            raise Busy(f"{self.n} export(s) running already: try again in a minute", 30)

    def give(self) -> None:
        self._slots.release()


class PreviewSlots:
    """Schedule previews computed at once: ``anonymous`` slots for requests without a valid
    operator token, and ``operators`` more that only requests with one may take (they take an
    anonymous slot when theirs are full). A request finding no free slot is refused with `Busy`
    (503, ``Retry-After: 1``) at once, never queued: a flood from the ship's network holds at most
    ``anonymous`` threads and never turns an operator's preview away."""

    def __init__(self, anonymous: int, operators: int) -> None:
        self.anonymous, self.operators = max(1, anonymous), max(0, operators)
        self._lanes = {
            False: threading.BoundedSemaphore(self.anonymous),
            True: threading.BoundedSemaphore(max(1, self.operators)),
        }

    @contextlib.contextmanager
    def slot(self, operator: bool) -> Iterator[None]:
        lanes = ([True] if operator and self.operators else []) + [False]
        for lane in lanes:
            if self._lanes[lane].acquire(blocking=False):
                try:
                    yield
                finally:
                    self._lanes[lane].release()
                return
        raise Busy(
            f"{self.anonymous} schedule preview(s) are being computed for browsers without an operator "
            "token: try again in a second (operators signed in have previews of their own)"
            if not operator
            else "every preview slot is taken: try again in a second",
            1,
        )
