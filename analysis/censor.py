"""Gray values clipped at zero: the true mean of a dark band from the pixels that read 0.

A camera whose black level sits at (or near) zero cannot record the
negative half of its read noise: a pixel whose signal plus noise falls
below 0.5 reads 0. The mean of a dark band is then too high, by up to
0.4 σ where the true level is 0 (σ the pixel noise in gray values). The
background the I_center method subtracts comes from such bands, so the
centre value of a faint LEM came out too low: with σ = 2.5 gray and a far
disk of 6 gray over a zero black level, I_center was 17 % low and λ_att
10 % low (`tests/analysis/test_censor.py`).

Model: a pixel reads ``Y = max(round(X), 0)`` with ``X ~ N(μ, σ)``, so

* ``P(Y = 0) = Φ((½ - μ)/σ)``,
* ``E[Y] = Σ_{k ≥ 1} P(Y ≥ k) = Σ_{k ≥ 1} Φ((μ - k + ½)/σ)``.

A band's zero fraction and mean give its σ (`band_sigma`); the dark bands
outside the LEM, where both are well measured, give one σ for the crop
(the read noise, the same everywhere in the dark), and with it each band's
mean is inverted to μ. Bands far above zero are left as they are. Below
σ = 0.5 gray the zeros and ones of a dark band no longer tell σ apart
(and the clipping moves a mean by at most 0.2 gray): nothing is undone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Bands whose zero fraction lies in this range measure σ (enough zeros and enough non-zeros).
SIGMA_ZERO_FRACTION = (0.02, 0.9)
#: Fewest zero pixels (over the bands that measure σ) for a correction: a few dead pixels are not clipping.
MIN_ZERO_PIXELS = 50
#: Below this pixel noise [gray] nothing is undone (see the module's text).
MIN_SIGMA_GRAY = 0.5
#: Bands whose mean lies this many σ above zero are not clipped (their share of zeros is < 10⁻¹⁵).
CLIPPED_WITHIN_SIGMAS = 8.0
#: From this pixel noise [gray] on, `clipped_mean` takes its closed form.
CLOSED_FORM_SIGMA = 1.5
#: Newton steps of `unclipped_mean` (from above on a convex rise: 10⁻⁹ gray within five).
_NEWTON_STEPS = 8
#: Bisection steps (the bracket shrinks by 2⁻²⁶: 10⁻⁶ gray over a bracket of 60).
_STEPS = 26
#: Most bands that measure σ (evenly picked among those that may): enough for its median.
_SIGMA_BANDS = 24


def ndtr(x: np.ndarray | float) -> np.ndarray:
    """Φ, the standard normal distribution function (SciPy's, imported when a sensor clips)."""
    from scipy.special import ndtr as phi  # 0.2 s to import: not on every start of the analysis

    return np.asarray(phi(x))


def ndtri(p: np.ndarray | float) -> np.ndarray:
    """Φ⁻¹."""
    from scipy.special import ndtri as phi_inv

    return np.asarray(phi_inv(p))


def clipped_mean(mu: np.ndarray | float, sigma: np.ndarray | float) -> np.ndarray:
    """``E[max(round(X), 0)]`` for ``X ~ N(mu, sigma)`` (elementwise).

    From σ = 1.5 gray on, the sum's Euler-Maclaurin form
    ``μ Φ(z) + σ φ(z) - φ(z)/(24σ)``, ``z = μ/σ``, is within 1.5·10⁻⁴ gray
    of it (40 times cheaper); below, the sum itself.
    """
    mu, sigma = np.broadcast_arrays(np.asarray(mu, dtype=np.float64), np.asarray(sigma, dtype=np.float64))
    z = mu / sigma
    phi = np.exp(-0.5 * z * z) / math.sqrt(2.0 * math.pi)
    out = np.asarray(mu * ndtr(z) + sigma * phi - phi / (24.0 * sigma))
    small = sigma < CLOSED_FORM_SIGMA
    if small.any():
        ms, ss = mu[small], sigma[small]
        k = np.arange(1, max(math.ceil(np.nanmax(ms + CLIPPED_WITHIN_SIGMAS * ss)) + 2, 2), dtype=np.float64)
        out[small] = ndtr((ms[..., None] - k + 0.5) / ss[..., None]).sum(axis=-1)
    return out


def band_sigma(mean: np.ndarray, zero_fraction: np.ndarray) -> np.ndarray:
    """Each band's σ from its mean and its share of zeros (NaN where they do not fit the model).

    With ``z = -Φ⁻¹(p₀)`` fixed by the zeros, ``μ = ½ + σz`` and the mean
    ``Φ(z) + Σ_{k≥2} Φ(z - (k-1)/σ)`` grows with σ: a bisection over
    0.05-100 gray finds it.
    """
    m = np.asarray(mean, dtype=np.float64)
    p0 = np.asarray(zero_fraction, dtype=np.float64)
    out = np.full(m.shape, np.nan)
    valid = (p0 > 0) & (p0 < 1) & np.isfinite(m)
    if not valid.any():
        return out
    z, mv = -ndtri(p0[valid]), m[valid]
    lo, hi = np.full_like(mv, 0.05), np.full_like(mv, 100.0)
    for _ in range(_STEPS):
        mid = np.sqrt(lo * hi)  # σ spans decades: bisect its logarithm
        above = clipped_mean(0.5 + mid * z, mid) > mv
        hi, lo = np.where(above, mid, hi), np.where(above, lo, mid)
    sigma = np.sqrt(lo * hi)
    out[valid] = np.where((sigma > 0.06) & (sigma < 99.0), sigma, np.nan)
    return out


def unclipped_mean(mean: np.ndarray, sigma: float) -> np.ndarray:
    """The μ whose clipped mean is ``mean`` (for each band), given the pixel noise σ.

    ``clipped_mean`` grows with μ and bends upward, so Newton's steps from
    μ = mean (where it lies above the mean) come down to it without
    overshooting (σ ≥ 1.5 gray; below, a bisection over ``[-4σ, mean + 1]``).
    A mean of (almost) nothing but zeros only bounds μ from above: μ stops
    at -4σ. Means more than `CLIPPED_WITHIN_SIGMAS` σ above zero are
    returned as they are.
    """
    m = np.asarray(mean, dtype=np.float64)
    out = m.copy()
    near = np.isfinite(m) & (m < CLIPPED_WITHIN_SIGMAS * sigma + 1.0)
    if not near.any():
        return out
    mn = m[near]
    if sigma >= CLOSED_FORM_SIGMA:
        mu = mn.copy()
        for _ in range(_NEWTON_STEPS):
            z = mu / sigma
            slope = ndtr(z) + z * np.exp(-0.5 * z * z) / (math.sqrt(2.0 * math.pi) * 24.0 * sigma * sigma)
            mu = np.maximum(mu - (clipped_mean(mu, sigma) - mn) / np.maximum(slope, 1e-12), -4.0 * sigma)
        out[near] = mu
        return out
    lo, hi = np.full_like(mn, -4.0 * sigma), mn + 1.0
    for _ in range(_STEPS):
        mid = 0.5 * (lo + hi)
        above = clipped_mean(mid, sigma) > mn
        hi, lo = np.where(above, mid, hi), np.where(above, lo, mid)
    out[near] = 0.5 * (lo + hi)
    return out


def inversion_slope(mu: np.ndarray | float, sigma: float) -> np.ndarray:
    """d E[Y] / d μ ≈ Φ((μ - ½)/σ), floored at 0.2: how much an error on the clipped mean grows."""
    return np.maximum(ndtr((np.asarray(mu, dtype=np.float64) - 0.5) / sigma), 0.2)


@dataclass(frozen=True)
class Unclipping:
    """What the clipping at zero did to a profile: the pixel noise it was undone with, and where."""

    sigma_gray: float
    n_zero_pixels: float
    max_shift_gray: float


def unclip_bands(
    mean: np.ndarray,
    sem: np.ndarray,
    count: np.ndarray,
    zero_fraction: np.ndarray,
    use: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, Unclipping] | None:
    """Band means and errors with the clipping at zero undone, or None if there is none to undo.

    ``use`` marks the bands that may measure σ (the dark ones outside the
    LEM: inside the disk the noise is the LEM's shot noise, not the read
    noise). σ is the count-weighted median of those bands' σ. Each band's
    error grows by the slope ``1/Φ(z)`` of the inversion.
    """
    p0 = np.nan_to_num(np.asarray(zero_fraction, dtype=np.float64))
    lo_p0, hi_p0 = SIGMA_ZERO_FRACTION
    measured = use & (p0 >= lo_p0) & (p0 <= hi_p0) & np.isfinite(mean) & (count > 0)
    n_zero = float(np.sum(p0[measured] * count[measured]))
    if n_zero < MIN_ZERO_PIXELS:
        return None
    which = np.flatnonzero(measured)
    picks = np.linspace(0, len(which) - 1, min(len(which), _SIGMA_BANDS)).round().astype(int)
    which = which[np.unique(picks)]
    sig = band_sigma(mean[which], p0[which])
    ok = np.isfinite(sig)
    if not ok.any():
        return None
    sigma = _weighted_median(sig[ok], count[which][ok].astype(np.float64))
    if sigma < MIN_SIGMA_GRAY:
        return None
    mu = unclipped_mean(mean, sigma)
    slope = inversion_slope(mu, sigma)
    shift = np.where(np.isfinite(mu), mean - mu, 0.0)
    return mu, sem / slope, Unclipping(float(sigma), n_zero, float(np.max(np.abs(shift), initial=0.0)))


def _weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    order = np.argsort(values)
    cum = np.cumsum(weights[order])
    return float(values[order][int(np.searchsorted(cum, 0.5 * cum[-1]))])
