"""Distance scans: decay in water, constancy in air, 1/L², the pinhole law."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest
from numpy.testing import assert_allclose

from analysis.calibration import (
    ScanPoint,
    compare_media,
    decay_fit,
    pinhole_fit,
    power_law_fit,
    reduce_scan,
)

DISTANCES_M = np.array([1.0, 1.25, 1.5, 1.75, 2.0, 2.25, 2.5, 2.75, 3.0])


def _decay_points(
    mu: float, rng: np.random.Generator, rel_err: float = 0.002, dist_err: float = 0.01
) -> list[ScanPoint]:
    """A scan read off a scale: true distances scatter around the readings by ``dist_err``."""
    true = DISTANCES_M + rng.normal(0, dist_err, DISTANCES_M.size)
    value = 1000.0 * np.exp(-mu * true) * (1 + rng.normal(0, rel_err, DISTANCES_M.size))
    return [ScanPoint(d, dist_err, v, rel_err * v, 2) for d, v in zip(DISTANCES_M, value, strict=True)]


def test_reduce_scan_groups_repeats_by_distance() -> None:
    pts = reduce_scan([2.0, 1.0, 2.0, 1.0], [0.01, 0.01, 0.02, 0.01], [10.0, 20.0, 12.0, 20.0], [0.1] * 4)
    assert [p.distance_m for p in pts] == [1.0, 2.0]
    assert_allclose([p.value for p in pts], [20.0, 11.0])
    assert [p.n_frames for p in pts] == [2, 2]
    assert pts[1].distance_err_m == 0.02
    with pytest.raises(ValueError, match="distances_m must be finite and > 0"):
        reduce_scan([0.0], [0.0], [1.0], [0.1])


def test_decay_fit_errors_include_the_distance_readings() -> None:
    # λ_att = 7.5 m; 1 cm distance readings. Over many scans the pulls of mu
    # have unit spread only because the distance errors enter the weights.
    rng = np.random.default_rng(11)
    pulls = []
    for _ in range(300):
        fit = decay_fit(_decay_points(1 / 7.5, rng))
        pulls.append((fit.mu_per_m - 1 / 7.5) / fit.mu_err_per_m)
    assert abs(np.mean(pulls)) < 0.15
    assert 0.85 < np.std(pulls) < 1.15
    one = decay_fit(_decay_points(1 / 7.5, np.random.default_rng(5)))
    assert abs(one.lambda_att_m - 7.5) < 3 * one.lambda_att_err_m
    assert_allclose(one.lambda_att_err_m, one.mu_err_per_m * one.lambda_att_m**2)


def test_air_scan_shows_no_decay_and_the_water_one_relative_to_it() -> None:
    rng = np.random.default_rng(3)
    air = decay_fit(_decay_points(0.0, rng))
    assert abs(air.mu_per_m) < 3 * air.mu_err_per_m
    assert air.lambda_att_lower_limit_m > 20.0
    water = decay_fit(_decay_points(0.2, rng))
    rel = compare_media(water, air)
    assert_allclose(rel.mu_per_m, water.mu_per_m - air.mu_per_m)
    assert_allclose(rel.mu_err_per_m, math.hypot(water.mu_err_per_m, air.mu_err_per_m))
    assert abs(rel.lambda_att_m - 5.0) < 3 * rel.lambda_att_err_m


def test_power_law_recovers_inverse_square() -> None:
    rng = np.random.default_rng(4)
    d = np.array([5.2, 10.0, 15.0, 20.0, 25.0, 30.0, 35.0, 41.2])
    total = 1e8 / d**2 * (1 + rng.normal(0, 0.003, d.size))
    fit = power_law_fit([ScanPoint(x, 0.0, t, 0.003 * t, 1) for x, t in zip(d, total, strict=True)])
    assert abs(fit.exponent - 2.0) < 3 * fit.exponent_err
    assert fit.exponent_err < 0.01


def test_pinhole_fit_recovers_the_focal_length_and_its_edge_systematic() -> None:
    a, f = 0.215, 2276.9
    d = np.array([5.2, 10.0, 20.0, 30.0, 41.2])
    radius = f * a / np.sqrt(d**2 - a**2) + 0.05  # an edge finder 0.05 px outward
    pts = [ScanPoint(x, 0.0, r, 0.02, 2) for x, r in zip(d, radius, strict=True)]
    plain = pinhole_fit(pts, a)
    assert plain.focal_sys_err_px == 0.0
    assert abs(plain.focal_px - f) > 2 * plain.focal_err_px  # the offset biases f beyond its stat error
    honest = pinhole_fit(pts, a, radius_offset_px=0.05)
    assert honest.focal_sys_err_px > 0
    assert abs(honest.focal_px - f) < 3 * honest.focal_err_px
    assert_allclose(honest.radius_px(d), f * a / np.sqrt(d**2 - a**2), rtol=5e-3)


@pytest.mark.parametrize("fit", [decay_fit, power_law_fit, lambda p: pinhole_fit(p, 0.2)])
def test_scans_need_three_distances(fit: Callable[[list[ScanPoint]], object]) -> None:
    pts = [ScanPoint(1.0, 0.0, 10.0, 0.1, 1), ScanPoint(2.0, 0.0, 9.0, 0.1, 1)]
    with pytest.raises(ValueError, match=r"needs frames at >= 3 distinct distances, got 2 \(1, 2 m\)"):
        fit(pts)
