"""Darkroom and cold-room experiments: linearity sweeps, the emission ratio, the point source."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from lrm.labset.base import LabBase, LabShot, centre_rate_e_per_s, check_leds, exposure_for
from lrm.sim.lab import PointSourceRenderer, TemperatureModel, air, departure_gray
from lrm.sim.render import FrameRenderer
from lrm.sim.scene import LEMModel, Placement

# ------------------------------------------------------------------ linearity
#: Exposures of the darkroom sweep, 1 ms to 350 ms, densest where the default source reaches the knee.
LINEARITY_EXPOSURES_MS: tuple[int, ...] = (1, 2, 5, 10, 20, 35, 50, 75, 100, 125, 150)
LINEARITY_EXPOSURES_MS += (170, 185, 195, 205, 215, 230, 250, 300, 350)
LINEARITY_EXPOSURES_S: tuple[float, ...] = tuple(ms / 1000.0 for ms in LINEARITY_EXPOSURES_MS)


@dataclass(frozen=True)
class LinearityLab(LabBase):
    """A steady source in a darkroom: an exposure sweep at one gain and a gain sweep at one exposure.

    The source is a disk of ``radiance_e_per_s`` at ``distance_m`` in air,
    on the optical axis; the defaults put the knee (240 gray) near 200 ms.
    """

    kind: ClassVar[str] = "linearity"
    gain_db: float = 6.0
    wavelength_nm: int = 460
    distance_m: float = 5.0
    radiance_e_per_s: float = 15000.0
    exposures_s: tuple[float, ...] = LINEARITY_EXPOSURES_S
    gains_db: tuple[float, ...] = tuple(float(g) for g in range(0, 25))
    gain_sweep_exposure_s: float = 0.04
    tolerance: float = 0.01

    def _lem(self) -> LEMModel:
        return LEMModel(radiance_e_per_s={self.wavelength_nm: self.radiance_e_per_s})

    def shots(self) -> list[LabShot]:
        settings = [(e, self.gain_db) for e in self.exposures_s]
        settings += [(self.gain_sweep_exposure_s, g) for g in self.gains_db if g != self.gain_db]
        out: list[LabShot] = []
        for exposure, gain in settings:
            for _ in range(self.repeats):
                out.append(
                    LabShot(
                        index=len(out),
                        wavelength_nm=self.wavelength_nm,
                        exposure_s=exposure,
                        gain_db=gain,
                        distance_m=self.distance_m,
                        distance_err_m=0.0,
                        true_distance_m=self.distance_m,
                    )
                )
        return out

    def render(
        self, shot: LabShot, rng: np.random.Generator, cache: dict[Any, Any]
    ) -> tuple[np.ndarray, dict[str, Any]]:
        return self._lem_frame(shot, rng, cache, self._lem(), air((self.wavelength_nm,)))

    def truth(self, shots: list[LabShot]) -> dict[str, Any]:
        cam = self.camera
        renderer = FrameRenderer(
            cam, Placement(self.camera_id, self.distance_m), air((self.wavelength_nm,)), self._lem()
        )
        rate = centre_rate_e_per_s(renderer, self.wavelength_nm)
        t = np.linspace(1e-4, max(self.exposures_s), 20000)
        g = np.linspace(min(self.gains_db), max(self.gains_db), 20000)
        return {
            "wavelength_nm": self.wavelength_nm,
            "tolerance": self.tolerance,
            "knee_gray": cam.knee_gray,
            "exposure_sweep": {
                "fixed_gain_db": self.gain_db,
                "slope_gray_per_s": rate * cam.gray_per_electron * cam.gain_factor(self.gain_db),
                "intercept_gray": cam.black_level_gray,
                "departure_gray": departure_gray(cam, rate * t, self.gain_db, self.tolerance),
            },
            "gain_sweep": {
                "fixed_exposure_s": self.gain_sweep_exposure_s,
                "slope_gray_per_gain": rate * self.gain_sweep_exposure_s * cam.gray_per_electron,
                "intercept_gray": cam.black_level_gray,
                "departure_gray": departure_gray(cam, rate * self.gain_sweep_exposure_s, g, self.tolerance),
            },
        }


# ------------------------------------------------------------- emission ratio
@dataclass(frozen=True)
class EmissionRatioLab(LabBase):
    """Both hemispheres of the LEM at ``distance_m`` in air, in a cold room and a warm one.

    Exposures are chosen per wavelength to put the near hemisphere's centre
    at ``target_gray``; the far one is brighter by I0'/I0. The thermometer
    reads each frame's temperature with ``temperature_reading_err_c``.
    """

    kind: ClassVar[str] = "emission-ratio"
    wavelengths_nm: tuple[int, ...] = (405, 460, 525)
    distance_m: float = 5.0
    temperatures_c: tuple[float, ...] = (2.1, 18.9)
    temperature_reading_err_c: float = 0.3
    temperature_model: TemperatureModel = field(default_factory=TemperatureModel)
    lem: LEMModel = field(default_factory=LEMModel)
    target_gray: float = 150.0

    def __post_init__(self) -> None:
        super().__post_init__()
        check_leds(self.lem, self.wavelengths_nm)

    def shots(self) -> list[LabShot]:
        rng = self._plan_rng()
        out: list[LabShot] = []
        for t in self.temperatures_c:
            for wl in self.wavelengths_nm:
                # One setting per wavelength at every temperature, as the lab kept it.
                exposure = exposure_for(
                    self.target_gray, self.lem.radiance_e_per_s[wl], self.camera, self.gain_db
                )
                for side in ("near", "far"):
                    for _ in range(self.repeats):
                        reading = round(float(t + rng.normal(0.0, self.temperature_reading_err_c)), 2)
                        out.append(
                            LabShot(
                                index=len(out),
                                wavelength_nm=wl,
                                exposure_s=exposure,
                                gain_db=self.gain_db,
                                distance_m=self.distance_m,
                                distance_err_m=0.0,
                                true_distance_m=self.distance_m,
                                hemisphere=side,
                                temperature_c=reading,
                                true_temperature_c=t,
                            )
                        )
        return out

    def render(
        self, shot: LabShot, rng: np.random.Generator, cache: dict[Any, Any]
    ) -> tuple[np.ndarray, dict[str, Any]]:
        lem = self.temperature_model.lem_at(self.lem, float(shot.true_temperature_c))  # type: ignore[arg-type]
        return self._lem_frame(shot, rng, cache, lem, air(self.wavelengths_nm), shot.hemisphere == "far")

    def truth(self, shots: list[LabShot]) -> dict[str, Any]:
        tm = self.temperature_model
        cold, warm = min(self.temperatures_c), max(self.temperatures_c)
        out: dict[str, Any] = {"temperatures_c": list(self.temperatures_c), "emission_ratio": {}}
        for wl in self.wavelengths_nm:
            out["emission_ratio"][str(wl)] = {
                "reference_c": tm.reference_c,
                "at_reference": self.lem.emission_ratio[wl],
                "runs": [
                    {"temperature_c": t, "ratio": self.lem.emission_ratio[wl] * tm.ratio_factor(wl, t)}
                    for t in self.temperatures_c
                ],
                "ratio_change": tm.ratio_factor(wl, warm) / tm.ratio_factor(wl, cold) - 1.0,
                "brightness_change": tm.brightness_factor(wl, warm) / tm.brightness_factor(wl, cold) - 1.0,
            }
        return out


# ----------------------------------------------------------------------- psf
@dataclass(frozen=True)
class PSFLab(LabBase):
    """A point-like source (an LED behind a pinhole) moved across the field of view.

    ``n_positions`` places on a grid over the central ``field_fraction`` of
    the frame, each with a random sub-pixel offset; ``repeats`` frames at
    each. The flux puts the brightest pixel near ``target_peak_gray``. The
    PSF is the camera's ``psf_sigma_px``.
    """

    kind: ClassVar[str] = "psf"
    # 12 dB: read noise of ~0.5 gray dithers the 8-bit steps in the PSF's
    # faint wings; at 0 dB (0.12 gray) rounding widens the fitted PSF by ~0.3 %.
    gain_db: float = 12.0
    wavelength_nm: int = 460
    distance_m: float = 10.0
    n_positions: int = 9
    field_fraction: float = 0.6
    exposure_s: float = 0.05
    target_peak_gray: float = 150.0

    def _flux_e_per_s(self) -> float:
        cam = self.camera
        peak_fraction = math.erf(0.5 / (math.sqrt(2.0) * cam.psf_sigma_px)) ** 2
        gain_total = cam.gray_per_electron * cam.gain_factor(self.gain_db)
        return (self.target_peak_gray - cam.black_level_gray) / (peak_fraction * gain_total * self.exposure_s)

    def shots(self) -> list[LabShot]:
        if self.n_positions < 1:
            raise ValueError(f"n_positions must be >= 1, got {self.n_positions}")
        rng = self._plan_rng()
        cam = self.camera
        side = math.ceil(math.sqrt(self.n_positions))
        fx = np.linspace(-0.5, 0.5, side) * self.field_fraction * cam.width_px if side > 1 else np.zeros(1)
        fy = np.linspace(-0.5, 0.5, side) * self.field_fraction * cam.height_px if side > 1 else np.zeros(1)
        grid = [(x, y) for y in fy for x in fx][: self.n_positions]
        out: list[LabShot] = []
        cx, cy = cam.center_xy
        for gx, gy in grid:
            for _ in range(self.repeats):
                pos = (float(cx + gx + rng.uniform(-0.5, 0.5)), float(cy + gy + rng.uniform(-0.5, 0.5)))
                out.append(
                    LabShot(
                        index=len(out),
                        wavelength_nm=self.wavelength_nm,
                        exposure_s=self.exposure_s,
                        gain_db=self.gain_db,
                        distance_m=self.distance_m,
                        distance_err_m=0.0,
                        true_distance_m=self.distance_m,
                        point_xy_px=pos,
                    )
                )
        return out

    def render(
        self, shot: LabShot, rng: np.random.Generator, cache: dict[Any, Any]
    ) -> tuple[np.ndarray, dict[str, Any]]:
        if "point" not in cache:
            cache["point"] = PointSourceRenderer(self.camera, seed=self.seed)
        x, y = shot.point_xy_px or self.camera.center_xy
        frame, truth = cache["point"].render(
            x, y, self._flux_e_per_s(), shot.exposure_s, shot.gain_db, rng=rng
        )
        return frame, truth.to_dict()

    def truth(self, shots: list[LabShot]) -> dict[str, Any]:
        return {"psf_sigma_px": self.camera.psf_sigma_px, "wavelength_nm": self.wavelength_nm}
