"""What every simulated lab experiment shares: the shot, the spec base class, small helpers."""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any, ClassVar

import numpy as np

from lrm.sim.camera import CameraModel
from lrm.sim.render import FrameRenderer
from lrm.sim.scene import LEMModel, Placement, Water


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
    direct = renderer.direct_center_e_per_s(wavelength_nm)
    halo = surface * float(renderer.halo_table(wavelength_nm)[0])
    return direct + halo + renderer.camera.dark_current_e_per_s


def check_leds(lem: LEMModel, wavelengths_nm: tuple[int, ...]) -> None:
    """Raise `ValueError` naming a wavelength the LEM cannot shine at."""
    for wl in wavelengths_nm:
        if wl not in lem.radiance_e_per_s or wl not in lem.emission_ratio:
            have = ", ".join(str(w) for w in sorted(lem.radiance_e_per_s))
            raise ValueError(f"the LEM has no {wl} nm LED (it has {have})")


def pointing_offset(rng: np.random.Generator, sigma_px: float) -> tuple[float, float]:
    """A pointing offset from the optical axis, (x, y) in pixels."""
    dx, dy = rng.normal(0.0, sigma_px, 2)
    return float(dx), float(dy)


def exposure_for(target_gray: float, rate_e_per_s: float, camera: CameraModel, gain_db: float) -> float:
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
