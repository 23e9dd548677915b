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
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
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


def start_fork_server() -> None:
    """Start the fork server now, so that its imports run beside this process's own work.

    A pool made later forks its workers from it at once instead of waiting
    for numpy, OpenCV and the analysis to load (the better part of a second).
    Cheap to call twice; a process that never makes a pool only paid one idle
    process.
    """
    from multiprocessing import forkserver

    _get_context()  # sets the preload list
    forkserver.ensure_running()


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


def _ready() -> None:
    """Nothing: running it proves a worker process is up."""


def map_in_order(
    fn: Callable[[T], R],
    items: Sequence[T],
    workers: int,
    done: Callable[[R], None] | None = None,
) -> list[R]:
    """``[fn(x) for x in items]`` on a pool of ``workers`` processes; ``done`` is called on each result.

    Starting the pool takes the better part of a second (the fork server
    imports numpy, OpenCV, SciPy before it forks a worker). Until it is up,
    this process works through the list itself, so a short job does not
    wait idle for the pool. ``fn`` must be picklable (module level).
    """
    results: list[R] = []
    with process_pool(workers) as pool:
        up = threading.Event()

        def start() -> None:
            try:
                for warm in [pool.submit(_ready) for _ in range(workers)]:
                    warm.result()
            finally:
                up.set()

        starter = threading.Thread(target=start, name="pool-start", daemon=True)
        starter.start()
        while not up.is_set() and len(results) < len(items):
            results.append(fn(items[len(results)]))
            if done is not None:
                done(results[-1])
        starter.join()
        for future in [pool.submit(fn, item) for item in items[len(results) :]]:
            results.append(future.result())
            if done is not None:
                done(results[-1])
    return results
