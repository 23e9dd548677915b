"""Distance scans: the LEM in a dark hall (air), a small ball along a water tank."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from lrm.labset.base import LabBase, LabShot, check_leds, exposure_for, pointing_offset
from lrm.sim.lab import air, tap_water
from lrm.sim.scene import LEMModel, Water


# ------------------------------------------------------------------ air scan
@dataclass(frozen=True)
class AirScanLab(LabBase):
    """The LEM at distances from 5.2 m to 41.2 m in a dark hall (the long-distance test in air).

    One exposure per wavelength (chosen for ``target_gray`` at the centre)
    for every distance; the LEM sits within ``pointing_err_px`` of the
    optical axis, a little differently at each distance.
    """

    kind: ClassVar[str] = "air-scan"
    wavelengths_nm: tuple[int, ...] = (405, 460, 525)
    distances_m: tuple[float, ...] = (5.2, 10.0, 15.0, 20.0, 25.0, 30.0, 35.0, 41.2)
    distance_err_m: float = 0.1
    pointing_err_px: float = 5.0
    lem: LEMModel = field(default_factory=LEMModel)
    target_gray: float = 150.0

    def __post_init__(self) -> None:
        super().__post_init__()
        check_leds(self.lem, self.wavelengths_nm)

    def shots(self) -> list[LabShot]:
        rng = self._plan_rng()
        true = {d: float(d + rng.normal(0.0, self.distance_err_m)) for d in self.distances_m}
        offsets = {d: pointing_offset(rng, self.pointing_err_px) for d in self.distances_m}
        out: list[LabShot] = []
        for wl in self.wavelengths_nm:
            rate = self.lem.radiance_e_per_s[wl]
            exposure = exposure_for(self.target_gray, rate, self.camera, self.gain_db)
            for d in self.distances_m:
                for _ in range(self.repeats):
                    out.append(
                        LabShot(
                            index=len(out),
                            wavelength_nm=wl,
                            exposure_s=exposure,
                            gain_db=self.gain_db,
                            distance_m=d,
                            distance_err_m=self.distance_err_m,
                            true_distance_m=true[d],
                            offset_px=offsets[d],
                        )
                    )
        return out

    def render(
        self, shot: LabShot, rng: np.random.Generator, cache: dict[Any, Any]
    ) -> tuple[np.ndarray, dict[str, Any]]:
        return self._lem_frame(shot, rng, cache, self.lem, air(self.wavelengths_nm))

    def truth(self, shots: list[LabShot]) -> dict[str, Any]:
        medium = air(self.wavelengths_nm)
        gpe = self.camera.gray_per_electron
        return {
            "exponent": 2.0,
            "focal_px": self.camera.focal_px,
            "source_radius_m": self.lem.radius_m,
            "true_distances_m": {str(s.distance_m): s.true_distance_m for s in shots},
            "wavelengths": {
                str(wl): {
                    "mu_per_m": 1.0 / medium.at(wl).lambda_att_m,
                    "i_center_gray_per_s": self.lem.radiance_e_per_s[wl] * gpe,
                }
                for wl in self.wavelengths_nm
            },
        }


# ----------------------------------------------------------------- tank scan
@dataclass(frozen=True)
class TankScanLab(LabBase):
    """A 2.5 cm glowing Teflon ball moved along a tank, first in air, then in tap water.

    Distances are read off the rail's scale (1 cm). One exposure per
    wavelength serves both media, chosen for ``target_gray`` at the nearest
    distance in water.
    """

    kind: ClassVar[str] = "tank-scan"
    wavelengths_nm: tuple[int, ...] = (460,)
    distances_m: tuple[float, ...] = (1.0, 1.25, 1.5, 1.75, 2.0, 2.25, 2.5, 2.75, 3.0)
    distance_err_m: float = 0.01
    media: tuple[str, ...] = ("air", "water")
    source_diameter_m: float = 0.025
    radiance_e_per_s: float = 50000.0
    water: Water = field(default_factory=tap_water)
    pointing_err_px: float = 3.0
    target_gray: float = 180.0

    def __post_init__(self) -> None:
        super().__post_init__()
        for wl in self.wavelengths_nm:
            self.water.at(wl)  # raises naming the wavelength the water lacks
        for medium in self.media:
            self._medium(medium)

    def _source(self) -> LEMModel:
        return LEMModel(
            diameter_m=self.source_diameter_m,
            radiance_e_per_s=dict.fromkeys(self.wavelengths_nm, self.radiance_e_per_s),
            emission_ratio=dict.fromkeys(self.wavelengths_nm, 1.0),
        )

    def _medium(self, name: str) -> Water:
        if name not in ("air", "water"):
            raise ValueError(f"media must be air or water, got {name!r}")
        return air(self.wavelengths_nm) if name == "air" else self.water

    def shots(self) -> list[LabShot]:
        rng = self._plan_rng()
        out: list[LabShot] = []
        for medium in self.media:
            true = {d: float(d + rng.normal(0.0, self.distance_err_m)) for d in self.distances_m}
            for wl in self.wavelengths_nm:
                near = min(self.distances_m)
                rate = self.radiance_e_per_s * math.exp(-near / self.water.at(wl).lambda_att_m)
                exposure = exposure_for(self.target_gray, rate, self.camera, self.gain_db)
                for d in self.distances_m:
                    offset = pointing_offset(rng, self.pointing_err_px)
                    for _ in range(self.repeats):
                        out.append(
                            LabShot(
                                index=len(out),
                                wavelength_nm=wl,
                                exposure_s=exposure,
                                gain_db=self.gain_db,
                                distance_m=d,
                                distance_err_m=self.distance_err_m,
                                true_distance_m=true[d],
                                medium=medium,
                                offset_px=offset,
                            )
                        )
        return out

    def render(
        self, shot: LabShot, rng: np.random.Generator, cache: dict[Any, Any]
    ) -> tuple[np.ndarray, dict[str, Any]]:
        return self._lem_frame(shot, rng, cache, self._source(), self._medium(shot.medium))

    def truth(self, shots: list[LabShot]) -> dict[str, Any]:
        medium_air = air(self.wavelengths_nm)
        return {
            "source_radius_m": self.source_diameter_m / 2.0,
            "water_name": self.water.name,
            "wavelengths": {
                str(wl): {
                    "lambda_att_m": self.water.at(wl).lambda_att_m,
                    "mu_water_per_m": 1.0 / self.water.at(wl).lambda_att_m,
                    "mu_air_per_m": 1.0 / medium_air.at(wl).lambda_att_m,
                }
                for wl in self.wavelengths_nm
            },
        }
