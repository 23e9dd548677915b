"""Simulated lab frame sets for the calibrations of the camera system, with their truth.

One spec class per experiment of the paper's "Calibration" section; each
plans its frames (`shots`), renders one (`render`) and states what an
analysis should recover (`truth`). `write_lab_set` turns any of them into a
frame set (manifest.csv with the per-frame columns of docs/frameset.md,
setup.json, PNGs) and a truth.json beside it.

Measured quantities that the lab reads off a scale or a thermometer (the
distance, the temperature) are drawn around their true values with the
stated reading error, so the manifest holds readings and truth.json the
true values; the analysis must carry those errors to be right.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from camcal.frameset import MANIFEST, FrameSetWriter, ManifestRow, Setup, write_atomic
from lrm.sim.camera import CameraModel
from lrm.sim.lab import (
    PointSourceRenderer,
    TemperatureModel,
    air,
    departure_gray,
    tap_water,
)
from lrm.sim.render import FrameRenderer
from lrm.sim.scene import LEMModel, Placement, Water

TRUTH = "truth.json"
LAB_KINDS = ("linearity", "emission-ratio", "air-scan", "tank-scan", "psf")


@dataclass(frozen=True)
class LabShot:
    """One frame of a lab set: its manifest values and what the simulator needs to draw it.

    ``distance_m`` and ``temperature_c`` are the readings the manifest
    gets, ``true_distance_m`` and ``true_temperature_c`` what the simulator
    draws. ``offset_px`` moves an extended source from the optical axis;
    ``point_xy_px`` places a point source in the frame.
    """

    index: int
    wavelength_nm: int
    exposure_s: float
    gain_db: float
    distance_m: float
    distance_err_m: float
    true_distance_m: float
    medium: str = "air"
    hemisphere: str | None = None
    temperature_c: float | None = None
    true_temperature_c: float | None = None
    offset_px: tuple[float, float] = (0.0, 0.0)
    point_xy_px: tuple[float, float] | None = None


@dataclass(frozen=True)
class LabBase:
    """What every lab set shares: the camera, its id, the seed, repeats per setting, the gain."""

    kind: ClassVar[str] = ""
    camera: CameraModel = field(default_factory=CameraModel)
    camera_id: str = "A"
    seed: int = 0
    repeats: int = 2
    gain_db: float = 0.0
    start: datetime = datetime(2021, 6, 1, 9, 0, 0, tzinfo=UTC)

    def __post_init__(self) -> None:
        if self.repeats < 1:
            raise ValueError(f"repeats must be >= 1, got {self.repeats}")

    def shots(self) -> list[LabShot]:
        raise NotImplementedError

    def render(
        self, shot: LabShot, rng: np.random.Generator, cache: dict[Any, Any]
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """One frame and its truth; ``cache`` keeps renderers between the frames of a set."""
        raise NotImplementedError

    def truth(self, shots: list[LabShot]) -> dict[str, Any]:
        raise NotImplementedError

    def _plan_rng(self) -> np.random.Generator:
        return np.random.default_rng([self.seed, 0x1AB])

    def _lem_frame(
        self,
        shot: LabShot,
        rng: np.random.Generator,
        cache: dict[Any, Any],
        lem: LEMModel,
        medium: Water,
        faces_far_side: bool = False,
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """A glowing sphere at the shot's true distance in ``medium``, drawn by `FrameRenderer`.

        One renderer per distance, medium, side and source state, kept in ``cache``.
        """
        key = (shot.true_distance_m, medium.name, faces_far_side, shot.true_temperature_c)
        if key not in cache:
            placement = Placement(self.camera_id, shot.true_distance_m, shot.distance_err_m, faces_far_side)
            cache[key] = FrameRenderer(self.camera, placement, medium, lem, seed=self.seed)
        frame, truth = cache[key].render(
            shot.wavelength_nm, shot.exposure_s, shot.gain_db, rng=rng, offset_px=shot.offset_px
        )
        return frame, truth.to_dict()


def centre_rate_e_per_s(renderer: FrameRenderer, wavelength_nm: int) -> float:
    """Electrons per second in a pixel at the disk's centre: direct light, halo and dark current."""
    surface = renderer.surface_radiance_e_per_s(wavelength_nm)
    att = renderer.water.at(wavelength_nm).lambda_att_m
    direct = surface * math.exp(-renderer.placement.distance_m / att)
    halo = surface * float(renderer.halo_table(wavelength_nm)[0])
    return direct + halo + renderer.camera.dark_current_e_per_s


def _offset(rng: np.random.Generator, sigma_px: float) -> tuple[float, float]:
    """A pointing offset from the optical axis, (x, y) in pixels."""
    dx, dy = rng.normal(0.0, sigma_px, 2)
    return float(dx), float(dy)


def _exposure_for(target_gray: float, rate_e_per_s: float, camera: CameraModel, gain_db: float) -> float:
    """The exposure (rounded to 0.1 ms) that brings a pixel collecting ``rate_e_per_s`` to ``target_gray``."""
    gain_total = camera.gray_per_electron * camera.gain_factor(gain_db)
    exposure = (target_gray - camera.black_level_gray) / (rate_e_per_s * gain_total)
    lo, hi = camera.exposure_range_s
    if not lo <= exposure <= hi:
        raise ValueError(
            f"reaching {target_gray:g} gray needs a {exposure:g} s exposure, "
            f"outside the camera's [{lo}, {hi}] s"
        )
    return round(exposure, 4)


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
        out = []
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

    def shots(self) -> list[LabShot]:
        rng = self._plan_rng()
        out = []
        for t in self.temperatures_c:
            for wl in self.wavelengths_nm:
                # One setting per wavelength at every temperature, as the lab kept it.
                exposure = _exposure_for(
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

    def shots(self) -> list[LabShot]:
        rng = self._plan_rng()
        true = {d: float(d + rng.normal(0.0, self.distance_err_m)) for d in self.distances_m}
        offsets = {d: _offset(rng, self.pointing_err_px) for d in self.distances_m}
        out = []
        for wl in self.wavelengths_nm:
            rate = self.lem.radiance_e_per_s[wl]
            exposure = _exposure_for(self.target_gray, rate, self.camera, self.gain_db)
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
        out = []
        for medium in self.media:
            true = {d: float(d + rng.normal(0.0, self.distance_err_m)) for d in self.distances_m}
            for wl in self.wavelengths_nm:
                near = min(self.distances_m)
                rate = self.radiance_e_per_s * math.exp(-near / self.water.at(wl).lambda_att_m)
                exposure = _exposure_for(self.target_gray, rate, self.camera, self.gain_db)
                for d in self.distances_m:
                    offset = _offset(rng, self.pointing_err_px)
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
        out = []
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


LabSpec = LinearityLab | EmissionRatioLab | AirScanLab | TankScanLab | PSFLab
SPEC_CLASSES: dict[str, type[LabBase]] = {
    c.kind: c for c in (LinearityLab, EmissionRatioLab, AirScanLab, TankScanLab, PSFLab)
}


def lab_spec(kind: str, **values: Any) -> LabBase:
    """The spec of one lab experiment by its kind name, with ``values`` replacing defaults."""
    try:
        cls = SPEC_CLASSES[kind]
    except KeyError:
        raise ValueError(f"unknown lab kind {kind!r}; choose from {', '.join(LAB_KINDS)}") from None
    return cls(**values)


def _row(spec: LabBase, shot: LabShot) -> ManifestRow:
    when = spec.start + timedelta(seconds=shot.index)
    return ManifestRow(
        index=shot.index,
        file=f"{spec.camera_id}_{shot.index + 1:05d}.png",
        camera=spec.camera_id,
        wavelength_nm=shot.wavelength_nm,
        exposure_s=shot.exposure_s,
        gain_db=shot.gain_db,
        timestamp=when.isoformat().replace("+00:00", "Z"),
        seq=shot.index + 1,
        distance_m=shot.distance_m,
        distance_err_m=shot.distance_err_m,
        temperature_c=shot.temperature_c,
        medium=shot.medium,
        hemisphere=shot.hemisphere,
    )


def write_lab_set(
    out: Path, spec: LabBase, *, progress: Callable[[int, int], None] | None = None
) -> dict[str, Any]:
    """Render ``spec`` into the frame set ``out`` and write its truth.json; return the truth.

    Each frame's noise comes from ``(seed, frame index)``, so a set is the
    same on every run. ``out`` must not hold a frame set already.
    """
    out = Path(out)
    if (out / MANIFEST).exists():
        raise FileExistsError(f"{out} already holds a frame set; choose an empty folder")
    shots = spec.shots()
    frames: list[dict[str, Any]] = []
    cache: dict[Any, Any] = {}
    with FrameSetWriter(out, Setup()) as writer:
        for shot in shots:
            frame, truth = spec.render(shot, np.random.default_rng([spec.seed, shot.index]), cache)
            row = writer.add(frame, _row(spec, shot))
            frames.append({"file": row.file, **asdict(shot), **truth})
            if progress:
                progress(len(frames), len(shots))
    doc = {
        "kind": spec.kind,
        "seed": spec.seed,
        "camera_model": {**asdict(spec.camera), "focal_px": spec.camera.focal_px},
        "truth": spec.truth(shots),
        "frames": frames,
    }
    write_atomic(out / TRUTH, (json.dumps(doc, indent=1, default=str) + "\n").encode(), fsync=False)
    return doc


def truth_values(doc: dict[str, Any]) -> list[dict[str, Any]]:
    """The true values of a lab set, in the form of a calibration result's ``values``.

    Each entry has ``quantity`` and ``value`` plus the context keys the
    matching result value carries (``wavelength_nm``, ``sweep``,
    ``medium``), so a result can be checked entry by entry (`match_truth`).
    Only quantities the simulator knows exactly are listed.
    """
    kind, t = doc["kind"], doc["truth"]
    out: list[dict[str, Any]] = []

    def add(quantity: str, val: float, **context: Any) -> None:
        out.append({"quantity": quantity, "value": float(val), **context})

    if kind == "linearity":
        wl = t["wavelength_nm"]
        e, g = t["exposure_sweep"], t["gain_sweep"]
        add("slope", e["slope_gray_per_s"], wavelength_nm=wl, sweep="exposure")
        add("dark_level_gray", e["intercept_gray"], wavelength_nm=wl, sweep="exposure")
        add("departure_gray", e["departure_gray"], wavelength_nm=wl, sweep="exposure")
        add("slope", g["slope_gray_per_gain"], wavelength_nm=wl, sweep="gain")
        add("dark_level_gray", g["intercept_gray"], wavelength_nm=wl, sweep="gain")
        add("departure_gray", g["departure_gray"], wavelength_nm=wl, sweep="gain")
    elif kind == "emission-ratio":
        for wl, r in t["emission_ratio"].items():
            runs = sorted(r["runs"], key=lambda x: x["temperature_c"])
            add("emission_ratio", r["at_reference"], wavelength_nm=int(wl))
            if len(runs) >= 2:
                slope = (runs[-1]["ratio"] - runs[0]["ratio"]) / (
                    runs[-1]["temperature_c"] - runs[0]["temperature_c"]
                )
                add("ratio_per_c", slope, wavelength_nm=int(wl))
                add("ratio_change", r["ratio_change"], wavelength_nm=int(wl))
                add("brightness_change", r["brightness_change"], wavelength_nm=int(wl))
    elif kind == "air-scan":
        for wl, w in t["wavelengths"].items():
            add("centre_mu_per_m", w["mu_per_m"], wavelength_nm=int(wl))
            add("total_exponent", t["exponent"], wavelength_nm=int(wl))
            add("focal_px", t["focal_px"], wavelength_nm=int(wl))
    elif kind == "tank-scan":
        for wl, w in t["wavelengths"].items():
            add("mu_per_m", w["mu_water_per_m"], wavelength_nm=int(wl), medium="water")
            add("lambda_att_m", w["lambda_att_m"], wavelength_nm=int(wl), medium="water")
            add("mu_per_m", w["mu_air_per_m"], wavelength_nm=int(wl), medium="air")
            relative = 1.0 / (w["mu_water_per_m"] - w["mu_air_per_m"])
            add("lambda_att_m", relative, wavelength_nm=int(wl), medium="water relative to air")
    elif kind == "psf":
        wl, sigma = t["wavelength_nm"], t["psf_sigma_px"]
        for q in ("psf_sigma_px", "psf_sigma_x_px", "psf_sigma_y_px"):
            add(q, sigma, wavelength_nm=wl)
        add("psf_fwhm_px", 2.0 * math.sqrt(2.0 * math.log(2.0)) * sigma, wavelength_nm=wl)
    else:
        raise ValueError(f"unknown lab kind {kind!r} in the truth document")
    return out


_MATCH_KEYS = ("quantity", "wavelength_nm", "sweep", "medium")


def match_truth(
    values: list[dict[str, Any]], truth: list[dict[str, Any]]
) -> list[tuple[dict[str, Any], dict[str, Any]]]:
    """Pairs (result value, true value) that agree on quantity, wavelength, sweep and medium.

    Raises `ValueError` naming a true value with no measured counterpart,
    so a result that silently drops a quantity does not pass a check.
    """
    pairs = []
    for tv in truth:
        key = tuple(tv.get(k) for k in _MATCH_KEYS)
        found = [v for v in values if tuple(v.get(k) for k in _MATCH_KEYS) == key]
        if len(found) != 1:
            raise ValueError(
                f"{len(found)} result values match the true {dict(zip(_MATCH_KEYS, key, strict=True))}"
            )
        pairs.append((found[0], tv))
    return pairs
