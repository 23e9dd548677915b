"""Per-frame measurements of the lab calibrations: aperture sums, fixed-pixel grays, sources."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from analysis.calibration import aperture_sum, gray_at, measure_source
from analysis.profile import Crop
from tests.utils.labsets import render_in_memory


def test_aperture_sum_counts_the_light_above_the_background() -> None:
    pixels = np.full((101, 101), 5.0, dtype=np.float32)
    yy, xx = np.mgrid[0:101, 0:101]
    pixels[(yy - 50) ** 2 + (xx - 50) ** 2 <= 10**2] += 100.0
    inside = int(np.count_nonzero((yy - 50) ** 2 + (xx - 50) ** 2 <= 10**2))
    s = aperture_sum(Crop(pixels, (0, 0), (50.0, 50.0)), 20.0, 5.0, 0.01)
    assert_allclose(s.total_gray, 100.0 * inside)
    assert s.complete and s.n_pixels == np.count_nonzero((yy - 50) ** 2 + (xx - 50) ** 2 <= 400)
    assert_allclose(s.total_err_gray, s.n_pixels * 0.01, rtol=1e-6)  # the dark part is noiseless here
    pixels[:, :40] = np.nan  # the frame edge cuts the aperture
    assert not aperture_sum(Crop(pixels, (0, 0), (50.0, 50.0)), 20.0, 5.0, 0.01).complete


def test_measure_source_finds_total_and_hough_radius_of_a_lab_frame() -> None:
    _, _, frames = render_in_memory("air-scan", wavelengths_nm=(460,), distances_m=(10.0, 20.0, 30.0))
    frame, truth = frames[1]
    m = measure_source(frame)
    assert m.analysis.ok and m.analysis.crop is None  # the crop is dropped: results stay small
    assert m.hough_radius_px is not None
    assert abs(m.hough_radius_px - truth["disk_radius_px"]) < 0.15
    expected_total = truth["direct_center_gray"] * np.pi * truth["disk_radius_px"] ** 2
    assert m.total is not None and m.total.complete
    assert abs(m.total.total_gray - expected_total) < 0.01 * expected_total


def test_gray_at_refuses_a_position_outside_the_frame() -> None:
    frame = np.zeros((20, 30), dtype=np.uint8)
    assert gray_at(frame, (10.0, 10.0)).mean_gray == 0.0
    with pytest.raises(ValueError, match=r"center_xy \(35.0, 5.0\) lies outside the 30 x 20 frame"):
        gray_at(frame, (35.0, 5.0))
