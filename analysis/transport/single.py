"""The once-scattered light by quadrature: the noise-free first order of the templates.

The first-order radiance a camera sees at angle ψ is a line integral (see
`analysis.transport.reference.single_scatter_radiance`)::

    L₁(ψ) = ∫ ds/λ_sca e^(-s/λ_att) G(x(s))     G(x) = ∫_cap p(Θ) e^(-|x - y|/λ_att) dω

The inner integral over the LEM's apparent cap depends on the point x only
through its distance r from the LEM's centre and the angle γ between the
outward radial direction and the direction from x to the camera. It is
tabulated once per phase function (`CapTable`), with the first two moments
of the path |x - y| from the surface, so absorption and scattering lengths
are applied afterwards like the Monte Carlo's path moments. This is the
exact expectation of the Monte Carlo's first-order estimate, without its
noise; the Monte Carlo keeps the higher orders.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import RegularGridInterpolator
from scipy.special import roots_legendre

from analysis.transport.proposals import cap_solid_angle_sr
from analysis.transport.sampling import mixed_phase_sr
from analysis.transport.scene import TransportScene, emission_shares
from analysis.transport.tally import PathMoments

#: The array fields of a `CapTable` (what a cache stores).
CAP_TABLE_ARRAYS = ("log_h", "gamma", "mean_phase", "excess", "spread", "dir_par", "dir_perp")


@dataclass(frozen=True)
class CapTable:
    """Phase function averaged over the LEM's apparent cap, with the path moments.

    Tabulated on ``q = log(r/a - 1)`` (the height above the LEM's surface in
    radii, log-spaced: the cap changes fastest close to the surface; r up to
    ``r_max_m``) and γ in [0, π]:

    * ``mean_phase``: (1/Ω) ∫_cap p(Θ) dω, the cap-averaged phase function
      per sr (it tends to p(γ) far away, so it interpolates smoothly);
    * ``excess``: (⟨|x - y|⟩ - (r - a)) / a, the mean path from the surface
      beyond the shortest one, in LEM radii;
    * ``spread``: var(|x - y|) / a²;
    * ``dir_par``, ``dir_perp``: the phase-weighted mean direction of the
      arriving light, along the outward radial direction and along the
      perpendicular in the plane that holds the direction to the camera
      (the emission profile is linear in the light's direction, see
      `analysis.transport.scene.N_COMPONENTS`).

    Beyond ``r_max_m`` the cap is a point: p(γ), path r - a... in the limit.
    """

    lem_radius_m: float
    mie_g: float
    rayleigh_fraction: float
    log_h: np.ndarray = field(repr=False)
    gamma: np.ndarray = field(repr=False)
    mean_phase: np.ndarray = field(repr=False)
    excess: np.ndarray = field(repr=False)
    spread: np.ndarray = field(repr=False)
    dir_par: np.ndarray = field(repr=False)
    dir_perp: np.ndarray = field(repr=False)

    def lookup(
        self, r_m: np.ndarray, gamma_rad: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Cap-integrated phase G (per unit LEM radiance), mean and variance of the path from
        the surface, and the mean light direction (radial and perpendicular parts)."""
        a = self.lem_radius_m
        r = np.maximum(r_m, a * (1.0 + 1e-9))
        lh = np.clip(np.log(r / a - 1.0), self.log_h[0], self.log_h[-1])
        pts = np.column_stack([lh.ravel(), np.clip(gamma_rad, 0.0, math.pi).ravel()])
        stacked = np.stack([self.mean_phase, self.excess, self.spread, self.dir_par, self.dir_perp], axis=-1)
        values = RegularGridInterpolator(
            (self.log_h, self.gamma), stacked, method="linear", bounds_error=False, fill_value=None
        )(pts)
        mean_phase, excess, spread, dir_par, dir_perp = (values[:, i].reshape(r.shape) for i in range(5))
        far = r > a * (1.0 + math.exp(self.log_h[-1]))
        if np.any(far):
            mean_phase = np.where(
                far, mixed_phase_sr(np.cos(gamma_rad), self.mie_g, self.rayleigh_fraction), mean_phase
            )
            dir_par = np.where(far, 1.0, dir_par)
            dir_perp = np.where(far, 0.0, dir_perp)
        omega = cap_solid_angle_sr(a, r)
        return mean_phase * omega, (r - a) + a * excess, a * a * spread, dir_par, dir_perp


def gamma_grid() -> np.ndarray:
    """γ nodes: dense below 0.4 rad, where the Mie forward peak and small caps give structure."""
    return np.concatenate([np.linspace(0.0, 0.4, 161), np.linspace(0.4, math.pi, 111)[1:]])


def build_cap_table(
    lem_radius_m: float,
    mie_g: float,
    rayleigh_fraction: float,
    *,
    r_max_m: float = 400.0,
    n_r: int = 160,
    n_beta: int = 40,
    n_phi: int = 48,
) -> CapTable:
    """Tabulate the cap integrals by Gauss-Legendre quadrature over the cap.

    The cap seen from distance r is the cone of half-angle α = asin(a/r)
    around the outward radial direction (the directions the LEM's light
    arrives from). In the cone's frame a direction at polar angle β and
    azimuth φ makes cos Θ = cos β cos γ + sin β sin γ cos φ with the
    direction to the camera, and comes from a surface point at distance
    r cos β - sqrt(a² - r² sin² β). Nodes: ``n_beta`` in β on [0, α]
    (weight sin β), ``n_phi`` in φ on [0, π] (the integrand is even in φ).
    """
    a = lem_radius_m
    log_h = np.linspace(math.log(1e-3), math.log(r_max_m / a - 1.0), n_r)
    gamma = gamma_grid()
    bn, bw = roots_legendre(n_beta)
    pn, pw = roots_legendre(n_phi)
    phi = 0.5 * math.pi * (pn + 1.0)
    w_phi = 0.5 * math.pi * pw * 2.0  # [0, π] doubled for the even integrand
    cos_phi = np.cos(phi)
    cg, sg = np.cos(gamma), np.sin(gamma)
    shape = (len(log_h), len(gamma))
    mean_phase, excess, spread = np.empty(shape), np.empty(shape), np.empty(shape)
    dir_par, dir_perp = np.empty(shape), np.empty(shape)
    for i, lh in enumerate(log_h):
        r = a * (1.0 + math.exp(lh))
        alpha = math.asin(min(a / r, 1.0))
        beta = 0.5 * alpha * (bn + 1.0)
        w_beta = 0.5 * alpha * bw * np.sin(beta)
        dist = r * np.cos(beta) - np.sqrt(np.maximum(a * a - (r * np.sin(beta)) ** 2, 0.0))
        cos_theta = (
            np.cos(beta)[None, :, None] * cg[:, None, None]
            + (np.sin(beta)[None, :, None] * sg[:, None, None]) * cos_phi[None, None, :]
        )
        phase = mixed_phase_sr(cos_theta, mie_g, rayleigh_fraction)
        p = phase @ w_phi  # (γ, β)
        p_perp = phase @ (w_phi * cos_phi)
        g0 = p @ w_beta
        g1 = p @ (w_beta * dist)
        g2 = p @ (w_beta * dist * dist)
        omega = 2.0 * math.pi * (1.0 - math.cos(alpha))
        mean_phase[i] = g0 / omega
        d1 = g1 / g0
        excess[i] = (d1 - (r - a)) / a
        spread[i] = np.maximum(g2 / g0 - d1 * d1, 0.0) / (a * a)
        dir_par[i] = (p @ (w_beta * np.cos(beta))) / g0
        dir_perp[i] = (p_perp @ (w_beta * np.sin(beta))) / g0
    return CapTable(a, mie_g, rayleigh_fraction, log_h, gamma, mean_phase, excess, spread, dir_par, dir_perp)


@dataclass(frozen=True)
class FirstOrderLines:
    """Quadrature nodes of the first-order radiance of every band of every camera.

    For camera c, emission component k and band i, node j of the
    line-of-sight quadrature carries the weight ``weight[c, k, i, j]`` (ds ×
    cap integral G, per unit LEM radiance and per 1/λ_sca, split between the
    components by the light's mean direction), and the light's path from the LEM's surface to
    the camera has mean ``path_m`` and variance ``spread_m2``. The radiance
    at scattering length λ and absorption length λ_abs is
    ``Σ_j weight · exp(-path/λ_att) / λ`` (to second order in the spread),
    averaged over the band.
    """

    weight: np.ndarray = field(repr=False)
    path_m: np.ndarray = field(repr=False)
    spread_m2: np.ndarray = field(repr=False)


def first_order_lines(
    scene: TransportScene, table: CapTable, *, n_line: int = 192, path_max_m: float = 400.0
) -> FirstOrderLines:
    """Line-of-sight quadrature nodes for each band, two radii per band.

    Each band is averaged over its annulus by two Gauss points in r² (the
    area measure). Along each line the substitution s = s₀ + w·sinh(t), with
    s₀ the foot of the perpendicular from the LEM's centre and w its
    distance (at least a/20), packs the nodes where the line passes the
    LEM. Lines that hit the LEM end at its surface; the others run to
    ``path_max_m``.
    """
    a = scene.lem_radius_m
    gp, gw = roots_legendre(2)
    un, uw = roots_legendre(n_line)
    out_w, out_l, out_v = [], [], []
    for cam in scene.cameras:
        edges = np.asarray(scene.band_edges_px)
        r2 = 0.5 * (edges[1:] ** 2 - edges[:-1] ** 2)[:, None] * (gp[None, :] + 1.0) + edges[:-1, None] ** 2
        psi = np.arctan(np.sqrt(r2) / cam.focal_px)  # (band, 2)
        big_l = cam.distance_m
        s0 = big_l * np.cos(psi)
        d_min = big_l * np.sin(psi)
        hit = d_min < a
        s_end = np.where(hit, s0 - np.sqrt(np.maximum(a * a - d_min * d_min, 0.0)), path_max_m)
        width = np.maximum(d_min, 0.05 * a)
        t0 = np.arcsinh((0.0 - s0) / width)
        t1 = np.arcsinh((s_end - s0) / width)
        t = 0.5 * (t1 - t0)[..., None] * (un + 1.0) + t0[..., None]
        s = s0[..., None] + width[..., None] * np.sinh(t)
        ds = width[..., None] * np.cosh(t) * 0.5 * (t1 - t0)[..., None] * uw
        # Camera at z = side·L looking back toward the LEM; the line leaves it at angle ψ.
        z = cam.side * (big_l - s * np.cos(psi)[..., None])
        rho = s * np.sin(psi)[..., None]
        r = np.hypot(rho, z)
        # γ: angle between the outward radial direction and the direction back to the camera.
        back_z = cam.side * np.cos(psi)[..., None]
        back_rho = -np.sin(psi)[..., None]
        cos_gamma = np.clip((rho * back_rho + z * back_z) / r, -1.0, 1.0)
        gamma = np.arccos(cos_gamma)
        g, dist, var, d_par, d_perp = table.lookup(r, gamma)
        # z-cosine of the mean light direction: radial part along x/r, perpendicular part along
        # the unit vector in the (radial, to-camera) plane, e = (back - cos γ radial) / sin γ.
        sin_gamma = np.sin(gamma)
        e_z = np.where(sin_gamma > 1e-9, (back_z - cos_gamma * z / r) / np.maximum(sin_gamma, 1e-9), 0.0)
        mu = np.clip(d_par * z / r + d_perp * e_z, -1.0, 1.0)
        w = ds * g * 0.5 * gw[None, :, None]  # band average of the two radii
        n_band = psi.shape[0]
        s0, s1 = emission_shares(mu, scene.emission_shape)
        out_w.append(np.stack([(s0 * w).reshape(n_band, -1), (s1 * w).reshape(n_band, -1)]))
        out_l.append((s + dist).reshape(n_band, -1))
        out_v.append(var.reshape(n_band, -1))
    return FirstOrderLines(np.stack(out_w), np.stack(out_l), np.stack(out_v))


def bin_first_order(lines: FirstOrderLines, path_edges_m: np.ndarray, distances_m: np.ndarray) -> PathMoments:
    """The quadrature nodes summed into path bins (excess over ``distance - a``) per camera,
    component and band, as `PathMoments` with zero variance: the form the Monte Carlo's
    tallies take, so both are reweighted the same way."""
    n_cam, n_comp, n_band, _ = lines.weight.shape
    n_path = len(path_edges_m) - 1
    excess = np.maximum(lines.path_m - distances_m[:, None, None], 0.0)
    pbin = np.minimum(np.searchsorted(path_edges_m, excess, side="right") - 1, n_path - 1)
    cell = (np.arange(n_cam)[:, None, None] * n_band + np.arange(n_band)[None, :, None]) * n_path + pbin
    sums = []
    for k in range(n_comp):
        w = lines.weight[:, k]
        parts = [w, w * lines.path_m, w * (lines.path_m**2 + lines.spread_m2)]
        sums.append(
            [np.bincount(cell.ravel(), weights=p.ravel(), minlength=n_cam * n_band * n_path) for p in parts]
        )
    shape = (n_cam, n_band, n_path)
    s0, s1, s2 = (np.stack([sums[k][i].reshape(shape) for k in range(n_comp)], axis=1) for i in range(3))
    return PathMoments.from_sums(s0, s1, s2, np.zeros_like(s0))


def first_order_radiance(lines: FirstOrderLines, lambda_sca_m: float, lambda_abs_m: float) -> np.ndarray:
    """Once-scattered radiance per camera, component and band (LEM radiance 1), from the nodes."""
    k = 1.0 / lambda_sca_m + 1.0 / lambda_abs_m
    factor = np.exp(-k * lines.path_m) * (1.0 + 0.5 * k * k * lines.spread_m2)
    return (lines.weight * factor[:, None]).sum(axis=-1) / lambda_sca_m
