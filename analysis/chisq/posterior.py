"""The lengths' shifts averaged over a posterior of held parameters (the phase function's budget line).

`marginal_posterior` takes refits on a grid of held parameters (each axis
spanning a uniform prior) and weighs their shifts by exp(-Δχ²/2s²): with
Δχ² set to zero it is the prior alone. It returns the shifts' mean and
spread, their RMS on each side, and the parameters' posterior mean and
width (`Marginal`). Pure numpy/SciPy, used by `analysis.chisq.systematics`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

#: Points per axis of the fine grid on which `marginal_posterior` integrates.
_MARGINAL_POINTS = 201


@dataclass(frozen=True)
class Marginal:
    """What the posterior over held parameters says: the lengths' mean shift and spread, the parameters'.

    ``shift_m`` and ``spread_m``: posterior mean and standard deviation of
    the (λ_abs, λ_sca, λ_att) shifts from the reference (NaN for a length
    the fit only bounds); ``mean`` and ``sd``: each parameter's posterior
    mean and standard deviation; ``up_m`` and ``down_m``: the RMS of the
    upward and of the downward shifts, each over its own side of the
    posterior (a symmetric spread gives both the RMS of the whole).
    """

    shift_m: np.ndarray
    spread_m: np.ndarray
    mean: tuple[float, ...]
    sd: tuple[float, ...]
    up_m: np.ndarray
    down_m: np.ndarray

    @property
    def rms_m(self) -> np.ndarray:
        """√(E[Δλ²]): the spread plus the distance of the posterior's mean from the reference."""
        return np.hypot(self.shift_m, self.spread_m)


def marginal_posterior(
    axes: Sequence[Sequence[float]],
    d: np.ndarray,
    error_scale: float,
    *,
    coefficient_at: Sequence[float | None] = (),
) -> Marginal:
    """The lengths' shifts averaged over the data's posterior of held parameters with uniform priors.

    ``axes`` are the parameters' values at which the lengths were refitted
    (each axis's ends span that prior's range; one grid point the
    reference, with zero shifts) and ``d`` has shape (*axis lengths, 4):
    (Δλ_abs, Δλ_sca, Δλ_att, Δχ²) against the reference. Between the points
    shifts and Δχ² are interpolated axis by axis (along an axis of four or
    more points Δχ² by a cubic spline, the shifts by a shape-preserving
    cubic; linear along a shorter one); the posterior is
    exp(-Δχ²/(2 s²)) over the prior's box (s the fit's error scale). Where
    the data pin the parameters, the mean shift moves the lengths to where
    the data put them and the spread is the shift over the posterior's
    width; where they do not, the spread covers the prior's range; a refit
    that runs away where the data exclude its parameters gets that
    exclusion's weight, not a secant's.

    ``coefficient_at`` gives, per length, the reference value λ₀ (None:
    none) of a length whose two sides are taken on its coefficient 1/λ
    instead (`_coefficient_sides`): λ_abs, where the data fix 1/λ_att =
    1/λ_abs + 1/λ_sca and the refits trade the two coefficients.
    """
    from scipy.interpolate import CubicSpline, PchipInterpolator, interp1d

    d = np.asarray(d, dtype=float)
    keep = [k for k, ax in enumerate(axes) if len(ax) > 1]
    if not keep:  # nothing varied: no shift, no spread
        zero = np.zeros(3)
        return Marginal(zero, zero, tuple(float(ax[0]) for ax in axes), tuple(0.0 for _ in axes), zero, zero)
    bounded = [not np.all(np.isfinite(d[..., k])) for k in range(3)]
    vals = np.nan_to_num(d.reshape([len(axes[k]) for k in keep] + [4]))
    pts = [np.asarray(axes[k], dtype=float) for k in keep]
    fine = []
    for k, x in enumerate(pts):
        order = np.argsort(x)
        x, vals = x[order], np.take(vals, order, axis=k)
        f = np.linspace(x[0], x[-1], _MARGINAL_POINTS)
        if len(x) >= 4:
            # Δχ² by a cubic spline (near a parabola, and the posterior can be narrower than the
            # points' spacing), the shifts by a shape-preserving cubic (no ringing where a refit ran
            # away at an end the data exclude).
            vals = np.concatenate(
                [PchipInterpolator(x, vals[..., :3], axis=k)(f), CubicSpline(x, vals[..., 3:], axis=k)(f)],
                axis=-1,
            )
        else:
            vals = interp1d(x, vals, axis=k)(f)
        fine.append(f)
    mesh = np.stack(np.meshgrid(*fine, indexing="ij"), axis=-1)
    dchi2 = vals[..., 3] / error_scale**2
    trapezoid = np.ones(_MARGINAL_POINTS)
    trapezoid[[0, -1]] = 0.5
    w = np.exp(-0.5 * (dchi2 - dchi2.min()))
    for k in range(len(pts)):  # the trapezoid rule along each axis
        w *= trapezoid.reshape([-1 if j == k else 1 for j in range(len(pts))])
    w /= w.sum()
    shift, spread, up, down = np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    for k in range(3):
        if bounded[k]:
            shift[k] = spread[k] = up[k] = down[k] = np.nan
            continue
        shift[k] = float(np.sum(w * vals[..., k]))
        spread[k] = math.sqrt(max(float(np.sum(w * (vals[..., k] - shift[k]) ** 2)), 0.0))
        up[k] = _side_rms(w, vals[..., k] > 0, vals[..., k])
        down[k] = _side_rms(w, vals[..., k] < 0, vals[..., k])
        ref = coefficient_at[k] if k < len(coefficient_at) else None
        if ref is not None and math.isfinite(ref) and ref > 0:
            up[k], down[k] = _coefficient_sides(w, vals[..., k], ref, up[k])
    mean, sd = [], []
    it = iter(range(len(pts)))
    for k, ax in enumerate(axes):
        if k not in keep:
            mean.append(float(ax[0]))
            sd.append(0.0)
            continue
        j = next(it)
        m = float(np.sum(w * mesh[..., j]))
        mean.append(m)
        sd.append(math.sqrt(max(float(np.sum(w * (mesh[..., j] - m) ** 2)), 0.0)))
    return Marginal(shift, spread, tuple(mean), tuple(sd), up, down)


def _side_rms(w: np.ndarray, side: np.ndarray, shift: np.ndarray) -> float:
    """√(E[Δλ² | Δλ on that side]): the RMS of the shifts on one side, 0 when there are none.

    Conditional, so that a symmetric spread gives both sides the RMS of the
    whole (pulls with the side toward the truth then keep an RMS of one).
    """
    p = float(np.sum(w[side]))
    return math.sqrt(float(np.sum(w[side] * shift[side] ** 2)) / p) if p > 1e-12 else 0.0


def _coefficient_sides(w: np.ndarray, shift: np.ndarray, ref: float, up_linear: float) -> tuple[float, float]:
    """A length's (up, down) sides taken on its coefficient 1/λ and mapped back to metres.

    The data fix the attenuation coefficient 1/λ_abs + 1/λ_sca; a phase
    function that lengthens λ_sca shortens 1/λ_abs by as much, and where
    1/λ_sca comes near 1/λ_att (turbid water) a small move of the
    coefficient is a large one of λ_abs. The RMS of the length's upward
    shifts is then ruled by the few refits near that pole, and the upper
    side grows far beyond what covers the usual case (turbid water: the
    truth within one error in 84 % of the sets, docs/transport.md). On the
    coefficient the shifts are near linear; the RMS of each side there,
    mapped back (1/(1/λ₀ ∓ RMS) − λ₀), keeps the interval's coverage
    (a monotone map keeps which values lie inside). Refits at finite
    lengths keep the coefficient's downward RMS below 1/λ₀; should it reach
    it (no upper end), the length's own upward RMS (``up_linear``) stays.
    """
    a0 = 1.0 / ref
    da = 1.0 / np.maximum(ref + shift, 1e-9 * ref) - a0
    lower = _side_rms(w, da < 0, da)  # the coefficient's downward side: the length's upward one
    upper = _side_rms(w, da > 0, da)
    up = 1.0 / (a0 - lower) - ref if lower < a0 else up_linear
    return up, ref - 1.0 / (a0 + upper)
