"""When the apparatus is where, and what colour the LEM shows: the dive's timeline.

Times are *dive time*: seconds since the start of the dive (the moment the
simulation's ``start`` datetime stands for). Depths are of the LEM, the
lowest module; the receivers hang above it on the same vertical cable.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

#: Phases in which the cameras run (the test stops are added by name).
STATION = "station"
MOVING_PHASES = ("descent", "ascent")


@dataclass(frozen=True)
class Segment:
    """One stretch of the dive: a phase, its time span and the LEM's depth at both ends."""

    phase: str
    start_s: float
    end_s: float
    depth_start_m: float
    depth_end_m: float


@dataclass(frozen=True)
class DiveProfile:
    """A T-REX dive: on deck, down with test stops, on station, up, recovered.

    The paper (section 2): test captures during the descent at 1200 m and
    2021 m, ~30 minutes of acquisition at 3420 m, sensors running through the
    ascent. Between the stops the winch pays out at a constant rate (the short
    accelerations at each stop are left out; the ship's heave dominates the
    vertical acceleration).

    Parameters
    ----------
    deck_s
        Time on deck before the LEM enters the water.
    descent_m_per_s, ascent_m_per_s
        Winch speeds.
    test_stops_m
        Depths of the test-capture stops, increasing, above the station.
    test_stop_s
        Time spent at each test stop.
    station_depth_m
        Depth of the LEM on station (T-REX: 3420 m).
    station_s
        Time on station.
    """

    deck_s: float = 60.0
    descent_m_per_s: float = 1.0
    test_stops_m: tuple[float, ...] = (1200.0, 2021.0)
    test_stop_s: float = 120.0
    station_depth_m: float = 3420.0
    station_s: float = 1800.0
    ascent_m_per_s: float = 1.0

    def __post_init__(self) -> None:
        for name in ("deck_s", "test_stop_s", "station_s"):
            value = getattr(self, name)
            if not (value >= 0 and math.isfinite(value)):
                raise ValueError(f"{name} must be a finite duration >= 0 s, got {value}")
        for name in ("descent_m_per_s", "ascent_m_per_s", "station_depth_m"):
            value = getattr(self, name)
            if not (value > 0 and math.isfinite(value)):
                raise ValueError(f"{name} must be > 0, got {value}")
        stops = tuple(float(d) for d in self.test_stops_m)
        object.__setattr__(self, "test_stops_m", stops)
        previous = 0.0
        for d in stops:
            if not (previous < d < self.station_depth_m):
                raise ValueError(
                    f"test_stops_m must increase strictly between 0 and station_depth_m "
                    f"({self.station_depth_m} m), got {stops}"
                )
            previous = d

    @staticmethod
    def stop_phase(depth_m: float) -> str:
        """Name of the test stop at ``depth_m``: ``"test-1200"``."""
        return f"test-{depth_m:g}"

    @cached_property
    def segments(self) -> tuple[Segment, ...]:
        """The dive as consecutive segments, ``deck`` first, ``recovered`` (open-ended) last."""
        out: list[Segment] = []
        t = 0.0

        def add(phase: str, duration_s: float, d0: float, d1: float) -> None:
            nonlocal t
            out.append(Segment(phase, t, t + duration_s, d0, d1))
            t += duration_s

        add("deck", self.deck_s, 0.0, 0.0)
        depth = 0.0
        for stop in self.test_stops_m:
            add("descent", (stop - depth) / self.descent_m_per_s, depth, stop)
            add(self.stop_phase(stop), self.test_stop_s, stop, stop)
            depth = stop
        add("descent", (self.station_depth_m - depth) / self.descent_m_per_s, depth, self.station_depth_m)
        add(STATION, self.station_s, self.station_depth_m, self.station_depth_m)
        add("ascent", self.station_depth_m / self.ascent_m_per_s, self.station_depth_m, 0.0)
        out.append(Segment("recovered", t, math.inf, 0.0, 0.0))
        return tuple(out)

    @cached_property
    def _starts(self) -> list[float]:
        return [s.start_s for s in self.segments]

    @cached_property
    def _knots(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Segment boundaries, LEM depth there and cumulative moving time there."""
        times = [0.0]
        depths = [0.0]
        moving = [0.0]
        for seg in self.segments[:-1]:
            times.append(seg.end_s)
            depths.append(seg.depth_end_m)
            moving.append(moving[-1] + (seg.end_s - seg.start_s if seg.phase in MOVING_PHASES else 0.0))
        return np.array(times), np.array(depths), np.array(moving)

    @property
    def duration_s(self) -> float:
        """Dive time at which the apparatus is back on deck (start of ``recovered``)."""
        return self.segments[-1].start_s

    @property
    def phases(self) -> tuple[str, ...]:
        """Phase names in order, each once."""
        return tuple(dict.fromkeys(s.phase for s in self.segments))

    def phase_at(self, t_s: float) -> str:
        """The phase at dive time ``t_s``; before 0 the apparatus is on deck."""
        if t_s < 0:
            return "deck"
        return self.segments[bisect.bisect_right(self._starts, t_s) - 1].phase

    def window(self, phase: str) -> tuple[float, float]:
        """Start and end (dive time, s) of ``phase``; for ``descent``, its first piece to its last."""
        spans = [(s.start_s, s.end_s) for s in self.segments if s.phase == phase]
        if not spans:
            raise ValueError(f"phase {phase!r} is not in this dive; phases: {', '.join(self.phases)}")
        return spans[0][0], spans[-1][1]

    def lem_depth_at(self, t_s: float) -> float:
        """Depth of the LEM at dive time ``t_s`` (0 on deck and after recovery)."""
        return float(self.lem_depths_m(np.array([t_s], dtype=np.float64))[0])

    def lem_depths_m(self, t_s: np.ndarray) -> np.ndarray:
        """`lem_depth_at` over an array of dive times."""
        times, depths, _ = self._knots
        return np.interp(np.asarray(t_s, dtype=np.float64), times, depths, left=0.0, right=0.0)

    def captures_enabled(self, t_s: float) -> bool:
        """True at the test stops and on station: when the cameras run. Sensors always run."""
        phase = self.phase_at(t_s)
        return phase == STATION or phase.startswith("test-")

    def moving_fraction(self, t_s: np.ndarray, smooth_s: float = 60.0) -> np.ndarray:
        """Share of the last ``smooth_s`` seconds the cable spent moving (descent, ascent).

        A continuous 0..1 envelope: drag and winch jerks grow while the cable
        moves and die away over about ``smooth_s`` after it stops, instead of
        switching on and off in one step.
        """
        if not smooth_s > 0:
            raise ValueError(f"smooth_s must be > 0, got {smooth_s}")
        times, _, moving = self._knots
        t = np.asarray(t_s, dtype=np.float64)
        cum = np.interp(t, times, moving, left=0.0, right=moving[-1])
        cum_before = np.interp(t - smooth_s, times, moving, left=0.0, right=moving[-1])
        return (cum - cum_before) / smooth_s


@dataclass(frozen=True)
class LEMTimetable:
    """The LEM's colour cycle in steady mode: each wavelength for ``dwell_s``, in turn.

    Dwell ``k`` (``k = floor((t - start_s) / dwell_s)``, any integer: the
    cycle extends before ``start_s`` too) shows ``wavelengths_nm[k % n]``.
    Frame headers record the wavelength the timetable says was on; a camera
    that knows the timetable can plan its shots so that no exposure straddles a
    change (`next_change_after`).
    """

    wavelengths_nm: tuple[int, ...] = (405, 460, 525)
    dwell_s: float = 60.0
    start_s: float = 0.0

    def __post_init__(self) -> None:
        wls = tuple(int(w) for w in self.wavelengths_nm)
        if not wls:
            raise ValueError("wavelengths_nm must not be empty")
        if len(set(wls)) != len(wls):
            raise ValueError(f"wavelengths_nm has repeated values: {wls}")
        object.__setattr__(self, "wavelengths_nm", wls)
        if not (self.dwell_s > 0 and math.isfinite(self.dwell_s)):
            raise ValueError(f"dwell_s must be > 0, got {self.dwell_s}")
        if not math.isfinite(self.start_s):
            raise ValueError(f"start_s must be finite, got {self.start_s}")

    @property
    def cycle_s(self) -> float:
        return self.dwell_s * len(self.wavelengths_nm)

    def dwell_index(self, t_s: float) -> int:
        return math.floor((t_s - self.start_s) / self.dwell_s)

    def wavelength_at(self, t_s: float) -> int:
        """The wavelength the LEM shows at dive time ``t_s``."""
        return self.wavelengths_nm[self.dwell_index(t_s) % len(self.wavelengths_nm)]

    def dwell_window(self, t_s: float) -> tuple[float, float]:
        """Start and end of the dwell containing ``t_s``."""
        k = self.dwell_index(t_s)
        return self.start_s + k * self.dwell_s, self.start_s + (k + 1) * self.dwell_s

    def next_change_after(self, t_s: float) -> float:
        """The first colour change strictly after ``t_s``."""
        return self.dwell_window(t_s)[1]

    def next_start_of(self, wavelength_nm: int, after_s: float) -> float:
        """The first time at or after ``after_s`` at which the LEM switches to ``wavelength_nm``."""
        try:
            i = self.wavelengths_nm.index(int(wavelength_nm))
        except ValueError:
            known = ", ".join(str(w) for w in self.wavelengths_nm)
            raise ValueError(f"wavelength_nm {wavelength_nm} is not in the timetable ({known})") from None
        n = len(self.wavelengths_nm)
        # First dwell starting at or after after_s (a hair of tolerance for float round-off).
        k0 = math.ceil((after_s - self.start_s) / self.dwell_s - 1e-9)
        k = k0 + (i - k0) % n
        return self.start_s + k * self.dwell_s

    def describe(self) -> dict[str, object]:
        """The timetable as plain values, for frame and session headers."""
        return {"wavelengths_nm": list(self.wavelengths_nm), "dwell_s": self.dwell_s, "start_s": self.start_s}
