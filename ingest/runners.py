"""Where a re-analysis runs its batches: in this process, on a local process pool, or on Dask.

A runner maps one function over batches and yields each batch's result as
soon as it is done (in any order), so the caller can store results while
the rest still run. The Dask runner works with a `distributed.LocalCluster`
on this machine or with any scheduler address; its workers need camcal
installed and read frames through fsspec (no shared file system needed for
frames in object storage).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import as_completed
from typing import Any, Protocol

log = logging.getLogger("camcal.runners")


class BatchRunner(Protocol):
    """Runs ``fn(batch, **kwargs)`` for every batch; yields the results as they complete."""

    def map(self, fn: Callable[..., Any], batches: Sequence[Any], **kwargs: Any) -> Iterator[Any]: ...

    def close(self) -> None: ...


class LocalRunner:
    """In this process (``workers <= 1``), or on a process pool started from the fork server."""

    def __init__(self, workers: int = 1) -> None:
        self.workers = workers

    def map(self, fn: Callable[..., Any], batches: Sequence[Any], **kwargs: Any) -> Iterator[Any]:
        if self.workers <= 1 or len(batches) <= 1:
            for b in batches:
                yield fn(b, **kwargs)
            return
        from camcal.core.parallel import process_pool

        pool = process_pool(min(self.workers, len(batches)))
        try:
            futures = [pool.submit(fn, b, **kwargs) for b in batches]
            for fut in as_completed(futures):
                yield fut.result()
        finally:  # left early (stopped, failed): the batches not started are dropped, not waited for
            pool.shutdown(wait=True, cancel_futures=True)

    def close(self) -> None:
        pass


def _opencv_plugin() -> Any:
    """A Dask worker plugin: OpenCV runs one thread per worker (a cluster has one worker per core)."""
    from distributed import WorkerPlugin

    class OneThreadForOpenCV(WorkerPlugin):  # type: ignore[misc]
        name = "camcal-opencv-threads"

        def setup(self, worker: Any) -> None:
            import cv2

            cv2.setNumThreads(1)

    return OneThreadForOpenCV()


def _warm_up() -> None:
    import ingest.worker  # noqa: F401  (numpy, OpenCV, SciPy and the analysis)


class DaskRunner:
    """Batches as Dask tasks: on a new `LocalCluster` of ``workers`` processes, or on ``scheduler``.

    ``close`` shuts down a cluster this runner started, never one it was
    only given the address of.
    """

    def __init__(self, *, workers: int = 2, scheduler: str | None = None, client: Any | None = None) -> None:
        from distributed import Client, LocalCluster

        self._cluster = None
        if client is not None:
            self.client, self._own_client = client, False
        elif scheduler is not None:
            self.client, self._own_client = Client(scheduler, timeout="20s"), True
        else:
            self._cluster = LocalCluster(
                n_workers=workers,
                threads_per_worker=1,
                processes=True,
                # A free loopback port: never 8787 (another cluster or a second re-analysis may hold it).
                dashboard_address="127.0.0.1:0",
                host="127.0.0.1",
                silence_logs=logging.WARNING,
            )
            self.client, self._own_client = Client(self._cluster), True
        self.client.register_plugin(_opencv_plugin())
        self.client.run(_warm_up)  # import the analysis once per worker, before any timing starts

    @property
    def n_workers(self) -> int:
        return len(self.client.scheduler_info().get("workers", {}))

    def map(self, fn: Callable[..., Any], batches: Sequence[Any], **kwargs: Any) -> Iterator[Any]:
        from distributed import as_completed as dask_as_completed

        if not batches:
            return
        futures = self.client.map(fn, list(batches), pure=False, **kwargs)
        try:
            for fut in dask_as_completed(futures):
                yield fut.result()
                fut.release()
        finally:
            self.client.cancel(futures)

    def close(self) -> None:
        if self._own_client:
            self.client.close()
        if self._cluster is not None:
            self._cluster.close()
