"""Linearity fits and the pinhole check on simulated frames."""

from __future__ import annotations

import numpy as np
import pytest

from analysis import analyze_frame, gain_factor, hough_radius_px, linearity_fit, pinhole_check
from tests.utils.sim import SMALL_CAMERA, renderer


def test_linearity_fit_finds_slope_r2_and_knee_on_simulated_frames() -> None:
    r = renderer("trex", 21.56, camera=SMALL_CAMERA)
    exposures = [0.01, 0.02, 0.03, 0.05, 0.07, 0.09, 0.11, 0.13, 0.15, 0.2, 0.25]
    gray = []
    for k, e in enumerate(exposures):
        frame, _ = r.render(460, e, 2.0, rng=np.random.default_rng(k))
        gray.append(analyze_frame(frame).center_gray)
    truth_slope = (r.expected_center_gray(460, 0.1, 2.0) - r.expected_center_gray(460, 0.05, 2.0)) / 0.05
    fit = linearity_fit(exposures, gray, (5, 240))
    assert fit.r2 > 0.999
    assert fit.slope == pytest.approx(truth_slope, rel=0.02)
    assert fit.knee_x is not None and fit.knee_x > 0.13
    assert 230 <= fit.linear_max_gray <= 245


def test_linearity_against_gain_is_linear_in_the_gain_factor() -> None:
    r = renderer("trex", 21.56, camera=SMALL_CAMERA)
    gains = [0.0, 2.0, 4.0, 6.0, 8.0]
    gray = [
        analyze_frame(r.render(460, 0.02, g, rng=np.random.default_rng(int(g)))[0]).center_gray for g in gains
    ]
    fit = linearity_fit(gain_factor(np.array(gains)), gray)
    assert fit.r2 > 0.999
    assert fit.knee_x is None


def test_linearity_needs_two_settings_in_range() -> None:
    with pytest.raises(ValueError, match=">= 2 distinct settings"):
        linearity_fit([0.1, 0.2], [250, 255])


def test_hough_radius_follows_one_over_distance() -> None:
    distances = [12.0, 21.56, 30.0, 41.62]
    radii = []
    for d in distances:
        r = renderer("trex", d, camera=SMALL_CAMERA)
        frame, truth = r.render(460, 0.05, 6.0, rng=np.random.default_rng(1))
        res = analyze_frame(frame)
        circle = hough_radius_px(res.crop.pixels, res.radius_px)
        assert circle is not None
        assert circle[2] == pytest.approx(truth.disk_radius_px, rel=0.04)
        radii.append(circle[2])
    check = pinhole_check(distances, radii)
    assert check.max_rel_residual < 0.04
    assert check.focal_px == pytest.approx(SMALL_CAMERA.focal_px, rel=0.03)


def test_pinhole_check_rejects_bad_input() -> None:
    with pytest.raises(ValueError, match=">= 2"):
        pinhole_check([10.0], [50.0])
