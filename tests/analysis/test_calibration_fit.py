"""The weighted line fit, repeat combination and weighted mean shared by the calibrations."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from analysis.calibration import combine_repeats, fit_line, weighted_mean


def test_fit_line_errors_are_honest_over_many_seeds() -> None:
    # y = 3 x + 2 with known Gaussian errors: the pulls of slope and intercept
    # over many independent data sets must have unit spread.
    x = np.linspace(0.0, 10.0, 12)
    sigma = np.full_like(x, 0.5)
    rng = np.random.default_rng(1)
    pulls = []
    for _ in range(400):
        fit = fit_line(x, 3.0 * x + 2.0 + rng.normal(0, sigma), sigma)
        pulls.append(((fit.slope - 3.0) / fit.slope_err, (fit.intercept - 2.0) / fit.intercept_err))
    p = np.array(pulls)
    assert_allclose(p.mean(axis=0), 0.0, atol=0.15)
    # The error is only ever scaled up (chi2/ndof > 1), so the spread is a little below 1.
    assert np.all((p.std(axis=0) > 0.8) & (p.std(axis=0) < 1.1))


def test_fit_line_carries_x_errors_through_the_slope() -> None:
    # A point with a large x error is off the line in y: with its x error it
    # barely moves the slope; without it, it drags the slope away.
    x = np.array([0.0, 1.0, 2.0, 3.0, 4.0, 5.0])
    y = 2.0 * x
    y[5] += 3.0
    y_err = np.full_like(x, 0.05)
    x_err = np.array([0, 0, 0, 0, 0, 2.0])
    with_x = fit_line(x, y, y_err, x_err)
    without = fit_line(x, y, y_err)
    assert abs(with_x.slope - 2.0) < 0.05
    assert abs(without.slope - 2.0) > 0.3
    assert_allclose(with_x.sigma_eff[5], np.hypot(0.05, with_x.slope * 2.0))


def test_fit_line_scales_errors_up_when_points_scatter_more_than_stated() -> None:
    rng = np.random.default_rng(2)
    x = np.linspace(0, 1, 50)
    y = x + rng.normal(0, 0.3, x.size)
    fit = fit_line(x, y, np.full_like(x, 0.1))
    assert 2.5 < fit.error_scale < 3.5
    honest = fit_line(x, y, np.full_like(x, 0.3))
    assert_allclose(fit.slope_err, honest.slope_err, rtol=0.1)


def test_fit_line_through_origin_has_no_intercept() -> None:
    x = np.array([1.0, 2.0, 4.0])
    fit = fit_line(x, 5.0 * x, [0.1, 0.1, 0.1], through_origin=True)
    assert_allclose(fit.slope, 5.0)
    assert fit.intercept == 0.0 and fit.ndof == 2


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (([0, 1, 2], [0, 1], [1, 1, 1]), "one length"),
        (([0, 1, 2], [0, 1, 2], [1, 0, 1]), "y_err must be > 0"),
        (([1, 1, 1], [0, 1, 2], [1, 1, 1]), ">= 2 distinct x"),
        (([0, 1, np.nan], [0, 1, 2], [1, 1, 1]), "x must be finite"),
    ],
)
def test_fit_line_names_the_bad_argument(args: tuple, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        fit_line(*args)


def test_combine_repeats_takes_the_larger_of_scatter_and_propagated_error() -> None:
    scattered = combine_repeats([1.0, 3.0, 1.0, 3.0], [0.01] * 4)
    assert_allclose(scattered.mean, 2.0)
    assert_allclose(scattered.err, np.std([1, 3, 1, 3], ddof=1) / 2)
    tight = combine_repeats([2.0, 2.0], [0.4, 0.4])
    assert_allclose(tight.err, np.sqrt(2) * 0.4 / 2)
    single = combine_repeats([5.0], [0.3])
    assert (single.mean, single.err, single.n) == (5.0, 0.3, 1)


def test_weighted_mean_scales_its_error_when_values_disagree() -> None:
    agree = weighted_mean([1.0, 1.0], [0.1, 0.1])
    assert_allclose(agree.err, 0.1 / np.sqrt(2))
    disagree = weighted_mean([1.0, 2.0], [0.1, 0.1])
    assert_allclose(disagree.mean, 1.5)
    assert_allclose(disagree.err, 0.1 / np.sqrt(2) * np.sqrt(disagree.chi2_ndof))
