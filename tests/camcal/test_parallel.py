"""The process pool that the frame-set analysis maps over."""

from __future__ import annotations

import os
import time

from camcal.core.parallel import map_in_order


def _square_and_pid(x: int) -> tuple[int, int]:
    time.sleep(0.02)  # a frame's worth of work: the pool is up long before this process could finish
    return x * x, os.getpid()


def test_results_come_in_order_each_reported_once_and_the_pool_does_the_bulk() -> None:
    seen: list[int] = []
    items = list(range(200))
    out = map_in_order(_square_and_pid, items, 2, lambda r: seen.append(r[0]))
    assert [r[0] for r in out] == [x * x for x in items]
    assert sorted(seen) == sorted(x * x for x in items)
    pids = {pid for _, pid in out}
    assert len(pids - {os.getpid()}) >= 1  # worker processes took part
    # this process only helps while the pool starts: the first items, in order
    here = [i for i, (_, pid) in enumerate(out) if pid == os.getpid()]
    assert here == list(range(len(here)))
    assert len(here) < len(items)
