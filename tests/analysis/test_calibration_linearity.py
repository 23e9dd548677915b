"""The linear-response fit: slope, dark level, linear range and where the response leaves the line."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.calibration import response_linearity
from lrm.sim.camera import CameraModel
from lrm.sim.lab import departure_gray, expected_mean_gray

CAMERA = CameraModel(width_px=64, height_px=64)
EXPOSURES_S = (
    np.array([1, 2, 5, 10, 20, 35, 50, 75, 100, 125, 150, 170, 185, 195, 205, 215, 230, 250, 300, 350]) / 1e3
)
RATE_E_PER_S = 15000.0
GAIN_DB = 6.0


def _sweep(seed: int, err_gray: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """The camera's mean response along the darkroom sweep, with Gaussian measurement noise."""
    mean = expected_mean_gray(CAMERA, RATE_E_PER_S * EXPOSURES_S, GAIN_DB)
    noisy = np.clip(mean + np.random.default_rng(seed).normal(0, err_gray, mean.size), 0, 255)
    return noisy, np.full(mean.size, err_gray)


def test_recovers_slope_dark_level_and_departure_of_the_simulated_sensor() -> None:
    gray, err = _sweep(seed=3)
    curve = response_linearity(EXPOSURES_S, gray, err, sweep="exposure", fixed=GAIN_DB)
    slope = RATE_E_PER_S * CAMERA.gray_per_electron * CAMERA.gain_factor(GAIN_DB)
    assert abs(curve.fit.slope - slope) < 3 * curve.fit.slope_err
    assert abs(curve.fit.intercept - CAMERA.black_level_gray) < 3 * curve.fit.intercept_err
    assert curve.fit.r2 > 0.9999
    true_departure = departure_gray(
        CAMERA, RATE_E_PER_S * np.linspace(1e-4, 0.35, 20000), GAIN_DB, curve.tolerance
    )
    assert curve.departure_gray is not None and curve.departure_err_gray is not None
    assert abs(curve.departure_gray - true_departure) < 3 * curve.departure_err_gray
    # The recommended range ends at a measured point still within the tolerance.
    low, high = curve.linear_range_gray
    assert low == pytest.approx(gray[0]) and CAMERA.knee_gray - 20 < high <= true_departure
    # Clipped points (the ADC at 255) never enter the line or the range.
    assert not any(lin for lin, g in zip(curve.linear, curve.gray, strict=True) if g >= 254)


def test_fitted_points_lie_inside_the_linear_range() -> None:
    gray, err = _sweep(seed=4)
    curve = response_linearity(EXPOSURES_S, gray, err, sweep="exposure", fixed=GAIN_DB)
    assert all(lin for lin, fit in zip(curve.linear, curve.fitted, strict=True) if fit)
    assert sum(curve.fitted) >= 10


def test_finds_a_nonlinear_bottom_too() -> None:
    # A sensor that clips its dark level at 6 gray: the flat bottom is left out.
    x = np.arange(1.0, 21.0)
    gray = np.maximum(2.0 + 4.0 * x, 12.0)
    curve = response_linearity(x, gray, np.full(x.size, 0.05), sweep="gain", fixed=0.04)
    assert curve.linear_range_gray[0] == pytest.approx(14.0)
    assert not any(curve.linear[:2])
    assert curve.fit.slope == pytest.approx(4.0)
    assert curve.departure_gray is None  # the top never leaves the line


def test_all_clipped_sweep_is_refused_naming_the_sweep() -> None:
    x = np.array([0.1, 0.2, 0.3, 0.4])
    with pytest.raises(ValueError, match="exposure sweep: 4 of 4 settings are clipped"):
        response_linearity(x, np.full(4, 255.0), np.full(4, 0.1), sweep="exposure", fixed=0.0)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"sweep": "time"}, "sweep must be"),
        ({"tolerance": 0.0}, "tolerance must lie"),
        ({"min_points": 2}, "min_points"),
    ],
)
def test_bad_parameters_are_named(kwargs: dict, message: str) -> None:
    base = {"sweep": "exposure", "fixed": 0.0}
    with pytest.raises(ValueError, match=message):
        response_linearity([1, 2, 3, 4], [1, 2, 3, 4], [0.1] * 4, **{**base, **kwargs})
