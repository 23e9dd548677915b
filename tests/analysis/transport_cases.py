"""Waters, camera and geometry of the transport and χ² tests, and how their frames are simulated.

The simulated frames take their halo from the same template grid the fit
uses (``TransportHalo(grid=...)``), so simulation and fit share the physics
and the Monte Carlo sample: the fit tests check the fit, the transport tests
check the transport.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from analysis import FrameRecord, Setting, analyze_frame, stack_by_setting
from analysis.attenuation import EmissionRatio, Geometry
from analysis.chisq import SettingProfiles, collect_settings
from analysis.scattering import WaterOptics
from analysis.transport.templates import TemplateGrid, TemplateSettings
from lrm.sim import CameraModel, FrameRenderer
from lrm.sim.render import TransportHalo
from lrm.sim.scene import TREX_PLACEMENTS, Water

#: The T-REX focal length (pixels) on a small 800 x 700 sensor: a narrow field of view,
#: the same LEM images and profiles as the full camera, a tenth of the pixels.
FOCAL_PX = 1224.0 / math.tan(math.radians(8.0))
WAVELENGTH_NM = 460
EMISSION_RATIO = EmissionRatio(1.27, 0.04)
GEOMETRY = Geometry("A", "B", 21.56, 0.02, 41.62, 0.04)


def small_camera() -> CameraModel:
    return CameraModel(width_px=800, height_px=700, fov_deg=2.0 * math.degrees(math.atan(400.0 / FOCAL_PX)))


@dataclass(frozen=True)
class WaterCase:
    """A water to simulate, the template nodes around it and the settings to shoot."""

    name: str
    optics: WaterOptics
    nodes_m: tuple[float, ...]
    settings: tuple[tuple[float, float], ...]


CASES = {
    "clear": WaterCase(
        "clear", WaterOptics(100.0, 140.0), (110.0, 180.0), ((0.01, 14.0), (0.01, 18.0), (0.02, 14.0))
    ),
    "turbid": WaterCase(
        "turbid", WaterOptics(25.0, 25.0), (20.0, 33.0), ((0.02, 14.0), (0.02, 18.0), (0.05, 14.0))
    ),
}


def grid_settings(case: WaterCase) -> TemplateSettings:
    """Templates for the fit with outer bins to the small frame's corner (so the simulator can share them)."""
    return TemplateSettings.near_far(
        GEOMETRY.distance_near_m,
        GEOMETRY.distance_far_m,
        FOCAL_PX,
        n_bands=144,
        outer_px=1130.0,
        n_outer=16,
        lambda_sca_nodes_m=case.nodes_m,
        n_photons=150_000,
        seed=11,
    )


def simulate_profiles(
    case: WaterCase, grid: TemplateGrid, repeats: int = 5, seed: int = 1
) -> list[SettingProfiles]:
    """Render, analyse and stack frames of both cameras; the halo from ``grid``."""
    water = Water({WAVELENGTH_NM: case.optics}, name=case.name)
    cam = small_camera()
    renderers = {
        p.camera: FrameRenderer(
            cam, p, water, seed=seed, halo_model="transport", transport=TransportHalo(grid=grid)
        )
        for p in TREX_PLACEMENTS
    }
    rng = np.random.default_rng(seed)
    records = []
    for exposure, gain in case.settings:
        for _ in range(repeats):
            for name, r in renderers.items():
                offset = (rng.normal(0, 1.5), rng.normal(0, 1.5))
                frame, _ = r.render(WAVELENGTH_NM, exposure, gain, rng=rng, offset_px=offset)
                records.append(
                    FrameRecord(name, Setting(WAVELENGTH_NM, exposure, gain), analyze_frame(frame))
                )
    return collect_settings(stack_by_setting(records), WAVELENGTH_NM, "A", "B")
