"""The photon transport against Mitsuba 3 on a small render (slow; needs the ``validate`` extra)."""

from __future__ import annotations

import importlib.util
import math

import numpy as np
import pytest

from analysis.transport.cache import TemplateCache
from analysis.transport.disk import disk_radius_px
from analysis.transport.scene import LEM_RADIUS_M

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(
        importlib.util.find_spec("mitsuba") is None,
        reason="mitsuba is not installed: pip install -e '.[validate]' to check the transport against it",
    ),
]

FOCAL_PX = 1224.0 / math.tan(math.radians(8.0))


def test_turbid_halo_and_direct_light_agree_with_mitsuba(tmp_path) -> None:
    from bench.bench_mitsuba import REACH_PX, compare_direct, compare_halo, transport_profile
    from bench.mitsuba_scene import render_strip

    la, ls, dist = 25.0, 25.0, 41.62
    r_disk = disk_radius_px(dist, LEM_RADIUS_M, FOCAL_PX)
    value, err = transport_profile(dist, la, ls, 60_000, 12, TemplateCache(tmp_path))
    strip = render_strip(dist, la, ls, FOCAL_PX, spp=128, height_px=16, max_depth=14)
    assert strip.radiance.shape == (16, REACH_PX)
    halo = compare_halo(strip, value, err, r_disk)
    # Within the two engines' combined Monte Carlo errors, band by band and overall.
    assert halo["ndof"] >= 10
    assert halo["chi2"] / halo["ndof"] < 2.5, halo
    assert halo["max_pull"] < 4.0, halo
    ratio = np.asarray(halo["ratio"])
    assert abs(float(np.nanmean(ratio)) - 1.0) < 0.05, ratio
    # No scattering: Mitsuba's direct light is the exact transmittance along each ray.
    direct = render_strip(
        dist, la, ls, FOCAL_PX, scattering=False, reach_px=int(r_disk // 2) + 2, height_px=8, spp=1024
    )
    d = compare_direct(direct, dist, la, ls, r_disk)
    assert abs(d["mitsuba_over_exact"] - 1.0) < 4 * d["mitsuba_err"] / d["exact"] + 1e-3, d
    # ...and so is the fit's disk model (the path to the sphere's surface, per band): within 0.5 %.
    assert abs(d["model_over_exact"] - 1.0) < 0.005, d
