"""Random directions, phase-function sampling and sphere geometry for the photon transport.

Every function works on whole batches (arrays of photons) so the transport
loop costs a few dozen numpy passes per scattering step, not a Python loop
per photon. Directions are unit vectors stored as ``(n, 3)`` float64 arrays.
"""

from __future__ import annotations

import numpy as np

from analysis.scattering import henyey_greenstein_sr, rayleigh_sr


def mixed_phase_sr(cos_theta: np.ndarray, mie_g: float, rayleigh_fraction: float) -> np.ndarray:
    """Mie (Henyey-Greenstein, ⟨cos θ⟩ = ``mie_g``) plus Rayleigh phase function, per steradian.

    The same mixture as `analysis.scattering.phase_function_sr`, without the
    need for a full `WaterOptics` (absorption plays no part in the sampling).
    """
    f = rayleigh_fraction
    out = (1.0 - f) * henyey_greenstein_sr(cos_theta, mie_g)
    if f > 0:
        out += f * rayleigh_sr(cos_theta)
    return out


def sample_hg_cos(xi: np.ndarray, g: float) -> np.ndarray:
    """cos θ of Henyey-Greenstein scattering by inverting its cumulative distribution.

    ``xi`` are uniform deviates in [0, 1). For ``g`` near 0 the distribution is
    isotropic and the closed form loses precision, so it is sampled directly.
    """
    if abs(g) < 1e-6:
        return 2.0 * xi - 1.0
    frac = (1.0 - g * g) / (1.0 - g + 2.0 * g * xi)
    return np.clip((1.0 + g * g - frac * frac) / (2.0 * g), -1.0, 1.0)


def sample_rayleigh_cos(xi: np.ndarray) -> np.ndarray:
    """cos θ of Rayleigh scattering, density (3/8)(1 + cos²θ) on [-1, 1].

    The cumulative distribution is (μ³ + 3μ + 4) / 8; with z = 4ξ - 2 the cubic
    μ³ + 3μ - 2z = 0 has the single real root given by Cardano's formula.
    """
    z = 4.0 * xi - 2.0
    root = np.sqrt(z * z + 1.0)
    return np.clip(np.cbrt(z + root) + np.cbrt(z - root), -1.0, 1.0)


def sample_mixed_cos(rng: np.random.Generator, n: int, mie_g: float, rayleigh_fraction: float) -> np.ndarray:
    """cos θ of one scattering each for ``n`` photons: Rayleigh with probability ``rayleigh_fraction``."""
    xi = rng.random(n)
    mu = sample_hg_cos(xi, mie_g)
    if rayleigh_fraction > 0:
        is_ray = rng.random(n) < rayleigh_fraction
        if np.any(is_ray):
            mu[is_ray] = sample_rayleigh_cos(xi[is_ray])
    return mu


def random_unit_vectors(rng: np.random.Generator, n: int) -> np.ndarray:
    """``n`` directions uniform on the unit sphere."""
    mu = 2.0 * rng.random(n) - 1.0
    phi = 2.0 * np.pi * rng.random(n)
    s = np.sqrt(np.maximum(1.0 - mu * mu, 0.0))
    return np.column_stack([s * np.cos(phi), s * np.sin(phi), mu])


def rotate(direction: np.ndarray, cos_theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Turn each unit vector by polar angle θ (given as cos θ) and azimuth φ around itself.

    The usual Monte Carlo rotation formulas; directions within 1e-6 of the
    z axis use the axis frame directly, where the general formula divides by
    zero.
    """
    ux, uy, uz = direction[:, 0], direction[:, 1], direction[:, 2]
    st = np.sqrt(np.maximum(1.0 - cos_theta * cos_theta, 0.0))
    cp, sp = np.cos(phi), np.sin(phi)
    den2 = 1.0 - uz * uz
    polar = den2 < 1e-12
    den = np.sqrt(np.where(polar, 1.0, den2))
    out = np.empty_like(direction)
    out[:, 0] = st * (ux * uz * cp - uy * sp) / den + ux * cos_theta
    out[:, 1] = st * (uy * uz * cp + ux * sp) / den + uy * cos_theta
    out[:, 2] = -st * cp * den + uz * cos_theta
    if np.any(polar):
        sign = np.sign(uz[polar])
        out[polar, 0] = st[polar] * cp[polar]
        out[polar, 1] = st[polar] * sp[polar]
        out[polar, 2] = sign * cos_theta[polar]
    out /= np.linalg.norm(out, axis=1)[:, None]
    return out


def segment_hits_sphere(
    start: np.ndarray, direction: np.ndarray, length: np.ndarray, radius: float
) -> np.ndarray:
    """True where the segment ``start + t·direction``, 0 < t < length, passes through the sphere.

    The sphere (the LEM) sits at the origin. Starting points are outside it;
    the segment is blocked when its closest approach to the centre lies within
    the segment and inside the radius.
    """
    t_star = np.clip(-np.einsum("ij,ij->i", start, direction), 0.0, length)
    closest = start + t_star[:, None] * direction
    return np.einsum("ij,ij->i", closest, closest) < radius * radius
