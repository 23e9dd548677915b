"""Every LEM that is there is found: faint ones in the linear range are `ok`, darker visible ones
`too_dark`, and only frames without a LEM are `no_source`.

Simulated frames (the camera hardware is what is simulated) of both T-REX
cameras on the small sensor (T-REX plate scale), across exposures from a
LEM lost in the noise to a bright one, at two gains, with camcal's default
sensor and a noisier one (dark offset 3 DN, ~1 DN read noise: the faint
frames of issue 12), each LEM displaced at random in the frame. The frame
analysis knows the LEM's size only from the geometry (distance, focal
length: `Setup.frame_settings`).
"""

from __future__ import annotations

import math
from collections import Counter

import numpy as np
import pytest

from analysis import FrameConfig, analyze_frame
from camcal.core.frameset import Setup
from lrm.sim import CameraModel, FrameRenderer, Placement
from lrm.sim.scene import water_preset
from tests.utils.sim import SMALL_CAMERA

NOISY = CameraModel(
    width_px=SMALL_CAMERA.width_px,
    height_px=SMALL_CAMERA.height_px,
    fov_deg=SMALL_CAMERA.fov_deg,
    black_level_gray=3.0,
    read_noise_e=25.0,
)
#: A disk whose summed signal-to-noise reaches this is "visible" (see bench/bench_detect.py).
VISIBLE_SNR = 30.0


def noise_gray(cam: CameraModel, exposure_s: float, gain_db: float) -> float:
    g = cam.gray_per_electron * cam.gain_factor(gain_db)
    return math.sqrt((cam.dark_current_e_per_s * exposure_s + cam.read_noise_e**2) * g * g + 1 / 12)


@pytest.fixture(scope="module")
def classified() -> list[dict[str, object]]:
    setup = Setup()
    water = water_preset("trex")
    rng = np.random.default_rng(2026)
    out = []
    for cam in (SMALL_CAMERA, NOISY):
        for pl in (Placement("A", 21.56, 0.02, False), Placement("B", 41.62, 0.04, True)):
            r = FrameRenderer(cam, pl, water, seed=4)
            config = FrameConfig(**setup.frame_settings(pl.camera))
            assert config.expected_radius_px == pytest.approx(r.disk_radius_px, rel=1e-6)
            n_disk = math.pi * r.disk_radius_px**2
            for gain in (0.0, 6.0):
                for exposure in np.geomspace(1e-4, 0.03, 14):
                    exp = float(exposure)
                    g = cam.gray_per_electron * cam.gain_factor(gain)
                    expected = r.expected_center_gray(460, exp, gain)
                    dark = cam.black_level_gray + cam.dark_current_e_per_s * exp * g
                    sigma = noise_gray(cam, exp, gain)
                    for _ in range(3):
                        off = tuple(rng.normal(0.0, 25.0, 2))
                        frame, _ = r.render(460, exp, gain, rng=rng, offset_px=off)
                        res = analyze_frame(frame, config)
                        out.append(
                            {
                                "on": True,
                                "centre": expected,
                                "centre_err": sigma / 10.0,  # the mean of 100 centre pixels
                                "snr": (expected - dark) * math.sqrt(n_disk) / sigma,
                                "status": res.reason or res.status,
                            }
                        )
            for k in range(25):
                frame, _ = r.render(460, float(np.geomspace(1e-4, 0.5, 25)[k]), 6.0, rng=rng, lem_on=False)
                out.append({"on": False, "status": analyze_frame(frame, config).reason or "ok"})
    return out


def test_a_lem_whose_centre_is_in_the_linear_range_is_ok(classified: list[dict[str, object]]) -> None:
    # In range beyond its measurement noise (3 σ of the centre's mean) and below the knee's reach.
    in_range = [f for f in classified if f["on"] and 5 + 3 * f["centre_err"] <= f["centre"] <= 225]
    ok = sum(f["status"] == "ok" for f in in_range)
    assert len(in_range) > 100
    assert ok >= 0.99 * len(in_range), Counter(f["status"] for f in in_range)


def test_a_visible_lem_below_the_linear_range_is_too_dark(classified: list[dict[str, object]]) -> None:
    dark = [
        f
        for f in classified
        if f["on"] and f["snr"] >= VISIBLE_SNR and f["centre"] <= 5 - 3 * f["centre_err"]
    ]
    assert len(dark) > 30
    assert Counter(f["status"] for f in dark) == Counter({"too_dark": len(dark)})


def test_without_a_lem_the_frame_is_no_source(classified: list[dict[str, object]]) -> None:
    off = [f for f in classified if not f["on"]]
    assert len(off) == 100
    assert sum(f["status"] != "no_source" for f in off) <= 0.01 * len(off)


def test_the_no_source_detail_says_how_far_the_best_disk_stood_out() -> None:
    frame = np.full((512, 640), 3, np.uint8)
    res = analyze_frame(frame, FrameConfig(**Setup().frame_settings("B")))
    assert res.reason == "no_source" and "45 px" in res.detail and "σ" in res.detail
