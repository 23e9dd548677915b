"""Factories for tests: simulated frames and frame sets with known truth."""

from __future__ import annotations

import math
from collections.abc import Iterable
from functools import lru_cache
from pathlib import Path

import numpy as np

from analysis import FrameConfig, FrameRecord, Setting, analyze_frame
from camcal.core.frameset import TREX_FOCAL_PX
from lrm.sim import CameraModel, FrameRenderer, Placement
from lrm.sim.scene import TREX_PLACEMENTS, Water, water_preset
from lrm.simset import SimulationSpec, simulate_frame_set

#: A small sensor with the T-REX plate scale (focal length ~8700 px): the LEM
#: disk has its T-REX size in pixels while a frame costs 1/15 of a 5 MP one.
SMALL_CAMERA = CameraModel(
    width_px=640, height_px=512, fov_deg=2 * math.degrees(math.atan(320 / TREX_FOCAL_PX))
)
FULL_CAMERA = CameraModel()


@lru_cache(maxsize=32)
def renderer(
    water_name: str = "trex",
    distance_m: float = 21.56,
    far_side: bool = False,
    camera: CameraModel = FULL_CAMERA,
    camera_id: str = "A",
    seed: int = 0,
    double_image: bool = False,
) -> FrameRenderer:
    """A cached renderer (the halo integral and noise bank are built once per test session)."""
    placement = Placement(camera_id, distance_m, 0.02, faces_far_side=far_side)
    return FrameRenderer(camera, placement, water_preset(water_name), seed=seed, double_image=double_image)


def in_range_settings(
    near: FrameRenderer,
    far: FrameRenderer,
    wavelength_nm: int,
    exposures_s: Iterable[float] = (0.02, 0.05, 0.07, 0.11, 0.2, 0.5, 1.0),
    gains_db: Iterable[float] = tuple(range(0, 22, 2)),
    near_max_gray: float = 215.0,
    far_min_gray: float = 25.0,
) -> list[tuple[float, float]]:
    """Settings at which both cameras see the LEM centre well inside the linear range."""
    out = []
    for e in exposures_s:
        for g in gains_db:
            n = near.expected_center_gray(wavelength_nm, e, g)
            f = far.expected_center_gray(wavelength_nm, e, g)
            if n <= near_max_gray and f >= far_min_gray:
                out.append((float(e), float(g)))
    return out


def records_for(
    near: FrameRenderer,
    far: FrameRenderer,
    settings: Iterable[tuple[int, float, float]],
    repeats: int,
    seed: int,
    config: FrameConfig | None = None,
) -> list[FrameRecord]:
    """Render and analyse ``repeats`` frames per camera and setting, in memory."""
    records = []
    k = 0
    for wl, e, g in settings:
        for _ in range(repeats):
            for r in (near, far):
                k += 1
                rng = np.random.default_rng([seed, k])
                off = tuple(rng.normal(0, 2.0, 2))
                frame, _ = r.render(wl, e, g, rng=rng, offset_px=off)
                records.append(
                    FrameRecord(r.placement.camera, Setting(wl, e, g), analyze_frame(frame, config))
                )
    return records


def small_frame_set(
    out: Path,
    *,
    water: Water | None = None,
    seed: int = 3,
    repeats: int = 2,
    exposures: tuple[float, ...] = (0.02, 0.05, 0.11),
    gains: tuple[float, ...] = (2.0, 8.0),
) -> dict[str, object]:
    """A quick frame set on the small sensor: T-REX geometry, a few settings."""
    from camcal.core.schedule import Schedule

    spec = SimulationSpec(
        water=water or water_preset("trex"),
        placements=TREX_PLACEMENTS,
        camera=SMALL_CAMERA,
        schedule=Schedule(name="test", exposures_s=exposures, gains_db=gains, repeats=repeats),
        seed=seed,
        jitter_px=1.0,
    )
    return simulate_frame_set(out, spec, workers=1)
