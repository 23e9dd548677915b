"""A camera whose black level sits at zero: its clipped dark means undone, a faint LEM's I_center is right.

The frames here are drawn with numpy alone (no part of camcal's simulator):
a uniform disk of known gray over a known halo and a zero black level,
Gaussian read noise, rounded to integers and clipped at 0 as an 8-bit
sensor does. The truth is the disk's gray itself.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from analysis import FrameConfig, analyze_frame
from analysis.censor import band_sigma, clipped_mean, unclipped_mean
from analysis.stack import stack_frames

RADIUS_PX = 45.0
SIZE_PX = 420


CASES = [(0.0, 2.5), (1.0, 2.5), (3.0, 2.5), (0.0, 1.0), (-1.0, 1.5), (0.6, 0.3)]


@pytest.mark.parametrize(("mu", "sigma"), CASES)
def test_the_model_of_a_clipped_pixel_matches_clipped_samples(mu: float, sigma: float) -> None:
    rng = np.random.default_rng(1)
    y = np.maximum(np.round(rng.normal(mu, sigma, 400_000)), 0)
    mean, p0 = float(y.mean()), float((y == 0).mean())
    sem = float(y.std() / math.sqrt(y.size))
    assert float(clipped_mean(mu, sigma)) == pytest.approx(mean, abs=4 * sem)
    assert band_sigma(np.array([mean]), np.array([p0]))[0] == pytest.approx(sigma, rel=0.02)
    assert unclipped_mean(np.array([mean]), sigma)[0] == pytest.approx(mu, abs=0.02 + 4 * sem / 0.3)


def test_bands_without_zeros_or_far_above_them_are_left_alone() -> None:
    assert math.isnan(band_sigma(np.array([20.0]), np.array([0.0]))[0])
    assert unclipped_mean(np.array([40.0, 12.3]), 1.0).tolist() == [40.0, 12.3]


def draw_frame(
    rng: np.random.Generator,
    disk_gray: float,
    sigma_gray: float,
    black_gray: float = 0.0,
    halo_gray: float = 1.5,
) -> np.ndarray:
    """8-bit frame: disk + exponential halo + black level + Gaussian noise, rounded and clipped."""
    cx, cy = SIZE_PX / 2 + rng.uniform(-3, 3), SIZE_PX / 2 + rng.uniform(-3, 3)
    yy, xx = np.mgrid[0:SIZE_PX, 0:SIZE_PX]
    r = np.hypot(xx - cx, yy - cy)
    disk = np.clip(RADIUS_PX + 0.5 - r, 0.0, 1.0)  # one-pixel antialiased edge
    halo = halo_gray * np.exp(-np.maximum(r - RADIUS_PX, 0.0) / 25.0)
    signal = black_gray + disk_gray * disk + halo * (1 - disk)
    return np.clip(np.round(signal + rng.normal(0.0, sigma_gray, signal.shape)), 0, 255).astype(np.uint8)


CONFIG = FrameConfig(expected_radius_px=RADIUS_PX)


@pytest.mark.parametrize("disk_gray", [6.0, 10.0, 20.0])
def test_a_faint_disk_over_a_zero_black_level_is_measured_without_bias(disk_gray: float) -> None:
    rng = np.random.default_rng([7, int(disk_gray)])
    results = [analyze_frame(draw_frame(rng, disk_gray, 2.5), CONFIG) for _ in range(16)]
    assert all(r.ok for r in results), [r.reason for r in results]
    values = np.array([r.i_center_gray for r in results])
    errors = np.array([r.i_center_err_gray for r in results])
    # Without the unclipping the background came out ~0.4 σ = 1 gray high: I_center 17 % low at 6 gray.
    assert abs(values.mean() - disk_gray) < max(0.015 * disk_gray, 3 * errors.mean() / 4)
    assert all(r.profile.unclipped is not None for r in results)
    assert results[0].profile.unclipped.sigma_gray == pytest.approx(2.5, rel=0.05)
    # The errors say what the scatter is (not much smaller).
    assert values.std(ddof=1) < 1.4 * np.sqrt(np.mean(errors**2))
    # Stacked, as `camcal analyze` and the χ² fit stack a setting's frames: the same.
    stack = stack_frames(results)
    tolerance = max(0.015 * disk_gray, 3 * stack.i_center_err_gray)
    assert stack.i_center_gray == pytest.approx(disk_gray, abs=tolerance)
    assert stack.measurement is not None and stack.measurement.profile.unclipped is not None


def test_a_black_level_above_the_noise_is_left_as_it_was() -> None:
    rng = np.random.default_rng(3)
    results = [analyze_frame(draw_frame(rng, 10.0, 2.5, black_gray=12.0), CONFIG) for _ in range(8)]
    assert all(r.ok and r.profile.unclipped is None for r in results)
    assert np.mean([r.i_center_gray for r in results]) == pytest.approx(10.0, abs=0.3)


def test_a_few_dead_pixels_are_not_a_clipped_sensor() -> None:
    rng = np.random.default_rng(4)
    frame = draw_frame(rng, 30.0, 2.5, black_gray=12.0)
    dead = rng.integers(0, SIZE_PX, size=(40, 2))
    frame[dead[:, 0], dead[:, 1]] = 0
    r = analyze_frame(frame, CONFIG)
    assert r.ok and r.profile.unclipped is None


def test_the_closed_form_of_the_clipped_mean_is_the_sum_it_stands_for() -> None:
    mu = np.linspace(-5.0, 30.0, 400)
    for sigma in (1.5, 2.5, 6.0):
        z = (mu[:, None] - np.arange(1, 100) + 0.5) / sigma
        exact = np.array([sum(0.5 * math.erfc(-x / math.sqrt(2)) for x in row) for row in z])
        assert np.max(np.abs(clipped_mean(mu, sigma) - exact)) < 1.5e-4
