"""Clocks for the module: the real one, and a simulated one that runs faster.

Everything on the module that reads the time or waits (the schedule runner,
the camera, the sensor loop) takes a `Clock`, so that a whole 2.5-hour dive
can be replayed in minutes on a workstation (`SimClock`) and the same code
runs on the Raspberry Pi with `SystemClock`.

Three notions of time are kept apart:

* ``now()``: wall-clock UTC, what frame headers and sensor samples carry;
* ``monotonic()``: seconds for measuring intervals, never jumps back;
* ``sleep(seconds)``: waiting, in seconds of the clock's own time.
"""

from __future__ import annotations

import math
import threading
import time
from datetime import UTC, datetime, timedelta
from typing import Protocol, runtime_checkable


@runtime_checkable
class Clock(Protocol):
    """What the module needs to know about time."""

    def now(self) -> datetime:
        """The current time, timezone-aware UTC."""
        ...

    def monotonic(self) -> float:
        """Seconds on a monotonic scale, for intervals only."""
        ...

    def sleep(self, seconds: float) -> None:
        """Wait ``seconds`` of this clock's time."""
        ...


def _check_seconds(seconds: float) -> float:
    seconds = float(seconds)
    if not (seconds >= 0 and math.isfinite(seconds)):
        raise ValueError(f"seconds must be a finite number >= 0, got {seconds}")
    return seconds


class SystemClock:
    """Real time: `datetime.now(UTC)`, `time.monotonic` and `time.sleep`."""

    def now(self) -> datetime:
        return datetime.now(UTC)

    def monotonic(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        time.sleep(_check_seconds(seconds))

    def wait(self, event: threading.Event, seconds: float) -> bool:
        """Wait up to ``seconds`` for ``event``; True if it was set (an interruptible sleep)."""
        return event.wait(_check_seconds(seconds))


class SimClock:
    """Simulated time running ``speed`` times faster than real time.

    ``now() = start + elapsed_real * speed``; ``sleep(s)`` sleeps ``s / speed``
    real seconds. The clock keeps running whether anyone sleeps or not, as a
    real clock does, so threads sharing it stay in step. `set_speed` changes
    the rate without a jump in simulated time. Safe to share between threads.

    Parameters
    ----------
    start
        Simulated time at creation, timezone-aware (converted to UTC).
    speed
        Simulated seconds per real second, > 0.
    """

    def __init__(self, start: datetime, speed: float = 1.0) -> None:
        if start.tzinfo is None or start.utcoffset() is None:
            raise ValueError(f"start must be timezone-aware (UTC), got naive {start.isoformat()}")
        self._lock = threading.Lock()
        self._start = start.astimezone(UTC)
        self._speed = self._check_speed(speed)
        # Simulated seconds at the last rebase, and the real time of that rebase.
        self._base_sim_s = 0.0
        self._base_real_s = time.monotonic()

    @classmethod
    def synced(cls, start: datetime, speed: float, real_epoch_unix_s: float) -> SimClock:
        """A clock whose simulated ``start`` happened at wall-clock time ``real_epoch_unix_s``.

        Processes that build their clocks from the same start, speed and
        epoch agree on the simulated time (to the precision of the host
        clock), so two simulated modules in separate processes stay in step.
        """
        clock = cls(start, speed)
        with clock._lock:
            clock._base_sim_s = (time.time() - real_epoch_unix_s) * clock._speed
            clock._base_real_s = time.monotonic()
        return clock

    @staticmethod
    def _check_speed(speed: float) -> float:
        speed = float(speed)
        if not (speed > 0 and math.isfinite(speed)):
            raise ValueError(f"speed must be a finite number > 0, got {speed}")
        return speed

    @property
    def start(self) -> datetime:
        return self._start

    @property
    def speed(self) -> float:
        with self._lock:
            return self._speed

    def elapsed_s(self) -> float:
        """Simulated seconds since ``start``."""
        with self._lock:
            return self._base_sim_s + (time.monotonic() - self._base_real_s) * self._speed

    def now(self) -> datetime:
        return self._start + timedelta(seconds=self.elapsed_s())

    def monotonic(self) -> float:
        return self.elapsed_s()

    def sleep(self, seconds: float) -> None:
        seconds = _check_seconds(seconds)
        if seconds > 0:
            time.sleep(seconds / self.speed)

    def wait(self, event: threading.Event, seconds: float) -> bool:
        """Wait up to ``seconds`` of simulated time for ``event``; True if it was set."""
        return event.wait(_check_seconds(seconds) / self.speed)

    def set_speed(self, speed: float) -> None:
        """Run at a new rate from now on; simulated time continues where it was."""
        speed = self._check_speed(speed)
        with self._lock:
            real = time.monotonic()
            self._base_sim_s += (real - self._base_real_s) * self._speed
            self._base_real_s = real
            self._speed = speed

    def __repr__(self) -> str:
        return f"SimClock(start={self._start.isoformat()}, speed={self.speed})"
