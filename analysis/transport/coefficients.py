"""The refined model's path coefficients (paper, appendix B): L̄₁ = c₁R, L̄₂ = c₂R.

A point source at the centre of a sphere of radius R emits isotropically.
Photons that scatter exactly once inside the sphere and then leave it travel
L₁ = x + y (x to the scattering point, y from there to the sphere); those
that scatter twice travel L₂ = x + y + z. Their mean paths, weighted by the
probability of each path, define c₁ = L̄₁/R and c₂ = L̄₂/R::

    L̄₁ = ∫dx ∫dμ L₁ P / ∫dx ∫dμ P,   P = [β_mie(μ)/λ_mie + β_ray(μ)/λ_ray] e^(-L₁/λ_sca)

with the phase functions per unit μ = cos θ (β_mie Henyey-Greenstein with
⟨cos θ⟩ = g, β_ray = 3/8 (1 + μ²)), and the analogous five-fold integral for
L̄₂ (x, μ₁, y up to the sphere, μ₂, azimuth φ). `c1_coefficient` and
`c2_coefficient` integrate them by Gauss-Legendre quadrature (scipy's
nodes); `sphere_paths_mc` simulates the same process with the transport's
samplers, as the independent check.

Integrating the Mie term in its cumulative probability ξ (μ = μ_HG(ξ),
β_mie dμ = dξ) turns the sharp forward peak (g = 0.9) into a smooth
integrand; the Rayleigh term is smooth in μ itself.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import roots_legendre

from analysis.transport.sampling import rotate, sample_hg_cos, sample_rayleigh_cos


@dataclass(frozen=True)
class ScatteringMix:
    """Mie and Rayleigh scattering lengths and the Mie ⟨cos θ⟩."""

    lambda_mie_m: float
    lambda_ray_m: float
    mie_g: float

    def __post_init__(self) -> None:
        if not (self.lambda_mie_m > 0 and self.lambda_ray_m > 0):
            raise ValueError(
                f"lambda_mie_m and lambda_ray_m must be > 0, got {self.lambda_mie_m}, {self.lambda_ray_m}"
            )
        if not -1 < self.mie_g < 1:
            raise ValueError(f"mie_g must lie in (-1, 1), got {self.mie_g}")

    @property
    def lambda_sca_m(self) -> float:
        return 1.0 / (1.0 / self.lambda_mie_m + 1.0 / self.lambda_ray_m)

    @property
    def rayleigh_fraction(self) -> float:
        return self.lambda_sca_m / self.lambda_ray_m


def _phase_nodes(mix: ScatteringMix, n_mie: int, n_ray: int) -> tuple[np.ndarray, np.ndarray]:
    """Nodes μ and weights w with Σ w f(μ) ≈ ∫ [β_mie/λ_mie + β_ray/λ_ray] f(μ) dμ."""
    xm, wm = roots_legendre(n_mie)
    xi = 0.5 * (xm + 1.0)
    mu_mie = sample_hg_cos(xi, mix.mie_g)
    w_mie = 0.5 * wm / mix.lambda_mie_m
    mu_ray, wr = roots_legendre(n_ray)
    w_ray = wr * 0.375 * (1.0 + mu_ray**2) / mix.lambda_ray_m
    return np.concatenate([mu_mie, mu_ray]), np.concatenate([w_mie, w_ray])


def _to_sphere(pos_along: np.ndarray, pos_sq: np.ndarray, radius_m: float) -> np.ndarray:
    """Distance from a point inside the sphere to its surface along a direction.

    ``pos_along`` is the point's position projected on the direction and
    ``pos_sq`` its squared distance from the centre.
    """
    return -pos_along + np.sqrt(np.maximum(pos_along**2 - pos_sq + radius_m**2, 0.0))


def c1_coefficient(radius_m: float, mix: ScatteringMix, *, n_x: int = 48, n_mu: int = 64) -> float:
    """c₁ = L̄₁/R by Gauss-Legendre quadrature over x in [0, R] and the scattering angle."""
    if not radius_m > 0:
        raise ValueError(f"radius_m must be > 0, got {radius_m}")
    xn, xw = roots_legendre(n_x)
    x = 0.5 * radius_m * (xn + 1.0)
    wx = 0.5 * radius_m * xw
    mu, wmu = _phase_nodes(mix, n_mu, max(n_mu // 2, 8))
    y = _to_sphere(x[:, None] * mu[None, :], (x * x)[:, None], radius_m)
    path = x[:, None] + y
    p = wx[:, None] * wmu[None, :] * np.exp(-path / mix.lambda_sca_m)
    return float((p * path).sum() / p.sum() / radius_m)


def c2_coefficient(
    radius_m: float,
    mix: ScatteringMix,
    *,
    n_x: int = 16,
    n_mu: int = 24,
    n_y: int = 16,
    n_phi: int = 12,
) -> float:
    """c₂ = L̄₂/R by Gauss-Legendre quadrature over the five variables of two scatterings.

    The first scattering is at x on the z axis, turning the photon by θ₁
    (μ₁ = cos θ₁) into d₁ = (sin θ₁, 0, cos θ₁); the second at distance y
    along d₁ (y from 0 to the sphere, as a fraction of that distance), turning
    by θ₂ with azimuth φ around d₁; z is the distance from there to the
    sphere. The integrand is even in φ, so φ runs over [0, π] with doubled
    weights.
    """
    if not radius_m > 0:
        raise ValueError(f"radius_m must be > 0, got {radius_m}")
    big_r, lam = radius_m, mix.lambda_sca_m
    xn, xw = roots_legendre(n_x)
    x = 0.5 * big_r * (xn + 1.0)
    wx = 0.5 * big_r * xw
    mu, wmu = _phase_nodes(mix, n_mu, max(n_mu // 2, 8))
    vn, vw = roots_legendre(n_y)
    v = 0.5 * (vn + 1.0)
    wv = 0.5 * vw
    pn, pw = roots_legendre(n_phi)
    phi = 0.5 * math.pi * (pn + 1.0)
    wphi = math.pi * pw  # [0, π], doubled
    num = den = 0.0
    s1 = np.sqrt(np.maximum(1.0 - mu * mu, 0.0))
    for xi, wxi in zip(x, wx, strict=True):
        # First scattering at (0, 0, xi); y runs to the sphere along d1.
        f = _to_sphere(xi * mu, xi * xi, big_r)  # (mu1,)
        y = f[:, None] * v[None, :]  # (mu1, y)
        wy = f[:, None] * wv[None, :]
        px = (y * s1[:, None])[..., None, None]  # p2 = (y sinθ1, 0, xi + y cosθ1)
        pz = (xi + y * mu[:, None])[..., None, None]
        # d2 = cosθ2 d1 + sinθ2 (cosφ e1 + sinφ e2), e1 = (cosθ1, 0, -sinθ1), e2 = (0, 1, 0)
        c2 = mu[None, None, :, None]
        s2 = s1[None, None, :, None]
        cphi = np.cos(phi)[None, None, None, :]
        c1 = mu[:, None, None, None]
        sn1 = s1[:, None, None, None]
        d2x = c2 * sn1 + s2 * cphi * c1
        d2z = c2 * c1 - s2 * cphi * sn1
        along = px * d2x + pz * d2z
        z = _to_sphere(along, px * px + pz * pz, big_r)
        path = xi + y[..., None, None] + z
        w = (
            wxi
            * wmu[:, None, None, None]
            * wy[..., None, None]
            * wmu[None, None, :, None]
            * wphi[None, None, None, :]
            * np.exp(-path / lam)
        )
        num += float((w * path).sum())
        den += float(w.sum())
    return num / den / big_r


@dataclass(frozen=True)
class SpherePaths:
    """Monte Carlo mean paths of once- and twice-scattered photons reaching radius R."""

    radius_m: float
    c1: float
    c1_err: float
    n1: int
    c2: float
    c2_err: float
    n2: int
    n_photons: int
    seed: int


def sphere_paths_mc(radius_m: float, mix: ScatteringMix, n_photons: int, seed: int = 0) -> SpherePaths:
    """Simulate the appendix-B process and measure c₁, c₂ with their statistical errors.

    Analogue photons start at the centre along +z (the source is isotropic
    and the detector a sphere, so one direction stands for all), fly
    exponential paths of mean λ_sca and scatter by Mie or Rayleigh in
    proportion to 1/λ_mie and 1/λ_ray, with the transport's samplers. A
    photon whose next flight would cross the sphere is recorded with its
    order and total path; after two scatterings inside it is dropped.
    """
    if n_photons < 10:
        raise ValueError(f"n_photons must be >= 10, got {n_photons}")
    rng = np.random.default_rng(seed)
    lam, big_r = mix.lambda_sca_m, radius_m
    f_ray = mix.rayleigh_fraction
    pos = np.zeros((n_photons, 3))
    direction = np.tile([0.0, 0.0, 1.0], (n_photons, 1))
    path = np.zeros(n_photons)
    out: dict[int, np.ndarray] = {}
    for order in range(3):
        along = np.einsum("ij,ij->i", pos, direction)
        exit_dist = _to_sphere(along, np.einsum("ij,ij->i", pos, pos), big_r)
        flight = rng.exponential(lam, len(path))
        leaves = flight >= exit_dist
        out[order] = path[leaves] + exit_dist[leaves]
        stay = ~leaves
        pos = pos[stay] + flight[stay, None] * direction[stay]
        path = path[stay] + flight[stay]
        direction = direction[stay]
        n = len(path)
        xi = rng.random(n)
        mu = sample_hg_cos(xi, mix.mie_g)
        ray = rng.random(n) < f_ray
        mu[ray] = sample_rayleigh_cos(xi[ray])
        direction = rotate(direction, mu, 2.0 * np.pi * rng.random(n))

    def mean_err(values: np.ndarray) -> tuple[float, float]:
        if len(values) < 2:
            return float("nan"), float("nan")
        return float(values.mean() / big_r), float(values.std(ddof=1) / math.sqrt(len(values)) / big_r)

    c1, e1 = mean_err(out[1])
    c2, e2 = mean_err(out[2])
    return SpherePaths(radius_m, c1, e1, len(out[1]), c2, e2, len(out[2]), n_photons, seed)
