"""Exposure schedules: exposures x gains x repeats x wavelengths.

One compact description, shared by the module (which runs it), the ship
(which validates and sends it) and the simulator. A schedule is never sent
as an expanded list of frames.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

#: The T-REX schedule (paper, section 2).
TREX_EXPOSURES_S: tuple[float, ...] = (0.02, 0.05, 0.07, 0.11, 0.2, 0.5, 1.0)
TREX_GAINS_DB: tuple[float, ...] = tuple(float(g) for g in range(2, 21, 2))
TREX_REPEATS = 20
KNOWN_WAVELENGTHS_NM: tuple[int, ...] = (405, 460, 525)


@dataclass(frozen=True, order=True)
class Shot:
    """One capture of a schedule: a setting and the repeat index within it."""

    wavelength_nm: int
    exposure_s: float
    gain_db: float
    repeat: int


class Schedule(BaseModel):
    """A named, versioned exposure schedule.

    ``order`` says which loop is outermost: ``"wavelength"`` (all settings of
    405 nm, then 460, then 525: the LEM changes colour least often) or
    ``"setting"`` (each exposure x gain at every wavelength in turn).
    ``pause_s`` is idle time after each completed pass.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    name: str = Field("custom", min_length=1, max_length=80)
    version: int = Field(1, ge=1)
    exposures_s: tuple[float, ...] = Field(min_length=1, max_length=64)
    gains_db: tuple[float, ...] = Field(min_length=1, max_length=64)
    repeats: int = Field(1, ge=1, le=1000)
    wavelengths_nm: tuple[int, ...] = Field(KNOWN_WAVELENGTHS_NM, min_length=1, max_length=8)
    order: str = Field("wavelength", pattern="^(wavelength|setting)$")
    pause_s: float = Field(0.0, ge=0, le=86400)

    @field_validator("exposures_s")
    @classmethod
    def _positive_exposures(cls, v: tuple[float, ...]) -> tuple[float, ...]:
        for x in v:
            if not x > 0:
                raise ValueError(f"exposure {x} s must be > 0")
        return v

    @field_validator("wavelengths_nm")
    @classmethod
    def _known_wavelengths(cls, v: tuple[int, ...]) -> tuple[int, ...]:
        for wl in v:
            if wl not in KNOWN_WAVELENGTHS_NM:
                known = ", ".join(str(k) for k in KNOWN_WAVELENGTHS_NM)
                raise ValueError(f"wavelength {wl} nm is not one of the LEM's ({known})")
        return v

    @model_validator(mode="after")
    def _no_duplicates(self) -> Schedule:
        for name in ("exposures_s", "gains_db", "wavelengths_nm"):
            values = getattr(self, name)
            if len(set(values)) != len(values):
                raise ValueError(f"{name} has repeated values")
        return self

    @property
    def n_frames(self) -> int:
        """Frames in one pass."""
        return len(self.exposures_s) * len(self.gains_db) * self.repeats * len(self.wavelengths_nm)

    def shots(self) -> Iterator[Shot]:
        """Every capture of one pass, in the schedule's order."""
        if self.order == "wavelength":
            for wl in self.wavelengths_nm:
                for exp in self.exposures_s:
                    for gain in self.gains_db:
                        for k in range(self.repeats):
                            yield Shot(wl, exp, gain, k)
        else:
            for exp in self.exposures_s:
                for gain in self.gains_db:
                    for wl in self.wavelengths_nm:
                        for k in range(self.repeats):
                            yield Shot(wl, exp, gain, k)


def trex_schedule() -> Schedule:
    """The full T-REX schedule: 7 exposures x 10 gains x 20 repeats x 3 wavelengths."""
    return Schedule(name="trex", exposures_s=TREX_EXPOSURES_S, gains_db=TREX_GAINS_DB, repeats=TREX_REPEATS)


def trex_subsampled(repeats: int = 2, gains_db: tuple[float, ...] = (2.0, 8.0, 14.0, 20.0)) -> Schedule:
    """The T-REX exposures at a few of its gains and repeats: a quick, representative set."""
    return Schedule(name="trex-subsampled", exposures_s=TREX_EXPOSURES_S, gains_db=gains_db, repeats=repeats)


def quick_check() -> Schedule:
    """A quick λ_att check: the three settings that suit each wavelength, a few repeats."""
    return Schedule(name="quick-check", exposures_s=(0.05, 0.07, 0.11), gains_db=(8.0,), repeats=5)


def presets() -> dict[str, Schedule]:
    """The named schedules an operator can start from."""
    return {"trex": trex_schedule(), "trex-subsampled": trex_subsampled(), "quick-check": quick_check()}
