"""Stacking the repeats of one setting: the mean of aligned crops, pixels outside the frame left out."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.profile import Crop
from analysis.stack import stack_crops


def _crop(pixels: np.ndarray, center: tuple[float, float] = (20.0, 20.0)) -> Crop:
    return Crop(pixels.astype(np.float32), (0, 0), center)


def test_the_stack_is_the_mean_over_the_finite_pixels_of_each_position() -> None:
    rng = np.random.default_rng(7)
    a, b, c = (rng.normal(10.0, 3.0, (40, 40)) for _ in range(3))
    b[:15, :6] = np.nan  # the LEM near the frame's edge in one repeat
    c[:5, :3] = np.nan  # ... and further in another: there only `a` is left
    out = stack_crops([_crop(a), _crop(b, (21.0, 19.0)), _crop(c, (22.0, 18.0))])
    assert out.pixels.dtype == np.float32
    np.testing.assert_allclose(out.pixels[20:, 10:], ((a + b + c) / 3)[20:, 10:], rtol=1e-6)
    np.testing.assert_allclose(out.pixels[10, 4], (a[10, 4] + c[10, 4]) / 2, rtol=1e-6)
    np.testing.assert_allclose(out.pixels[2, 1], a[2, 1], rtol=1e-6)
    assert out.center_xy == pytest.approx((21.0, 19.0))
    assert np.isfinite(out.pixels).all()


def test_a_pixel_outside_the_frame_in_every_crop_stays_outside() -> None:
    a, b = np.full((8, 8), 4.0), np.full((8, 8), 6.0)
    a[0, 0] = b[0, 0] = np.nan
    out = stack_crops([_crop(a), _crop(b)])
    assert np.isnan(out.pixels[0, 0])
    assert np.isfinite(out.pixels).sum() == 63
    assert out.pixels[3, 3] == pytest.approx(5.0)


def test_crops_of_different_shapes_are_refused() -> None:
    with pytest.raises(ValueError, match="one shape"):
        stack_crops([_crop(np.zeros((8, 8))), _crop(np.zeros((6, 6)))])
    with pytest.raises(ValueError, match="at least one"):
        stack_crops([])
