"""The PSF fit of a point-like source: the focus check."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from analysis.calibration import fit_point_source, pixel_integrated_gaussian, psf_width, psf_width_of
from lrm.sim.camera import CameraModel
from lrm.sim.lab import PointSourceRenderer


def test_pixel_integrated_gaussian_holds_all_light_on_the_right_pixels() -> None:
    cols = np.arange(-10.0, 11.0)
    g = pixel_integrated_gaussian(cols, cols, 0.3, -0.2, 1.1, 1.7)
    assert_allclose(g.sum(), 1.0, atol=1e-9)
    rows = cols[:, None]
    assert_allclose((g * cols[None, :]).sum(), 0.3, atol=1e-9)
    assert_allclose((g * rows).sum(), -0.2, atol=1e-9)
    # Pixel integration widens the variance by 1/12 pixel² over the Gaussian's.
    assert_allclose((g * (cols[None, :] - 0.3) ** 2).sum(), 1.1**2 + 1 / 12, rtol=1e-3)


@pytest.mark.parametrize("sigma_px", [0.8, 1.2, 2.0])
def test_recovers_the_simulated_psf_width(sigma_px: float) -> None:
    camera = CameraModel(width_px=96, height_px=96, psf_sigma_px=sigma_px)
    renderer = PointSourceRenderer(camera, seed=1)
    rng = np.random.default_rng(2)
    fits = []
    for _ in range(12):
        x, y = 47.5 + rng.uniform(-0.5, 0.5), 48.0 + rng.uniform(-0.5, 0.5)
        peak_fraction = math.erf(0.5 / (math.sqrt(2) * sigma_px)) ** 2
        flux = 150.0 / (peak_fraction * camera.gray_per_electron * camera.gain_factor(12.0) * 0.05)
        frame, truth = renderer.render(x, y, flux, 0.05, 12.0, rng=rng)
        fit = fit_point_source(frame, (x, y), half_size_px=max(8, math.ceil(4 * sigma_px)))
        assert_allclose([fit.x_px, fit.y_px], [x, y], atol=0.05)
        assert_allclose(fit.flux_gray, truth.flux_gray, rtol=0.04)  # shot noise of ~4000 e: 1.5 %
        fits.append(fit)
    result = psf_width_of(fits)
    assert abs(result.sigma.mean - sigma_px) < 3 * result.sigma.err
    assert result.sigma.err < 0.01 * sigma_px
    assert result.ellipticity < 0.03


def test_astigmatism_shows_in_the_two_widths() -> None:
    # An elliptical PSF drawn by supersampling, independent of the erf model.
    rng = np.random.default_rng(3)
    k, size = 10, 41
    sub = (np.arange(size * k) + 0.5) / k - 0.5
    gx = np.exp(-0.5 * ((sub - 20.2) / 1.0) ** 2).reshape(size, k).sum(1)
    gy = np.exp(-0.5 * ((sub - 19.7) / 1.6) ** 2).reshape(size, k).sum(1)
    image = 4000.0 * np.outer(gy, gx) / (2 * math.pi * 1.0 * 1.6 * k * k) + 10.0
    frame = np.clip(np.round(image + rng.normal(0, 0.6, image.shape)), 0, 255).astype(np.uint8)
    fit = fit_point_source(frame, (20.0, 20.0), half_size_px=9)
    assert abs(fit.sigma_x_px - 1.0) < 3 * fit.sigma_x_err_px
    assert abs(fit.sigma_y_px - 1.6) < 3 * fit.sigma_y_err_px
    assert_allclose(fit.background_gray, 10.0, atol=0.2)


def test_window_leaving_the_frame_is_refused() -> None:
    frame = np.zeros((32, 32), dtype=np.uint8)
    with pytest.raises(ValueError, match="window leaves the frame"):
        fit_point_source(frame, (3.0, 16.0), half_size_px=8)
    with pytest.raises(ValueError, match="half_size_px must be >= 3"):
        fit_point_source(frame, (16.0, 16.0), half_size_px=2)


def test_psf_width_needs_a_fit() -> None:
    with pytest.raises(ValueError, match="no usable point-source frame"):
        psf_width([], [], [], [])
