"""Distance scans: a source photographed at a series of distances, in air or in water.

Three laws of a pinhole camera looking at a glowing sphere of radius ``a``
at distance ``L`` through a medium of attenuation length λ:

* the centre gray (the sphere's surface brightness) goes as ``exp(-L / λ)``:
  constant in air (λ of air is tens of kilometres), an exponential decay
  in water, whose slope in ``ln I`` is ``-1 / λ`` (the I_center method);
* the total gray of the image goes as ``L**-2`` (times the same exponential);
* the disk radius is ``f * a / sqrt(L**2 - a**2)``, i.e. ``f * a / L`` far
  from the sphere (the pinhole check of the long-distance test in air).

Each is a straight-line fit (`analysis.calibration.fit.fit_line`) with the
distance errors carried into the weights.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from analysis.calibration.fit import LineFit, combine_repeats, fit_line

#: A distance scan needs this many distinct distances: two for the line, one to test it.
MIN_DISTANCES = 3


@dataclass(frozen=True)
class ScanPoint:
    """The frames taken at one distance, reduced to one value.

    ``value`` is whatever the scan measures (centre gray per second, total
    gray per second, radius in pixels) with its one-sigma error, combined
    over ``n_frames`` repeats; ``distance_err_m`` is the error of the
    distance reading (common to the repeats).
    """

    distance_m: float
    distance_err_m: float
    value: float
    err: float
    n_frames: int


def reduce_scan(
    distances_m: Sequence[float],
    distance_errs_m: Sequence[float],
    values: Sequence[float],
    errors: Sequence[float],
) -> list[ScanPoint]:
    """Combine the repeats taken at each distance (`combine_repeats`), nearest distance first.

    Frames belong to one distance when their manifest distances are equal;
    the distance error is the largest one given for it.
    """
    if not (len(distances_m) == len(distance_errs_m) == len(values) == len(errors)):
        raise ValueError("distances_m, distance_errs_m, values and errors must have one length")
    groups: dict[float, list[int]] = defaultdict(list)
    for i, d in enumerate(distances_m):
        if not (math.isfinite(d) and d > 0):
            raise ValueError(f"distances_m must be finite and > 0, got {d}")
        groups[float(d)].append(i)
    points = []
    for d, idx in sorted(groups.items()):
        c = combine_repeats([values[i] for i in idx], [errors[i] for i in idx])
        points.append(ScanPoint(d, max(float(distance_errs_m[i]) for i in idx), c.mean, c.err, c.n))
    return points


def _check_points(points: Sequence[ScanPoint], what: str, positive: bool = True) -> None:
    if len(points) < MIN_DISTANCES:
        have = ", ".join(f"{p.distance_m:g}" for p in points) or "none"
        raise ValueError(
            f"{what} needs frames at >= {MIN_DISTANCES} distinct distances, got {len(points)} ({have} m)"
        )
    if positive:
        bad = [p.distance_m for p in points if not (p.value > 0 and p.err > 0)]
        if bad:
            raise ValueError(f"{what} needs positive values with errors; not at {bad} m")


@dataclass(frozen=True)
class DecayFit:
    """``ln I = ln I0 - mu * L``: the exponential decay of a brightness with distance.

    ``mu_per_m`` is the attenuation coefficient (1/λ_att) with its error;
    in air it should be consistent with 0. ``amplitude`` is I extrapolated
    to L = 0. ``fit`` is the line in (L, ln I).
    """

    points: tuple[ScanPoint, ...]
    fit: LineFit
    mu_per_m: float
    mu_err_per_m: float
    amplitude: float
    amplitude_err: float

    @property
    def lambda_att_m(self) -> float:
        """1 / mu; infinite when mu <= 0 (no measurable attenuation)."""
        return 1.0 / self.mu_per_m if self.mu_per_m > 0 else math.inf

    @property
    def lambda_att_err_m(self) -> float:
        return self.mu_err_per_m / self.mu_per_m**2 if self.mu_per_m > 0 else math.inf

    @property
    def lambda_att_lower_limit_m(self) -> float:
        """One-sided 95 % lower limit on λ_att: 1 / (mu + 1.645 sigma)."""
        upper_mu = self.mu_per_m + 1.645 * self.mu_err_per_m
        return 1.0 / upper_mu if upper_mu > 0 else math.inf


def decay_fit(points: Sequence[ScanPoint]) -> DecayFit:
    """Fit ``ln I`` against distance; the distance errors enter through the slope.

    The relative error of I is the error of ``ln I``. A constant offset of
    every distance reading (where the rail's zero sits) moves only the
    amplitude, never the slope, so only the reading-to-reading errors matter.
    """
    _check_points(points, "a decay fit")
    d = np.array([p.distance_m for p in points])
    de = np.array([p.distance_err_m for p in points])
    v = np.array([p.value for p in points])
    ve = np.array([p.err for p in points])
    fit = fit_line(d, np.log(v), ve / v, de)
    amp = math.exp(fit.intercept)
    return DecayFit(tuple(points), fit, -fit.slope, fit.slope_err, amp, amp * fit.intercept_err)


@dataclass(frozen=True)
class MediumComparison:
    """The same scan in water and in air: ``mu = mu_water - mu_air``.

    Whatever makes the centre gray drift with distance in both media (the
    geometry of the set-up, a slowly dimming source) cancels; what remains is
    the water's attenuation.
    """

    mu_per_m: float
    mu_err_per_m: float

    @property
    def lambda_att_m(self) -> float:
        return 1.0 / self.mu_per_m if self.mu_per_m > 0 else math.inf

    @property
    def lambda_att_err_m(self) -> float:
        return self.mu_err_per_m / self.mu_per_m**2 if self.mu_per_m > 0 else math.inf


def compare_media(water: DecayFit, air: DecayFit) -> MediumComparison:
    """Attenuation coefficient of water relative to the same scan in air."""
    return MediumComparison(water.mu_per_m - air.mu_per_m, math.hypot(water.mu_err_per_m, air.mu_err_per_m))


@dataclass(frozen=True)
class PowerLawFit:
    """``ln T = c - n * ln L``: the total gray against distance; ``n`` = 2 for 1/L²."""

    points: tuple[ScanPoint, ...]
    fit: LineFit
    exponent: float
    exponent_err: float


def power_law_fit(points: Sequence[ScanPoint]) -> PowerLawFit:
    """Fit ``ln T`` against ``ln L``; a distance error σ_L enters as σ_L / L in ln L."""
    _check_points(points, "a 1/L² fit")
    d = np.array([p.distance_m for p in points])
    de = np.array([p.distance_err_m for p in points])
    v = np.array([p.value for p in points])
    ve = np.array([p.err for p in points])
    fit = fit_line(np.log(d), np.log(v), ve / v, de / d)
    return PowerLawFit(tuple(points), fit, -fit.slope, fit.slope_err)


@dataclass(frozen=True)
class PinholeFit:
    """``r = f * a / sqrt(L**2 - a**2)``: disk radius against distance.

    ``focal_px`` (f) follows from the known source radius
    ``source_radius_m`` (a). Its error ``focal_err_px`` adds in quadrature
    the fit's statistical error ``focal_stat_err_px`` and
    ``focal_sys_err_px``, the change of f when every radius moves by the
    edge finder's systematic offset (the same at all distances, so it does
    not average out). ``radius_distance_px_m`` is ``f * a``, the constant of
    the ``r ∝ 1/L`` law; ``max_rel_residual`` the largest relative deviation
    of a measured radius from the fit.
    """

    points: tuple[ScanPoint, ...]
    fit: LineFit
    source_radius_m: float
    focal_px: float
    focal_stat_err_px: float
    focal_sys_err_px: float
    max_rel_residual: float

    @property
    def focal_err_px(self) -> float:
        return math.hypot(self.focal_stat_err_px, self.focal_sys_err_px)

    @property
    def radius_distance_px_m(self) -> float:
        return self.focal_px * self.source_radius_m

    def radius_px(self, distance_m: np.ndarray | float) -> np.ndarray:
        """The fitted radius at ``distance_m``."""
        d = np.asarray(distance_m, dtype=np.float64)
        a = self.source_radius_m
        return self.focal_px * a / np.sqrt(d * d - a * a)


def pinhole_fit(
    points: Sequence[ScanPoint], source_radius_m: float, radius_offset_px: float = 0.0
) -> PinholeFit:
    """Fit the disk radius against ``a / sqrt(L² - a²)`` through the origin: the slope is f in pixels.

    The exact form (a sphere's angular radius is asin(a/L), imaged at
    f tan of it) differs from f a / L by 0.1 % at 5 m for the LEM.
    ``radius_offset_px`` is the systematic uncertainty of the edge finder,
    one offset shared by every radius: the fit is repeated with the radii
    shifted by it and the change of f is its systematic error.
    """
    if not source_radius_m > 0:
        raise ValueError(f"source_radius_m must be > 0, got {source_radius_m}")
    if radius_offset_px < 0:
        raise ValueError(f"radius_offset_px must be >= 0, got {radius_offset_px}")
    _check_points(points, "the pinhole check")
    d = np.array([p.distance_m for p in points])
    a = float(source_radius_m)
    if np.any(d <= a):
        raise ValueError(f"every distance must exceed the source radius {a} m, got {d.min()} m")
    de = np.array([p.distance_err_m for p in points])
    u = a / np.sqrt(d * d - a * a)
    du = a * d / (d * d - a * a) ** 1.5 * de
    r = np.array([p.value for p in points])
    re = np.array([p.err for p in points])
    fit = fit_line(u, r, re, du, through_origin=True)
    shifted = fit_line(u, r + radius_offset_px, re, du, through_origin=True)
    max_rel = float(np.max(np.abs(fit.residuals) / r))
    return PinholeFit(
        tuple(points), fit, a, fit.slope, fit.slope_err, abs(shifted.slope - fit.slope), max_rel
    )
