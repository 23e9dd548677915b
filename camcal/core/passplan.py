"""How one pass of a schedule meets the LEM's colour cycle, walked in virtual time.

The module's runner (`lrm.runner.ScheduleRunner`) waits for the LEM's colour at
the start of a wavelength's shots, starts no exposure the LEM would change
colour in, and when the LEM moves on amid a wavelength's shots takes the rest
first at that colour's next turn. Before an operator sends a
schedule the ship says how long a pass will take and over how many turns of
each colour its shots are spread: this walks the runner's rules in virtual
time, over several phases of the LEM's cycle (``tests/lrm/test_passplan.py``
runs the real runner beside it). Only what the schedule, the camera's readout
and the LEM's timetable decide is walked: no gate (stops, station), no pauses
by the operator, no slow card.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from camcal.core.schedule import KNOWN_WAVELENGTHS_NM, Schedule, Shot, defer_rest_of_run, run_bounds

#: Passes walked per phase of the LEM (the first is dropped: it starts wherever the LEM stood).
_PASSES = 3
#: Phases of the LEM's cycle a pass may start at (fewer for large schedules: ``_MAX_STEPS``).
_PHASES = 6
#: Shots walked in all, at most (a preview must answer at once; 20,000 shots take ~0.1 s).
_MAX_STEPS = 60_000


@dataclass(frozen=True)
class PassPlan:
    """One pass of a schedule against the LEM's cycle: its duration and how it is spread."""

    #: Mean duration of one pass in steady state (pause included), over the LEM's phase.
    duration_s: float
    #: Exposure and readout of every shot of one pass: the camera's own time.
    shooting_s: float
    #: The LEM's time on one colour (None: no LEM timetable; the pass is the shooting and the pause).
    dwell_s: float | None
    #: Per wavelength, the shooting time of its longest run of consecutive shots in one pass.
    longest_run_s: dict[int, float] = field(default_factory=dict)
    #: Per wavelength, the mean number of the LEM's turns of that colour one pass takes shots in.
    turns: dict[int, float] = field(default_factory=dict)
    pause_s: float = 0.0

    @property
    def busy_share(self) -> float:
        """Share of a pass the camera is exposing or reading out (the rest it waits for colours)."""
        return min(1.0, self.shooting_s / self.duration_s) if self.duration_s > 0 else 1.0

    def warnings(self) -> list[str]:
        """What an operator should know before sending (not problems: the module can run it)."""
        if self.dwell_s is None:
            return []
        longest = max(self.longest_run_s.values(), default=0.0)
        if longest <= self.dwell_s:
            return []
        if max(self.turns.values(), default=1.0) < 1.5:
            return [
                f"a wavelength's run of shots takes up to {_fmt(longest)}, a little longer than the LEM "
                f"shows a colour ({_fmt(self.dwell_s)}): the shots a turn leaves are taken first at the next"
            ]
        turns = ", ".join(f"{wl} nm {n:.1f}" for wl, n in sorted(self.turns.items()))
        return [
            f"a wavelength's run of shots takes up to {_fmt(longest)}, longer than the LEM shows a colour "
            f"({_fmt(self.dwell_s)}): the module spreads a pass over several turns of a colour (turns a "
            f"pass: {turns}), taking what a turn left first at the next, so a λ_att visit holds only "
            "part of the settings"
        ]


def _fmt(seconds: float) -> str:
    if seconds < 120:
        return f"{round(seconds, 1):g} s"
    if seconds < 7200:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def plan_pass(
    schedule: Schedule,
    readout_s: float,
    lem_dwell_s: float | None,
    lem_wavelengths_nm: tuple[int, ...] = KNOWN_WAVELENGTHS_NM,
) -> PassPlan:
    """Walk the schedule's passes against a LEM showing each colour ``lem_dwell_s`` in turn."""
    shots = list(schedule.shots())
    shooting = sum(s.exposure_s + readout_s for s in shots)
    runs: dict[int, float] = {}  # per wavelength, its longest run
    per_pass: dict[int, float] = {}  # per wavelength, all its shots
    for wl, t in _runs(shots, readout_s):
        runs[wl] = max(runs.get(wl, 0.0), t)
        per_pass[wl] = per_pass.get(wl, 0.0) + t
    if not lem_dwell_s or not shots:
        return PassPlan(shooting + schedule.pause_s, shooting, None, runs, {}, schedule.pause_s)
    missing = {s.wavelength_nm for s in shots} - set(lem_wavelengths_nm)
    if missing:
        raise ValueError(f"the LEM never shows {sorted(missing)} nm")
    phases = max(1, min(_PHASES, _MAX_STEPS // (len(shots) * _PASSES)))
    cycle_s = lem_dwell_s * len(lem_wavelengths_nm)
    elapsed = taken_s = 0.0
    dwells: dict[int, int] = {}
    taken_wl: dict[int, float] = {}
    for k in range(phases):
        walk = _Walk(shots, readout_s, lem_dwell_s, lem_wavelengths_nm, schedule.pause_s)
        walk.t = cycle_s * (k + 0.5) / phases
        walk.take(len(shots))  # the first pass starts wherever the LEM stood: not counted
        start = walk.t
        window = walk.take(len(shots) * (_PASSES - 1))
        elapsed += walk.t - start
        taken_s += sum(d for _, _, d in window)
        for wl, (n, t) in _window_use(window, lem_dwell_s).items():
            dwells[wl] = dwells.get(wl, 0) + n
            taken_wl[wl] = taken_wl.get(wl, 0.0) + t
    # the shots a window holds are not exactly one pass's (what a turn left moves on): scale by time
    turns = {wl: dwells[wl] * per_pass[wl] / taken_wl[wl] for wl in dwells}
    return PassPlan(shooting * elapsed / taken_s, shooting, lem_dwell_s, runs, turns, schedule.pause_s)


def _window_use(taken: list[tuple[float, int, float]], dwell_s: float) -> dict[int, tuple[int, float]]:
    """Per wavelength, of shots taken as (start, wavelength, duration): the LEM's dwells and the time used.

    The window's first and last dwells are left out: the window may cut them.
    """
    ks = [_dwell(t, dwell_s) for t, _, _ in taken]
    lo, hi = min(ks), max(ks)
    out: dict[int, tuple[set[int], float]] = {}
    for k, (_, wl, d) in zip(ks, taken, strict=True):
        if lo < k < hi:
            seen, used = out.get(wl, (set(), 0.0))
            seen.add(k)
            out[wl] = (seen, used + d)
    return {wl: (len(seen), used) for wl, (seen, used) in out.items()}


def _dwell(t: float, dwell_s: float) -> int:
    """The LEM's dwell at ``t``, read as the module reads it: from a time to the microsecond."""
    return math.floor(round(t, 6) / dwell_s)


def _runs(shots: list[Shot], readout_s: float) -> list[tuple[int, float]]:
    """(wavelength, shooting time) of each run of consecutive shots at one wavelength."""
    out: list[tuple[int, float]] = []
    for s in shots:
        t = s.exposure_s + readout_s
        if out and out[-1][0] == s.wavelength_nm:
            out[-1] = (s.wavelength_nm, out[-1][1] + t)
        else:
            out.append((s.wavelength_nm, t))
    return out


class _Walk:
    """The runner's rules in virtual time (`lrm.runner.ScheduleRunner.next_capture`)."""

    def __init__(
        self, shots: list[Shot], readout_s: float, dwell_s: float, order: tuple[int, ...], pause_s: float
    ) -> None:
        self.shots, self.readout_s, self.dwell_s, self.order = list(shots), readout_s, dwell_s, order
        self.runs = run_bounds(self.shots)  # a deferral turns shots within their run only
        self.pause_s = pause_s
        self.t = 0.0
        self.index = 0
        self.last_taken: int | None = None

    def _dwell(self, t: float) -> int:
        return _dwell(t, self.dwell_s)

    def _colour(self, t: float) -> int:
        return self.order[self._dwell(t) % len(self.order)]

    def _next_start(self, wl: int, t: float) -> float:
        k = math.ceil(t / self.dwell_s - 1e-9)
        while self.order[k % len(self.order)] != wl:
            k += 1
        return k * self.dwell_s

    def take(self, n: int) -> list[tuple[float, int, float]]:
        """Take ``n`` shots; each as (start, wavelength, exposure + readout).

        As the runner does, the pause follows each time the list of shots wraps (with deferred
        shots, more than once a pass).
        """
        taken: list[tuple[float, int, float]] = []
        while len(taken) < n:
            if self.index >= len(self.shots):
                self.index = 0
                self.t += self.pause_s
            shot = self.shots[self.index]
            if self._colour(self.t) != shot.wavelength_nm or not self._fits(shot.exposure_s):
                if not self._defer():
                    self.t = self._next_start(shot.wavelength_nm, self.t) + 1e-3
                continue
            d = shot.exposure_s + self.readout_s
            taken.append((self.t, shot.wavelength_nm, d))
            self.t += d
            self.last_taken = self.index
            self.index += 1
        return taken

    def _fits(self, exposure_s: float) -> bool:
        """An exposure started now ends before the LEM changes colour (or could never fit a dwell)."""
        change = (self._dwell(self.t) + 1) * self.dwell_s
        return exposure_s >= self.dwell_s or round(self.t + exposure_s, 6) <= change

    def _defer(self) -> bool:
        if self.last_taken != self.index - 1 or self.index >= len(self.shots):
            return False
        j = defer_rest_of_run(self.shots, self.index, self.runs[self.index])
        if j is None:
            return False
        self.index, self.last_taken = j, None
        return True
