"""The T-REX scene for Mitsuba 3: an independent renderer to check `analysis.transport` against.

Mitsuba is an optional extra (``pip install camcal[validate]``); nothing of
camcal needs it, and this module imports it only inside its functions.
Only the ``scalar_rgb`` variant is used (the LLVM variants crash on some
machines; scalar needs nothing but the wheel).

The scene: a homogeneous medium (σ_t = 1/λ_abs + 1/λ_sca, albedo
(1/λ_sca)/σ_t) whose phase function is Henyey-Greenstein ⟨cos θ⟩ and
Rayleigh mixed by `blendphase` (the Rayleigh share as its weight); the LEM
a black sphere of radius a with a uniform Lambertian area emitter of
radiance 1 (the units of the transport's templates); a pinhole camera in the
medium on the LEM's axis at distance L, with the camera's focal length in
pixels and a box pixel filter; everything inside a 300 m sphere of the same
water (the transport follows light 400 m). The volumetric path tracer
(`volpath`) follows up to ``max_depth`` - 1 scatterings.

Only a strip of the image is rendered, from the axis outward: the scene is
symmetric about the axis, so a strip samples every radius.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from analysis.transport.scene import LEM_RADIUS_M


@dataclass(frozen=True)
class MitsubaStrip:
    """A rendered strip: per-pixel radiance and each pixel centre's distance from the axis [px]."""

    radiance: np.ndarray
    rho_px: np.ndarray
    seconds: float

    def binned(self, edges_px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean radiance per radial bin and its error (the pixels' scatter over √n)."""
        idx = np.searchsorted(edges_px, self.rho_px.ravel(), side="right") - 1
        vals = self.radiance.ravel()
        n = len(edges_px) - 1
        mean = np.full(n, np.nan)
        err = np.full(n, np.nan)
        for i in range(n):
            v = vals[idx == i]
            if v.size >= 2:
                mean[i] = float(v.mean())
                err[i] = float(v.std(ddof=1) / math.sqrt(v.size))
        return mean, err


def render_strip(
    distance_m: float,
    lambda_abs_m: float,
    lambda_sca_m: float,
    focal_px: float,
    *,
    mie_g: float = 0.93,
    rayleigh_fraction: float = 0.17,
    scattering: bool = True,
    reach_px: int = 160,
    height_px: int = 16,
    spp: int = 512,
    max_depth: int = 14,
    seed: int = 0,
    lem_radius_m: float = LEM_RADIUS_M,
    phase: dict[str, object] | None = None,
    near_clip_m: float = 1e-4,
) -> MitsubaStrip:
    """Render the strip [0, reach_px) x [-height_px/2, height_px/2) of the camera's image.

    ``scattering=False`` keeps σ_t but makes the water purely absorbing (the
    direct light alone, whose exact value is known). ``phase`` replaces the
    HG + Rayleigh blend by another Mitsuba phase function (a `tabphase` of
    `bench.phase_shapes`). The camera's rays start ``near_clip_m`` from it
    (Mitsuba's default, 0.01 m, leaves that much water out of every path:
    the direct light 0.03-0.1 % too bright).
    """
    import time

    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    sigma_t = 1.0 / lambda_abs_m + 1.0 / lambda_sca_m
    albedo = (1.0 / lambda_sca_m) / sigma_t if scattering else 0.0
    phase = phase or {
        "type": "blendphase",
        "weight": rayleigh_fraction,
        "phase1": {"type": "hg", "g": mie_g},
        "phase2": {"type": "rayleigh"},
    }
    width = 2 * reach_px
    scene = mi.load_dict(
        {
            "type": "scene",
            "integrator": {"type": "volpath", "max_depth": max_depth, "rr_depth": 1000},
            "water": {"type": "homogeneous", "sigma_t": sigma_t, "albedo": albedo, "phase": phase},
            "bound": {
                "type": "sphere",
                "radius": 300.0,
                "bsdf": {"type": "null"},
                "interior": {"type": "ref", "id": "water"},
            },
            "lem": {
                "type": "sphere",
                "radius": lem_radius_m,
                "bsdf": {"type": "diffuse", "reflectance": 0.0},
                "emitter": {"type": "area", "radiance": 1.0},
                "exterior": {"type": "ref", "id": "water"},
            },
            "sensor": {
                "type": "perspective",
                "fov": 2.0 * math.degrees(math.atan(reach_px / focal_px)),
                "fov_axis": "x",
                "near_clip": near_clip_m,
                "to_world": mi.ScalarTransform4f().look_at(
                    origin=[0.0, 0.0, distance_m], target=[0.0, 0.0, 0.0], up=[0.0, 1.0, 0.0]
                ),
                "medium": {"type": "ref", "id": "water"},
                "film": {
                    "type": "hdrfilm",
                    "width": width,
                    "height": width,
                    "crop_offset_x": reach_px,
                    "crop_offset_y": reach_px - height_px // 2,
                    "crop_width": reach_px,
                    "crop_height": height_px,
                    "rfilter": {"type": "box"},
                    "pixel_format": "rgb",
                },
                "sampler": {"type": "independent", "sample_count": spp},
            },
        }
    )
    t0 = time.perf_counter()
    img = np.array(mi.render(scene, spp=spp, seed=seed))[:, :, 0].astype(np.float64)
    seconds = time.perf_counter() - t0
    ys, xs = np.mgrid[0:height_px, 0:reach_px]
    rho = np.hypot(xs + 0.5, ys + 0.5 - height_px / 2.0)
    return MitsubaStrip(img, rho, seconds)
