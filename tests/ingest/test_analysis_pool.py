"""The ingest's analysis pool when a process dies: real worker processes, really killed.

A frame whose analysis kills its process (``os._exit``, as a decoder crash or the OOM killer
would) breaks Python's whole pool. The pool must be replaced, every other frame of the dead
pool analysed again, and only the frame that kills a process on its own rejected.
"""

from __future__ import annotations

import os
import queue
from concurrent.futures import Future
from concurrent.futures.process import BrokenProcessPool
from typing import Any

from analysis import FrameConfig
from ingest.analysis_pool import AnalysisPool, Job


def analyse_or_die(path: str, config: FrameConfig, thumb: str | None) -> dict[str, Any]:
    """In a worker process: a result for every frame but the poisoned one, which kills the process."""
    if path.endswith("poison.png"):
        os._exit(3)
    return {"status": "ok", "path": path}


def run(paths: list[str], n_workers: int = 2) -> tuple[dict[str, Any], AnalysisPool, list[str]]:
    """Drive the pool as the ingest's store thread does until every frame has an outcome."""
    done: queue.Queue[tuple[Job, Future[Any]]] = queue.Queue()
    counted: list[str] = []
    pool = AnalysisPool(
        n_workers,
        frame_config=lambda module: FrameConfig(),
        file_of=lambda path: path,
        thumb_of=lambda frame_id: None,
        deliver=lambda job, fut: done.put((job, fut)),
        count=counted.append,
        analyse=analyse_or_die,
    )
    pool.start()
    assert pool.ready.wait(60), "the worker processes did not start"
    for i, path in enumerate(paths):
        pool.queue(Job(i, path, {"module": "A"}))
    outcome: dict[str, Any] = {}
    try:
        while len(outcome) < len(paths):
            pool.feed()
            job, fut = done.get(timeout=60)
            pool.done(1)
            if pool.crashed(fut):
                continue
            assert job.path not in outcome, f"{job.path} came back twice"
            exc = fut.exception()
            outcome[job.path] = exc if exc is not None else fut.result()
    finally:
        pool.stop()
    return outcome, pool, counted


def test_a_frame_that_kills_its_process_is_the_only_one_rejected() -> None:
    paths = [f"/frames/{i:03d}.png" for i in range(30)]
    paths.insert(7, "/frames/poison.png")
    outcome, pool, counted = run(paths)
    assert isinstance(outcome.pop("/frames/poison.png"), BrokenProcessPool)
    assert outcome == {p: {"status": "ok", "path": p} for p in paths if "poison" not in p}
    # two crashes: with the others in the pool, then alone (which names the frame for certain)
    assert counted == ["analysis_restarts", "analysis_restarts"]
    assert len(pool.crashes) == 2 and "alone" in pool.crashes[-1][1]
    assert not pool.backlog and not pool.suspects and pool.in_flight == 0


def test_without_a_crash_every_frame_is_analysed_once_and_nothing_restarts() -> None:
    paths = [f"/frames/{i:03d}.png" for i in range(40)]
    outcome, pool, counted = run(paths)
    assert set(outcome) == set(paths) and counted == [] and not pool.crashes
