"""A virtual clock, camera and LEM for the schedule runner's tests: time moves only when someone sleeps."""

from __future__ import annotations

import threading
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta

EPOCH = datetime(2021, 9, 10, 4, 0, 0, tzinfo=UTC)


class VirtualClock:
    """Seconds since EPOCH that advance only when someone sleeps."""

    def __init__(self) -> None:
        self.t = 0.0
        self._lock = threading.Lock()

    def now(self) -> datetime:
        return EPOCH + timedelta(seconds=self.monotonic())

    def monotonic(self) -> float:
        with self._lock:
            return self.t

    def sleep(self, seconds: float) -> None:
        with self._lock:
            self.t += seconds


@dataclass
class Shot:
    captured_at: datetime
    exposure_s: float
    gain_db: float
    wavelength_nm: int | None = None


class FakeCamera:
    """Records every capture with the virtual time it was taken at."""

    def __init__(self, clock: VirtualClock, readout_s: float = 0.0) -> None:
        self.clock = clock
        self.readout_s = readout_s
        self.taken: list[tuple[float, float, float]] = []

    def capture(self, exposure_s: float, gain_db: float) -> Shot:
        self.taken.append((self.clock.monotonic(), exposure_s, gain_db))
        t = self.clock.now()
        self.clock.sleep(exposure_s + self.readout_s)  # the exposure (and readout) take their time
        return Shot(t, exposure_s, gain_db)


class CyclingLem:
    """405, 460, 525 nm for ``dwell_s`` each, over and over, from EPOCH."""

    order = (405, 460, 525)

    def __init__(self, dwell_s: float = 10.0) -> None:
        self.dwell_s = dwell_s

    def _phase(self, t: datetime) -> float:
        return (t - EPOCH).total_seconds()

    def wavelength_at(self, t: datetime) -> int:
        return self.order[int(self._phase(t) // self.dwell_s) % 3]

    def next_start_of(self, wavelength_nm: int, after: datetime) -> datetime:
        s = self._phase(after)
        k = int(s // self.dwell_s) + 1
        while self.order[k % 3] != wavelength_nm:
            k += 1
        return EPOCH + timedelta(seconds=k * self.dwell_s)

    def next_change_after(self, t: datetime) -> datetime:
        return EPOCH + timedelta(seconds=(int(self._phase(t) // self.dwell_s) + 1) * self.dwell_s)
