"""Worker processes that are safe to start from any process.

Forking a process that already runs threads (OpenCV's pool, a web server,
a ZeroMQ context) can leave a child waiting forever on a lock some thread
held at the moment of the fork. Pools here start their workers from a clean
fork server instead, which has the heavy modules already imported.
"""

from __future__ import annotations

import multiprocessing
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from typing import Any

_PRELOAD = ["numpy", "cv2", "scipy.optimize", "analysis", "camcal.frameset"]
_context: Any = None


def _get_context() -> Any:
    global _context
    if _context is None:
        ctx = multiprocessing.get_context("forkserver")
        ctx.set_forkserver_preload(_PRELOAD)
        _context = ctx
    return _context


def _init_worker(initializer: Callable[..., None] | None, initargs: tuple[Any, ...]) -> None:
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
        initargs=(initializer, initargs),
    )
