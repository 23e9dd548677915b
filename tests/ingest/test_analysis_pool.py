"""The ingest's analysis pool when a process dies: real worker processes, really killed.

A frame whose analysis kills its process (``os._exit``, as a decoder crash or the OOM killer
would) breaks Python's whole pool. The pool must be replaced, every other frame of the dead
pool analysed again, and only the frame that kills a process on its own rejected.
"""

from __future__ import annotations

import os
import queue
import time
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


def run(
    paths: list[str], n_workers: int = 2, pause_s: float = 5.0
) -> tuple[dict[str, Any], AnalysisPool, list[str]]:
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
        restart_pause_s=pause_s,
    )
    pool.start()
    assert pool.ready.wait(60), "the worker processes did not start"
    for i, path in enumerate(paths):
        pool.queue(Job(i, path, {"module": "A"}))
    outcome: dict[str, Any] = {}
    deadline = time.monotonic() + 120
    try:
        while len(outcome) < len(paths):
            assert time.monotonic() < deadline, f"no outcome for {set(paths) - set(outcome)}"
            pool.feed()
            try:
                job, fut = done.get(timeout=0.05)
            except queue.Empty:  # nothing running (a dead pool waits for its pause): feed again
                continue
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
    outcome, pool, counted = run(paths, pause_s=0.3)
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


def test_processes_that_keep_dying_are_started_again_only_after_a_pause() -> None:
    """Deaths in a row (here every frame kills its process) must not start pools back to back."""
    paths = [f"/frames/{i}-poison.png" for i in range(3)]
    outcome, pool, counted = run(paths, pause_s=0.5)
    assert all(isinstance(v, BrokenProcessPool) for v in outcome.values()) and len(outcome) == 3
    # the three died together, then each alone: the first new pool at once, the next after a pause
    assert len(counted) == len(pool.crashes) == 4
    t = [when for when, _ in pool.crashes]
    assert t[2] - t[1] >= 0.5 and t[3] - t[2] >= 0.5
