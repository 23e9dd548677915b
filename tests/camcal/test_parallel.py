"""The threads that a frame set's decoding and analysis map over."""

from __future__ import annotations

import threading
import time

import cv2
import pytest

from camcal.core.parallel import map_in_threads
from tests.utils.pace import Pace


def _square_and_thread(x: int) -> tuple[int, str, int]:
    time.sleep(0.005)  # a frame's worth of waiting outside the interpreter's lock
    return x * x, threading.current_thread().name, cv2.getNumThreads()


def test_results_come_in_order_each_reported_once_on_worker_threads() -> None:
    seen: list[int] = []
    items = list(range(200))
    before = cv2.getNumThreads()
    out = map_in_threads(_square_and_thread, items, 2, lambda r: seen.append(r[0]))
    assert [r[0] for r in out] == [x * x for x in items]
    assert seen == [x * x for x in items]  # reported as they come, in order
    assert {name for _, name, _ in out} <= {"camcal-map_0", "camcal-map_1"}
    assert len({name for _, name, _ in out}) == 2  # both threads took part
    assert {n for _, _, n in out} == {1}  # OpenCV's own pool held at one thread meanwhile ...
    assert cv2.getNumThreads() == before  # ... and given back afterwards


def test_an_error_stops_the_map_and_what_had_not_started_never_runs() -> None:
    ran: list[int] = []
    # The items after the bad one take long enough that the caller, told of the error, cancels the
    # rest before the two threads could work through them, however busy the machine keeps it.
    slow_s = 0.2 * Pace().factor

    def fail_on_three(x: int) -> int:
        ran.append(x)
        time.sleep(0.01 if x <= 3 else slow_s)
        if x == 3:
            raise ValueError("frame 3 is bad")
        return x

    with pytest.raises(ValueError, match="frame 3"):
        map_in_threads(fail_on_three, list(range(100)), 2)
    assert len(ran) < 10
