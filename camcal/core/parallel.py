"""Worker processes that are safe to start from any process.

Forking a process that already runs threads (OpenCV's pool, a web server,
a ZeroMQ context) can leave a child waiting forever on a lock some thread
held at the moment of the fork. Pools here start their workers from a clean
fork server instead, which has the heavy modules already imported.

Nothing outlives the process that made the pool, however it ends (even
SIGKILL): each worker leaves as soon as that process is gone
(`camcal.core.supervise.exit_when_gone`) — it would otherwise wait forever on its
task queue, whose writing end it holds itself, and keep the fork server
alive, which serves as long as any of its clients lives. The fork server and
the resource tracker then see their pipes close and exit.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from typing import Any, TypeVar

from camcal.core.supervise import exit_when_gone

T = TypeVar("T")
R = TypeVar("R")

#: What every worker needs: the frame decoder and the analysis (no SciPy: a worker that needs it,
#: a simulator's, imports it itself). The fork server imports these once; each worker is a fork of it.
_PRELOAD = ["numpy", "cv2", "analysis", "camcal.core.frameset"]
_context: Any = None


def _get_context() -> Any:
    global _context
    if _context is None:
        ctx = multiprocessing.get_context("forkserver")
        ctx.set_forkserver_preload(_PRELOAD)
        _context = ctx
    return _context


def _init_worker(owner_pid: int, initializer: Callable[..., None] | None, initargs: tuple[Any, ...]) -> None:
    exit_when_gone(owner_pid)  # a worker holds nothing worth saving: its task is done again
    # Ctrl-C in a terminal reaches the whole process group: the owner stops the pool in order.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    import cv2

    cv2.setNumThreads(1)  # one process per core already
    if initializer is not None:
        initializer(*initargs)


def process_pool(
    workers: int, initializer: Callable[..., None] | None = None, initargs: tuple[Any, ...] = ()
) -> ProcessPoolExecutor:
    """A `ProcessPoolExecutor` of ``workers`` processes started by a fork server."""
    return ProcessPoolExecutor(
        max_workers=workers,
        mp_context=_get_context(),
        initializer=_init_worker,
        initargs=(os.getpid(), initializer, initargs),
    )


def map_in_threads(
    fn: Callable[[T], R],
    items: Sequence[T],
    workers: int,
    done: Callable[[R], None] | None = None,
) -> list[R]:
    """``[fn(x) for x in items]`` on ``workers`` threads of this process, in order; ``done`` is called
    on each result as it comes, in order.

    For work that runs outside the interpreter's lock: inflating a PNG
    (libdeflate), OpenCV, numpy's passes over whole frames. Two threads then
    keep two cores busy without a single process to start (a pool of
    processes costs the better part of a second before its first result,
    more than a frame set of a few hundred frames takes). OpenCV's own
    threads are held at one meanwhile: the threads here already fill the cores.
    """
    import cv2

    results: list[R] = []
    before = cv2.getNumThreads()
    cv2.setNumThreads(1)
    pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="camcal-map")
    try:
        for future in [pool.submit(fn, item) for item in items]:
            results.append(future.result())
            if done is not None:
                done(results[-1])
    finally:  # an error or Ctrl-C: what has not started never starts
        pool.shutdown(wait=True, cancel_futures=True)
        cv2.setNumThreads(before)
    return results
