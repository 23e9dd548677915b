"""Expensive work the API starts, kept within bounds: re-analyses queued, exports a few at a time.

A re-analysis costs tens of seconds of CPU on every core it gets; a dive's
export reads every row of the dive. Neither may be started as often as
someone can click (or script) the button: `ReanalysisQueue` runs
re-analyses one at a time, in the order they were asked for, and refuses
more than a few waiting (503); `ExportSlots` lets ``n`` exports run at once
and refuses the next (503, try again later). Both are made by the app's
lifespan and stopped with it.
"""

from __future__ import annotations

import contextlib
import logging
import queue
import threading
from collections.abc import Callable

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

    A queued run has the status ``queued`` until its turn; runs still queued
    when the server stops are marked ``cancelled``.
    """

    def __init__(self, store: Store, max_queued: int) -> None:
        self.store = store
        self._q: queue.Queue[tuple[int, Callable[[], None]] | None] = queue.Queue(max_queued)
        self._thread = threading.Thread(target=self._run, name="reanalysis-queue", daemon=True)
        self._thread.start()

    def submit(self, run_id: int, job: Callable[[], None]) -> None:
        """Queue ``job`` (which fills run ``run_id``); `Busy` if too many wait already."""
        self.store.finish_run(run_id, "queued")
        try:
            self._q.put_nowait((run_id, job))
        except queue.Full:
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
            self.store.finish_run(run_id, "running")
            try:
                job()
            except Exception:  # recorded as a failed run (and logged); the queue goes on
                log.exception("re-analysis run %s failed", run_id)

    def stop(self) -> None:
        """Cancel what waits; let the running one end with the process."""
        while True:
            try:
                item = self._q.get_nowait()
            except queue.Empty:
                break
            if item is not None:
                self.store.finish_run(item[0], "cancelled")
        with contextlib.suppress(queue.Full):
            self._q.put_nowait(None)


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
