"""Clocks: the real one and the simulated one that runs faster."""

from __future__ import annotations

import threading
import time
from datetime import UTC, datetime, timedelta

import pytest

from lrm.clock import Clock, SimClock, SystemClock
from tests.utils.pace import Pace

START = datetime(2021, 9, 10, 4, 0, 0, tzinfo=UTC)


def test_sim_clock_runs_speed_times_faster() -> None:
    clock = SimClock(START, speed=50.0)
    pace = Pace()
    before = time.monotonic()
    sim0 = clock.monotonic()
    after = time.monotonic()
    clock.sleep(2.0)  # 40 ms of real time
    real = time.monotonic() - before
    assert 0.039 <= real < pace.bound(0.5), (real, str(pace))
    r1 = time.monotonic()
    elapsed = clock.monotonic() - sim0
    r2 = time.monotonic()
    assert elapsed >= 2.0
    # the simulated interval lies within the real one bracketing its two readings, × 50 (on a busy
    # machine a reading may wait between the clocks: the bracket holds that, a fixed tolerance did not)
    assert (r1 - after) * 50.0 * 0.999 <= elapsed <= (r2 - before) * 50.0 * 1.001, (
        elapsed,
        r1 - after,
        r2 - before,
    )
    now = clock.now()
    assert now.tzinfo is not None and now.utcoffset() == timedelta(0)
    assert (now - START).total_seconds() == pytest.approx(clock.elapsed_s(), abs=0.5)


def test_set_speed_keeps_time_continuous() -> None:
    clock = SimClock(START, speed=10.0)
    clock.sleep(0.5)
    real0 = time.monotonic()
    before = clock.elapsed_s()
    clock.set_speed(1000.0)
    after = clock.elapsed_s()
    real = time.monotonic() - real0
    # no jump: what passed is at most the real time between the reads at the new speed
    assert 0 <= after - before <= real * 1000.0 + 1e-6, (after - before, real)
    clock.sleep(20.0)  # 20 ms real
    assert clock.elapsed_s() >= before + 20.0


def test_sim_clock_is_shared_safely_between_threads() -> None:
    clock = SimClock(START, speed=100.0)
    seen: list[float] = []
    lock = threading.Lock()

    def worker() -> None:
        last = 0.0
        for _ in range(200):
            now = clock.monotonic()
            assert now >= last
            last = now
            clock.set_speed(100.0)
        with lock:
            seen.append(last)

    threads = [threading.Thread(target=worker) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(seen) == 4


def test_interruptible_wait() -> None:
    clock = SimClock(START, speed=1000.0)
    event = threading.Event()
    assert clock.wait(event, 10.0) is False  # 10 ms real
    event.set()
    assert clock.wait(event, 1e6) is True


@pytest.mark.parametrize("clock", [SystemClock(), SimClock(START, 10.0)])
def test_clocks_follow_the_protocol_and_check_their_input(clock: Clock) -> None:
    assert isinstance(clock, Clock)
    assert clock.now().utcoffset() == timedelta(0)
    with pytest.raises(ValueError, match="seconds"):
        clock.sleep(-1.0)


def test_sim_clock_rejects_bad_arguments() -> None:
    with pytest.raises(ValueError, match="speed"):
        SimClock(START, speed=0.0)
    with pytest.raises(ValueError, match="start"):
        SimClock(datetime(2021, 9, 10), speed=1.0)
