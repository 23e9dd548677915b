"""Exposure schedules: exposures x gains x repeats x wavelengths, plus order and pauses.

One compact description, shared by the module (which runs it), the ship
(which validates, previews and sends it) and the simulator. A schedule is
never sent as an expanded list of frames.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from camcal.core.numbers import Integer, Number

#: The T-REX schedule (paper, section 2).
TREX_EXPOSURES_S: tuple[float, ...] = (0.02, 0.05, 0.07, 0.11, 0.2, 0.5, 1.0)
TREX_GAINS_DB: tuple[float, ...] = tuple(float(g) for g in range(2, 21, 2))
TREX_REPEATS = 20
KNOWN_WAVELENGTHS_NM: tuple[int, ...] = (405, 460, 525)
#: Most frames one pass may hold: a pass longer than a dive is a mistake.
MAX_FRAMES_PER_PASS = 20_000


@dataclass(frozen=True, order=True)
class Shot:
    """One capture of a schedule: a setting and the repeat index within it."""

    wavelength_nm: int
    exposure_s: float
    gain_db: float
    repeat: int


def _positive(values: tuple[float, ...], what: str) -> tuple[float, ...]:
    for x in values:
        if not (0 < x <= 3600):
            raise ValueError(f"{what} {x} s must be > 0 and at most an hour")
    if len(set(values)) != len(values):
        raise ValueError(f"{what} has repeated values")
    return values


class Block(BaseModel):
    """A further grid of a schedule (e.g. the gain sweep of a linearity scan)."""

    model_config = ConfigDict(frozen=True, extra="forbid")
    exposures_s: tuple[Number, ...] = Field(min_length=1, max_length=64)
    gains_db: tuple[Number, ...] = Field(min_length=1, max_length=64)
    repeats: Integer = Field(1, ge=1, le=1000)

    @field_validator("exposures_s")
    @classmethod
    def _exposures(cls, v: tuple[float, ...]) -> tuple[float, ...]:
        return _positive(v, "exposure")

    @field_validator("gains_db")
    @classmethod
    def _gains(cls, v: tuple[float, ...]) -> tuple[float, ...]:
        if any(not -60 <= g <= 60 for g in v):
            raise ValueError("gains must lie within ±60 dB")
        if len(set(v)) != len(v):
            raise ValueError("gain has repeated values")
        return v


class Schedule(BaseModel):
    """A named, versioned exposure schedule.

    The main grid is ``exposures_s x gains_db x repeats``; ``blocks`` adds
    further grids taken after it (a linearity scan is an exposure sweep at
    one gain plus a gain sweep at one exposure). ``order`` says which loop is
    outermost: ``"wavelength"`` (every setting at 405 nm, then 460, then
    525: the LEM changes colour least often) or ``"setting"`` (each setting
    at every wavelength in turn). ``pause_s`` is idle time after each pass.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    name: str = Field("custom", min_length=1, max_length=80)
    version: Integer = Field(1, ge=1, le=2**31 - 1)
    exposures_s: tuple[Number, ...] = Field(min_length=1, max_length=64)
    gains_db: tuple[Number, ...] = Field(min_length=1, max_length=64)
    repeats: Integer = Field(1, ge=1, le=1000)
    wavelengths_nm: tuple[Integer, ...] = Field(KNOWN_WAVELENGTHS_NM, min_length=1, max_length=8)
    blocks: tuple[Block, ...] = Field((), max_length=16)
    order: str = Field("wavelength", pattern="^(wavelength|setting)$")
    pause_s: Number = Field(0.0, ge=0, le=86400)

    @field_validator("exposures_s")
    @classmethod
    def _exposures(cls, v: tuple[float, ...]) -> tuple[float, ...]:
        return _positive(v, "exposure")

    @field_validator("gains_db")
    @classmethod
    def _gains(cls, v: tuple[float, ...]) -> tuple[float, ...]:
        return Block._gains(v)  # type: ignore[call-arg]

    @field_validator("wavelengths_nm")
    @classmethod
    def _known_wavelengths(cls, v: tuple[int, ...]) -> tuple[int, ...]:
        for wl in v:
            if wl not in KNOWN_WAVELENGTHS_NM:
                known = ", ".join(str(k) for k in KNOWN_WAVELENGTHS_NM)
                raise ValueError(f"wavelength {wl} nm is not one of the LEM's ({known})")
        if len(set(v)) != len(v):
            raise ValueError("wavelengths_nm has repeated values")
        return v

    @model_validator(mode="after")
    def _budget(self) -> Schedule:
        if self.n_frames > MAX_FRAMES_PER_PASS:
            raise ValueError(
                f"one pass would take {self.n_frames} frames, more than the budget of {MAX_FRAMES_PER_PASS}"
            )
        return self

    def grids(self) -> list[tuple[tuple[float, ...], tuple[float, ...], int]]:
        """The main grid and the extra blocks as (exposures, gains, repeats)."""
        return [(self.exposures_s, self.gains_db, self.repeats)] + [
            (b.exposures_s, b.gains_db, b.repeats) for b in self.blocks
        ]

    def settings(self) -> list[tuple[float, float, int]]:
        """Every (exposure, gain, repeats) of one wavelength, in order, without duplicates."""
        seen: set[tuple[float, float]] = set()
        out = []
        for exposures, gains, repeats in self.grids():
            for exp in exposures:
                for gain in gains:
                    if (exp, gain) not in seen:
                        seen.add((exp, gain))
                        out.append((exp, gain, repeats))
        return out

    @property
    def n_frames(self) -> int:
        """Frames in one pass."""
        return sum(r for _, _, r in self.settings()) * len(self.wavelengths_nm)

    def shots(self) -> Iterator[Shot]:
        """Every capture of one pass, in the schedule's order."""
        settings = self.settings()
        if self.order == "wavelength":
            for wl in self.wavelengths_nm:
                for exp, gain, repeats in settings:
                    for k in range(repeats):
                        yield Shot(wl, exp, gain, k)
        else:
            for exp, gain, repeats in settings:
                for wl in self.wavelengths_nm:
                    for k in range(repeats):
                        yield Shot(wl, exp, gain, k)


def defer_rest_of_run(shots: list[Shot], i: int, run: tuple[int, int] | None = None) -> int | None:
    """Amid one wavelength's run of consecutive shots (shot ``i - 1`` taken, ``i`` next) the LEM
    moved on: turn the run in place so that the shots not taken come first at its next turn.

    Returns the index just after the run (where to go on), or None when ``i`` starts a run (nothing
    to defer: wait for its colour). The schedule runner (`lrm.runner`) and the ship's estimate of a
    pass (`camcal.core.passplan`) share it. ``run``: the run's (start, end) when the caller knows it
    (`run_bounds`; a deferral never moves a run's ends), else it is looked for from ``i``.
    """
    if not 0 < i < len(shots) or shots[i - 1].wavelength_nm != shots[i].wavelength_nm:
        return None
    if run is None:
        wl, a, j = shots[i].wavelength_nm, i - 1, i
        while a > 0 and shots[a - 1].wavelength_nm == wl:
            a -= 1
        while j < len(shots) and shots[j].wavelength_nm == wl:
            j += 1
    else:
        a, j = run
    shots[a:j] = shots[i:j] + shots[a:i]
    return j


def run_bounds(shots: list[Shot]) -> list[tuple[int, int]]:
    """For each shot, the (start, end) of its wavelength's run of consecutive shots: what
    `defer_rest_of_run` would look for, found once for a walk over many deferrals (a run of 16,000
    shots looked for at each of hundreds of deferrals took seconds)."""
    out: list[tuple[int, int]] = []
    start = 0
    for k in range(1, len(shots) + 1):
        if k == len(shots) or shots[k].wavelength_nm != shots[start].wavelength_nm:
            out.extend([(start, k)] * (k - start))
            start = k
    return out


@dataclass(frozen=True)
class CameraLimits:
    """What a module's camera can take."""

    exposure_range_s: tuple[float, float] = (1e-4, 2.0)
    gain_range_db: tuple[float, float] = (0.0, 24.0)
    gain_step_db: float = 0.1

    def problems(self, schedule: Schedule) -> list[tuple[str, str]]:
        """(field, reason) for every exposure or gain the camera cannot take."""
        out = []
        elo, ehi = self.exposure_range_s
        glo, ghi = self.gain_range_db
        for i, (exposures, gains, _) in enumerate(schedule.grids()):
            where = "" if i == 0 else f"blocks.{i - 1}."
            for e in exposures:
                if not elo <= e <= ehi:
                    out.append(
                        (f"{where}exposures_s", f"exposure {e} s outside the camera's range [{elo}, {ehi}] s")
                    )
            for g in gains:
                if not glo <= g <= ghi:
                    out.append(
                        (f"{where}gains_db", f"gain {g} dB outside the camera's range [{glo}, {ghi}] dB")
                    )
                elif (
                    self.gain_step_db > 0 and abs(round(g / self.gain_step_db) * self.gain_step_db - g) > 1e-6
                ):
                    out.append(
                        (
                            f"{where}gains_db",
                            f"gain {g} dB is not a multiple of the {self.gain_step_db} dB step",
                        )
                    )
        return out


def trex_schedule() -> Schedule:
    """The full T-REX schedule: 7 exposures x 10 gains x 20 repeats x 3 wavelengths."""
    return Schedule(name="trex", exposures_s=TREX_EXPOSURES_S, gains_db=TREX_GAINS_DB, repeats=TREX_REPEATS)


def trex_subsampled(repeats: int = 2, gains_db: tuple[float, ...] = (2.0, 8.0, 14.0, 20.0)) -> Schedule:
    """The T-REX exposures at a few of its gains and repeats: a quick, representative set."""
    return Schedule(name="trex-subsampled", exposures_s=TREX_EXPOSURES_S, gains_db=gains_db, repeats=repeats)


def quick_check() -> Schedule:
    """A quick λ_att check: the three exposures that suit the three wavelengths, at one gain."""
    return Schedule(name="quick-check", exposures_s=(0.05, 0.07, 0.11), gains_db=(8.0,), repeats=5)


def linearity_scan() -> Schedule:
    """Exposures at a fixed gain, then gains at a fixed exposure (the in-situ self-calibration)."""
    return Schedule(
        name="linearity-scan",
        exposures_s=(0.01, 0.02, 0.03, 0.05, 0.07, 0.11, 0.15, 0.2, 0.3),
        gains_db=(6.0,),
        repeats=3,
        blocks=(
            Block(exposures_s=(0.05,), gains_db=(0.0, 2.0, 4.0, 8.0, 10.0, 12.0, 14.0, 16.0), repeats=3),
        ),
    )


def monitoring_loop() -> Schedule:
    """Long exposures (0.2-1.0 s) for bioluminescence and the deployment, one frame each."""
    return Schedule(name="monitoring", exposures_s=(0.2, 0.5, 1.0), gains_db=(8.0,), repeats=1, pause_s=5.0)


def presets() -> dict[str, Schedule]:
    """The named schedules an operator can start from."""
    return {
        "trex": trex_schedule(),
        "trex-subsampled": trex_subsampled(),
        "quick-check": quick_check(),
        "linearity-scan": linearity_scan(),
        "monitoring": monitoring_loop(),
    }
