"""Vectorised Monte Carlo of the LEM's light in water, seen by pinhole cameras.

What is simulated
-----------------
The LEM is a sphere of radius ``a`` glowing like a Lambertian surface of
radiance B₀ = 1 (templates are radiances in units of the LEM's surface
radiance). Photons leave its surface, fly exponential free paths of mean
λ_sca, scatter with the Mie (Henyey-Greenstein) + Rayleigh phase function and
are lost if they fly back into the LEM. Absorption is left out of the
sampling: it multiplies a photon's weight by ``exp(-path / λ_abs)``, so the
tallies keep the path lengths and any λ_abs is applied afterwards
(`analysis.transport.templates`).

Variance reduction
------------------
A pinhole camera 20-40 m away sees a cone of ~1° around the LEM; almost no
analogue photon ends in it. Two estimators make the images cheap:

* **next-event estimation** (the point-detector estimator): at every
  scattering vertex the photon sends the camera its expected flux
  ``w · p(Θ) · exp(-d/λ_sca) / d²`` (Θ between its direction and the
  direction to the camera, d the distance), binned by the angle ψ at which
  the camera sees the vertex. Radiance per band = flux / band solid angle.
* **vertices forced into each camera's cone** (multiple importance
  sampling): each flight is drawn either the natural way (probability
  ``natural_fraction``) or with the new vertex placed in the cone a camera
  sees, uniformly in ψ and along the axis. The photon's weight becomes
  ``p_natural / Σ_s q_s p_s`` (balance heuristic over all strategies), which
  keeps the estimate unbiased and cancels the 1/d² of the point detector for
  vertices close to a camera: its variance stays finite.
* **flights guided toward a camera** (the same balance heuristic): from the
  second flight on, a share ``guided_fraction`` flies the natural free path
  in a direction drawn from the Mie forward peak around the direction to a
  camera. Light scattered twice or more at small angles on its way to a
  camera needs consecutive vertices nearly in line with it; cone vertices,
  drawn without regard to where the photon came from, line up only rarely,
  and the few that do carried the higher orders' heavy tail (a turbid halo's
  second order at 10-30 % per 8-px bin with 10⁶ photons, and a seed's
  realisation 2-5 % off Mitsuba's with errors that did not cover it).

The direct (unscattered) light is tallied separately as order 0 from
uniformly drawn surface points.

Tallies are kept per camera, emission component, scattering order, angular band and
excess-path bin, as sums of w, w·ℓ, w·ℓ² and w² (ℓ = total path). Per-band
statistical errors use Σw² (contributions of one photon's different
vertices rarely share a one-pixel band, so their correlation is neglected).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from analysis.scattering import henyey_greenstein_sr
from analysis.transport.sampling import (
    mixed_phase_sr,
    random_unit_vectors,
    rotate,
    sample_hg_cos,
    sample_mixed_cos,
    segment_hits_sphere,
)
from analysis.transport.scene import (
    CameraSite,
    ScatteringMedium,
    TransportConfig,
    TransportScene,
    emission_shares,
)

#: Mixture of the axial position in the cone proposal: ∝ 1/t² beyond the forward peak,
#: uniform on [0, L], log-uniform on [a, L].
_AXIS_SHARES = (0.5, 0.25, 0.25)
#: Independent groups of batches whose scatter measures the higher orders' error.
N_GROUPS = 16
#: Share of forced first vertices whose emission point is uniform over the visible cap (rest: guided).
_CAP_UNIFORM_SHARE = 0.5
#: Share of cone-proposal angles drawn uniformly over the fine bands (the rest over the outer bins).
_INNER_PSI_SHARE = 0.75


@dataclass(frozen=True)
class ConeProposal:
    """A density that places vertices in the cone a camera sees.

    The angle ψ at which the camera sees the point is drawn uniformly on
    [0, ψ_inner] (equal counts per one-pixel band) or, with weight
    ``1 - _INNER_PSI_SHARE``, log-uniformly on [ψ_inner, ψ_outer]; the
    azimuth uniformly. Then the distance ``t`` from the LEM's centre along
    the axis: light scattered at ``t`` reaches the camera at ψ after turning
    by Θ ≈ ψL/t, and the Mie phase function is flat for Θ below ~(1 - g) and
    falls steeply beyond, so the once-scattered radiance gathers along the
    line of sight with density ∝ 1/t² from ``t₀ = ψL/(1 - g)`` on. Half of
    the points follow that, a quarter are uniform on [0, L] and a quarter
    log-uniform on [a, L] (wide-angle and Rayleigh scattering near the LEM).
    ``pdf`` is the density per unit volume.
    """

    camera: CameraSite
    lem_radius_m: float
    psi_inner_rad: float
    psi_outer_rad: float
    forward_width_rad: float = 0.07

    @property
    def _has_outer(self) -> bool:
        return self.psi_outer_rad > self.psi_inner_rad * 1.0001

    def _t0(self, psi: np.ndarray) -> np.ndarray:
        big_l = self.camera.distance_m
        return np.clip(psi * big_l / self.forward_width_rad, self.lem_radius_m, 0.5 * big_l)

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        big_l, a = self.camera.distance_m, self.lem_radius_m
        xi = rng.random(n)
        if self._has_outer:
            inner = rng.random(n) < _INNER_PSI_SHARE
            psi = np.where(
                inner,
                self.psi_inner_rad * xi,
                self.psi_inner_rad * (self.psi_outer_rad / self.psi_inner_rad) ** xi,
            )
        else:
            psi = self.psi_outer_rad * xi
        t0 = self._t0(psi)
        xi = rng.random(n)
        pick = rng.random(n)
        inv = 1.0 / (1.0 / t0 - xi * (1.0 / t0 - 1.0 / big_l))
        t = np.where(
            pick < _AXIS_SHARES[0],
            inv,
            np.where(pick < _AXIS_SHARES[0] + _AXIS_SHARES[1], big_l * xi, a * (big_l / a) ** xi),
        )
        u = big_l - t
        b = u * np.tan(psi)
        phi = 2.0 * np.pi * rng.random(n)
        return np.column_stack([b * np.cos(phi), b * np.sin(phi), self.camera.side * t])

    def pdf(self, x: np.ndarray) -> np.ndarray:
        big_l, a = self.camera.distance_m, self.lem_radius_m
        t = self.camera.side * x[:, 2]
        u = big_l - t
        b = np.hypot(x[:, 0], x[:, 1])
        ok = (t >= 0) & (u > 0)
        t_safe = np.where(ok, t, 1.0)
        u_safe = np.where(ok, u, 1.0)
        psi = np.arctan2(b, u_safe)
        t0 = self._t0(psi)
        p_t = (
            _AXIS_SHARES[0]
            * np.where(t_safe >= t0, 1.0 / (np.maximum(t_safe, t0) ** 2 * (1.0 / t0 - 1.0 / big_l)), 0.0)
            + _AXIS_SHARES[1] / big_l
            + _AXIS_SHARES[2]
            * np.where(t_safe >= a, 1.0 / (np.maximum(t_safe, a) * math.log(big_l / a)), 0.0)
        )
        if self._has_outer:
            span = math.log(self.psi_outer_rad / self.psi_inner_rad)
            p_psi = np.where(
                psi < self.psi_inner_rad,
                _INNER_PSI_SHARE / self.psi_inner_rad,
                np.where(
                    psi < self.psi_outer_rad,
                    (1.0 - _INNER_PSI_SHARE) / (np.maximum(psi, 1e-300) * span),
                    0.0,
                ),
            )
        else:
            p_psi = np.where(psi < self.psi_outer_rad, 1.0 / self.psi_outer_rad, 0.0)
        b_safe = np.maximum(b, 1e-300)
        dpsi_db = u_safe / (u_safe * u_safe + b_safe * b_safe)
        return np.where(ok, p_t * p_psi * dpsi_db / (2.0 * np.pi * b_safe), 0.0)


@dataclass(frozen=True)
class TransportTally:
    """The binned result of one transport run.

    Arrays have shape ``(camera, component, order, band, path_bin)`` (see
    `analysis.transport.scene.N_COMPONENTS` for the two emission components);
    ``order`` 0 is the direct light, ``k`` the light scattered ``k`` times.
    ``sum_w`` is the radiance-weighted flux (in units of the LEM's surface
    radiance times sr), ``sum_wl`` and ``sum_wl2`` its first two path
    moments, ``sum_w2`` the sum of squared contributions (for errors). The
    path ℓ is the total path from the LEM's surface to the camera.
    ``group_w`` holds Σw of the orders >= 2 per independent group of
    batches, shape ``(group, camera, component, band)``: the scatter between
    groups measures the error where a few rare, heavy contributions make
    Σw² an underestimate.
    """

    scene: TransportScene
    medium: ScatteringMedium
    config: TransportConfig
    seed: int
    sum_w: np.ndarray = field(repr=False)
    sum_wl: np.ndarray = field(repr=False)
    sum_wl2: np.ndarray = field(repr=False)
    sum_w2: np.ndarray = field(repr=False)
    path_edges_m: np.ndarray = field(repr=False)
    group_w: np.ndarray = field(repr=False)

    def radiance(
        self, lambda_abs_m: float = math.inf, orders: slice | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Radiance per camera and band (uniform LEM, B₀ = 1) and its statistical error.

        Applies absorption ``exp(-ℓ / lambda_abs_m)`` at the simulated
        scattering length. ``orders`` selects scattering orders (default:
        the scattered light, orders >= 1).
        """
        sel = slice(1, None) if orders is None else orders
        k = 0.0 if math.isinf(lambda_abs_m) else 1.0 / lambda_abs_m
        value, var = path_reweight(self.sum_w, self.sum_wl, self.sum_wl2, self.sum_w2, k)
        value = value[:, :, sel].sum(axis=(1, 2))
        var = var[:, :, sel].sum(axis=(1, 2))
        omega = np.stack([self.scene.band_solid_angle_sr(c) for c in range(len(self.scene.cameras))])
        return value / omega, np.sqrt(var) / omega


def path_reweight(
    sum_w: np.ndarray, sum_wl: np.ndarray, sum_wl2: np.ndarray, sum_w2: np.ndarray, k_per_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """Σ w·exp(-k ℓ) and its variance from per-bin path moments, summed over path bins.

    Within a bin the factor is expanded around the mean path:
    exp(-k ℓ̄)(1 + k² var(ℓ)/2), exact to second order in the bin's spread.
    Used for absorption (k = 1/λ_abs) and for moving to another scattering
    length (k gains 1/λ - 1/λ₀).
    """
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(sum_w != 0, sum_wl / sum_w, 0.0)
        spread = np.where(sum_w != 0, np.maximum(sum_wl2 / sum_w - mean * mean, 0.0), 0.0)
    factor = np.exp(-k_per_m * mean)
    value = (sum_w * factor * (1.0 + 0.5 * k_per_m * k_per_m * spread)).sum(axis=-1)
    var = (sum_w2 * factor * factor * (1.0 + 2.0 * k_per_m * k_per_m * spread)).sum(axis=-1)
    return value, var


@dataclass(frozen=True)
class PathMoments:
    """Per-bin path moments in sparse form, for fast reweighting by exp(-k ℓ).

    ``index`` maps each non-empty bin to a cell of an output array of shape
    ``out_shape`` (the path bins are summed over). `reweight` applies the
    second-order expansion of `path_reweight` with one `numpy.bincount`.
    """

    out_shape: tuple[int, ...]
    index: np.ndarray = field(repr=False)
    weight: np.ndarray = field(repr=False)
    mean_m: np.ndarray = field(repr=False)
    spread_m2: np.ndarray = field(repr=False)
    weight2: np.ndarray = field(repr=False)

    @classmethod
    def from_sums(
        cls, sum_w: np.ndarray, sum_wl: np.ndarray, sum_wl2: np.ndarray, sum_w2: np.ndarray
    ) -> PathMoments:
        """From sums with the path bins on the last axis."""
        out_shape = sum_w.shape[:-1]
        n_path = sum_w.shape[-1]
        nz = np.flatnonzero(sum_w.ravel() != 0)
        w = sum_w.ravel()[nz]
        mean = sum_wl.ravel()[nz] / w
        spread = np.maximum(sum_wl2.ravel()[nz] / w - mean * mean, 0.0)
        return cls(out_shape, nz // n_path, w, mean, spread, sum_w2.ravel()[nz])

    def reweight(self, k_per_m: float) -> tuple[np.ndarray, np.ndarray]:
        """Σ w·exp(-k ℓ) and its variance per output cell."""
        factor = np.exp(-k_per_m * self.mean_m)
        k2 = k_per_m * k_per_m
        size = int(np.prod(self.out_shape))
        value = np.bincount(
            self.index, weights=self.weight * factor * (1.0 + 0.5 * k2 * self.spread_m2), minlength=size
        )
        var = np.bincount(
            self.index,
            weights=self.weight2 * factor * factor * (1.0 + 2.0 * k2 * self.spread_m2),
            minlength=size,
        )
        return value.reshape(self.out_shape), var.reshape(self.out_shape)


class _Accumulator:
    """Sums of w, w·ℓ, w·ℓ², w² over flat bins (camera, emission bin, order, band, path bin)."""

    def __init__(self, scene: TransportScene, config: TransportConfig) -> None:
        self.scene = scene
        self.shape = (
            len(scene.cameras),
            scene.n_components,
            config.max_order + 1,
            scene.n_bands,
            config.n_path_bins,
        )
        size = int(np.prod(self.shape))
        self.size = size
        self.sums = np.zeros((4, size))
        self.n_groups = max(1, min(N_GROUPS, -(-config.n_photons // config.batch_size)))
        self.group_w = np.zeros((self.n_groups, self.shape[0], self.shape[1], self.shape[3]))
        self.group = 0
        self.edges_px = np.asarray(scene.band_edges_px)
        self.path_edges = config.path_edges_m()

    def add(
        self,
        camera: int,
        emission_mu: np.ndarray,
        order: int,
        r_px: np.ndarray,
        path_m: np.ndarray,
        value: np.ndarray,
    ) -> None:
        """Add contributions seen at image radius ``r_px`` after total path ``path_m``.

        ``emission_mu`` is the z-cosine of each photon's emission direction:
        the contribution is split between the two emission components by
        the scene's emission shape (`analysis.transport.scene.emission_shares`).
        """
        band = np.searchsorted(self.edges_px, r_px, side="right") - 1
        keep = (band >= 0) & (band < self.shape[3]) & (value > 0)
        if not np.any(keep):
            return
        band, path, value, mu = band[keep], path_m[keep], value[keep], emission_mu[keep]
        cam = self.scene.cameras[camera]
        excess = np.maximum(path - (cam.distance_m - self.scene.lem_radius_m), 0.0)
        pbin = np.minimum(np.searchsorted(self.path_edges, excess, side="right") - 1, self.shape[4] - 1)
        _, n_comp, n_ord, n_band, n_path = self.shape
        for comp, share in enumerate(emission_shares(mu, self.scene.emission_shape)):
            v = value * share
            flat = (((camera * n_comp + comp) * n_ord + order) * n_band + band) * n_path + pbin
            for i, weights in enumerate((v, v * path, v * path * path, v * v)):
                self.sums[i] += np.bincount(flat, weights=weights, minlength=self.size)
            if order >= 2:
                self.group_w[self.group, camera, comp] += np.bincount(band, weights=v, minlength=n_band)[
                    :n_band
                ]

    def arrays(self) -> list[np.ndarray]:
        return [s.reshape(self.shape) for s in self.sums]


def _camera_view(cam: CameraSite, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Image radius (px) at which a camera sees each point, and whether it is in front of it."""
    u = cam.distance_m - cam.side * x[:, 2]
    b = np.hypot(x[:, 0], x[:, 1])
    in_front = u > 0
    r_px = np.where(in_front, cam.focal_px * b / np.where(in_front, u, 1.0), np.inf)
    return r_px, in_front


def run_transport(
    scene: TransportScene,
    medium: ScatteringMedium,
    config: TransportConfig,
    seed: int = 0,
) -> TransportTally:
    """Simulate ``config.n_photons`` photons from the LEM and tally what each camera sees.

    Deterministic for a given ``seed`` (one `numpy.random.Generator` drives
    every batch in turn).
    """
    rng = np.random.default_rng(seed)
    acc = _Accumulator(scene, config)
    proposals = _proposals(scene, medium)
    left = config.n_photons
    i = 0
    while left > 0:
        n = min(config.batch_size, left)
        acc.group = i % acc.n_groups
        _scattered_batch(rng, n, scene, medium, config, proposals, acc)
        left -= n
        i += 1
    left = config.direct_samples
    while left > 0:
        n = min(config.batch_size, left)
        _direct_batch(rng, n, scene, medium, config, acc)
        left -= n
    s0, s1, s2, q = acc.arrays()
    return TransportTally(scene, medium, config, seed, s0, s1, s2, q, acc.path_edges, acc.group_w)


def _proposals(scene: TransportScene, medium: ScatteringMedium) -> list[ConeProposal]:
    width = max(1.0 - medium.mie_g, 0.02)
    out = []
    for i, cam in enumerate(scene.cameras):
        psi = scene.psi_edges_rad(i)
        fine = np.flatnonzero(np.diff(scene.band_edges_px) <= 1.0 + 1e-9)
        inner = psi[fine[-1] + 1] if len(fine) else psi[-1]
        out.append(ConeProposal(cam, scene.lem_radius_m, float(inner), float(psi[-1]), width))
    return out


def _direct_batch(
    rng: np.random.Generator,
    n: int,
    scene: TransportScene,
    medium: ScatteringMedium,
    config: TransportConfig,
    acc: _Accumulator,
) -> None:
    """Unscattered light: surface points drawn uniformly, each seen along its straight line.

    A surface element dA of radiance 1 seen at distance d under an angle θ
    from its normal gives the flux cos θ dA / d²; with points drawn uniformly
    over the sphere's 4πa² each sample carries 4πa²/N of that.
    """
    a = scene.lem_radius_m
    normal = random_unit_vectors(rng, n)
    y = a * normal
    scale = 4.0 * math.pi * a * a / config.direct_samples
    for c, cam in enumerate(scene.cameras):
        v = np.array([0.0, 0.0, cam.z_m]) - y
        d = np.linalg.norm(v, axis=1)
        cos_y = np.einsum("ij,ij->i", normal, v) / d
        value = np.where(cos_y > 0, scale * cos_y * np.exp(-d / medium.lambda_sca_m) / (d * d), 0.0)
        r_px, _ = _camera_view(cam, y)
        acc.add(c, v[:, 2] / d, 0, r_px, d, value)


def _scattered_batch(
    rng: np.random.Generator,
    n: int,
    scene: TransportScene,
    medium: ScatteringMedium,
    config: TransportConfig,
    proposals: list[ConeProposal],
    acc: _Accumulator,
) -> None:
    """Follow ``n`` photons from their first scattering vertex to ``max_order``."""
    a = scene.lem_radius_m
    lam = medium.lambda_sca_m
    q_nat = config.natural_fraction
    n_cones = len(proposals)
    q_cone = (1.0 - q_nat) / n_cones  # the first flight: natural or forced
    q_guided = config.guided_fraction  # later flights: natural, forced or guided
    q_next = (1.0 - q_nat - q_guided) / n_cones
    q_guide = q_guided / n_cones
    guide_g = max(medium.mie_g, 0.0)
    packet = 4.0 * math.pi**2 * a * a / config.n_photons  # power of one photon, LEM radiance 1

    # --- first vertex: emission point y and first scattering point x, drawn jointly.
    strategy = _strategies(rng, n, q_nat, len(proposals))
    x = np.empty((n, 3))
    y = np.empty((n, 3))
    direction = np.empty((n, 3))
    nat = strategy == 0
    m = int(nat.sum())
    if m:
        normal = random_unit_vectors(rng, m)
        mu = np.sqrt(rng.random(m))  # Lambertian: cos θ distributed as sqrt(ξ)
        d_nat = rotate(normal, mu, 2.0 * np.pi * rng.random(m))
        s = rng.exponential(lam, m)
        y[nat] = a * normal
        direction[nat] = d_nat
        x[nat] = a * normal + s[:, None] * d_nat
    for c, prop in enumerate(proposals):
        sel = strategy == c + 1
        m = int(sel.sum())
        if not m:
            continue
        xc = prop.sample(rng, m)
        yc, toward, hit = _emission_point_for(rng, xc, prop.camera, a, medium.mie_g)
        x[sel] = np.where(hit[:, None], xc, np.nan)
        y[sel] = yc
        direction[sel] = -toward
    seg = x - y
    s = np.linalg.norm(seg, axis=1)
    r = np.linalg.norm(x, axis=1)
    valid = np.isfinite(r) & (r > a * (1.0 + 1e-9)) & np.isfinite(s)
    r = np.where(valid, r, 2.0 * a)
    s = np.where(valid, s, 1.0)
    x_safe = np.where(valid[:, None], x, 0.0)
    dir_safe = np.where(valid[:, None], direction, np.array([0.0, 0.0, 1.0]))
    omega_cap = cap_solid_angle_sr(a, r)
    natural = np.exp(-s / lam) / (4.0 * math.pi**2 * a * a * lam)
    mix = q_nat * natural
    for prop in proposals:
        to_cam = np.array([0.0, 0.0, prop.camera.z_m]) - x_safe
        to_cam /= np.linalg.norm(to_cam, axis=1)[:, None]
        guided = henyey_greenstein_sr(np.einsum("ij,ij->i", dir_safe, to_cam), medium.mie_g)
        q_dir = _CAP_UNIFORM_SHARE / omega_cap + (1.0 - _CAP_UNIFORM_SHARE) * guided
        mix = mix + q_cone * prop.pdf(x_safe) * q_dir
    weight = np.where(valid, natural / np.maximum(mix, 1e-300), 0.0)
    emission_mu = direction[:, 2].copy()
    path = s
    order = 1
    live = weight > 0
    x, direction, weight, path = x[live], direction[live], weight[live], path[live]
    emission_mu = emission_mu[live]

    while len(weight):
        # --- next-event estimate toward each camera from this vertex.
        for c, cam in enumerate(scene.cameras):
            r_px, in_front = _camera_view(cam, x)
            near = in_front & (r_px < acc.edges_px[-1])
            if not np.any(near):
                continue
            xv, dv = x[near], direction[near]
            v = np.array([0.0, 0.0, cam.z_m]) - xv
            d = np.linalg.norm(v, axis=1)
            to_cam = v / d[:, None]
            cos_theta = np.einsum("ij,ij->i", dv, to_cam)
            blocked = segment_hits_sphere(xv, to_cam, d, a)
            phase = mixed_phase_sr(cos_theta, medium.mie_g, medium.rayleigh_fraction)
            value = np.where(blocked, 0.0, packet * weight[near] * phase * np.exp(-d / lam) / (d * d))
            acc.add(c, emission_mu[near], order, r_px[near], path[near] + d, value)
        if order >= config.max_order:
            break
        # --- next flight: natural, forced into one camera's cone, or guided toward a camera.
        n_live = len(weight)
        strategy = _strategies(rng, n_live, q_nat, n_cones, q_guided)
        new_x = np.empty_like(x)
        nat = strategy == 0
        m = int(nat.sum())
        if m:
            mu = sample_mixed_cos(rng, m, medium.mie_g, medium.rayleigh_fraction)
            d_new = rotate(direction[nat], mu, 2.0 * np.pi * rng.random(m))
            new_x[nat] = x[nat] + rng.exponential(lam, m)[:, None] * d_new
        for c, prop in enumerate(proposals):
            sel = strategy == c + 1
            m = int(sel.sum())
            if m:
                new_x[sel] = prop.sample(rng, m)
            sel = strategy == n_cones + c + 1
            m = int(sel.sum())
            if m:
                aim = _unit_toward(prop.camera, x[sel])
                d_new = rotate(aim, sample_hg_cos(rng.random(m), guide_g), 2.0 * np.pi * rng.random(m))
                new_x[sel] = x[sel] + rng.exponential(lam, m)[:, None] * d_new
        step = new_x - x
        s = np.linalg.norm(step, axis=1)
        s_safe = np.maximum(s, 1e-12)
        new_dir = step / s_safe[:, None]
        blocked = segment_hits_sphere(x, new_dir, s_safe, a) | (np.linalg.norm(new_x, axis=1) <= a)
        cos_theta = np.einsum("ij,ij->i", direction, new_dir)
        natural = (
            mixed_phase_sr(cos_theta, medium.mie_g, medium.rayleigh_fraction)
            * np.exp(-s_safe / lam)
            / (lam * s_safe * s_safe)
        )
        mix = q_nat * natural
        free_path = np.exp(-s_safe / lam) / (lam * s_safe * s_safe)
        for prop in proposals:
            mix = mix + q_next * prop.pdf(new_x)
            if q_guide > 0:
                aim = _unit_toward(prop.camera, x)
                guided = henyey_greenstein_sr(np.einsum("ij,ij->i", new_dir, aim), guide_g)
                mix = mix + q_guide * guided * free_path
        weight = np.where(blocked, 0.0, weight * natural / np.maximum(mix, 1e-300))
        path = path + s
        order += 1
        live = (weight > 0) & (path < config.path_max_m)
        x, direction, weight, path = new_x[live], new_dir[live], weight[live], path[live]
        emission_mu = emission_mu[live]


def cap_solid_angle_sr(radius_m: float, distance_m: np.ndarray) -> np.ndarray:
    """Solid angle of a sphere of radius a seen from distance r: 2π(1 - cos α), sin α = a/r.

    Written as 2π (a/r)² / (1 + cos α), which keeps its precision far away,
    where 1 - cos α would cancel to zero.
    """
    s2 = np.minimum((radius_m / np.asarray(distance_m)) ** 2, 1.0)
    return 2.0 * np.pi * s2 / (1.0 + np.sqrt(1.0 - s2))


def _emission_point_for(
    rng: np.random.Generator, x: np.ndarray, camera: CameraSite, a: float, mie_g: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Surface points lighting the forced vertices ``x``: the LEM point each photon came from.

    Half are uniform over the sphere's apparent cap seen from x; half follow
    the Mie forward peak: the light's direction is drawn from the
    Henyey-Greenstein distribution around the direction from x to the
    camera, and traced back to the sphere (misses are wasted). Near the LEM
    the cap is wide and only its part that shines almost straight toward the
    camera matters; the guided half finds it. Returns the points, the unit
    vectors from x toward them and whether the draw is usable.
    """
    m = len(x)
    r = np.linalg.norm(x, axis=1)
    outside = r > a * (1.0 + 1e-9)
    r_safe = np.where(outside, r, 2.0 * a)
    x_safe = np.where(outside[:, None], x, np.array([0.0, 0.0, 2.0 * a]))
    cos_alpha = np.sqrt(np.maximum(1.0 - (a / r_safe) ** 2, 0.0))
    toward = np.empty((m, 3))
    uniform = rng.random(m) < _CAP_UNIFORM_SHARE
    k = int(uniform.sum())
    if k:
        cos_beta = cos_alpha[uniform] + (1.0 - cos_alpha[uniform]) * rng.random(k)
        axis = -x_safe[uniform] / r_safe[uniform, None]
        toward[uniform] = rotate(axis, cos_beta, 2.0 * np.pi * rng.random(k))
    g = ~uniform
    k = m - int(uniform.sum())
    if k:
        to_cam = np.array([0.0, 0.0, camera.z_m]) - x_safe[g]
        to_cam /= np.linalg.norm(to_cam, axis=1)[:, None]
        light = rotate(to_cam, sample_hg_cos(rng.random(k), mie_g), 2.0 * np.pi * rng.random(k))
        toward[g] = -light
    # Nearest intersection of x + t·toward with the sphere.
    b = np.einsum("ij,ij->i", x_safe, toward)
    disc = b * b - (r_safe * r_safe - a * a)
    hit = outside & (disc >= 0) & (b < 0)
    t = -b - np.sqrt(np.maximum(disc, 0.0))
    y = x_safe + t[:, None] * toward
    return y, toward, hit


def _strategies(
    rng: np.random.Generator, n: int, q_nat: float, n_cones: int, q_guided: float = 0.0
) -> np.ndarray:
    """0 for a natural flight, ``c + 1`` for one forced into camera ``c``'s cone, ``n_cones + c + 1``
    for one guided toward camera ``c`` (a share ``q_guided`` of all flights)."""
    xi = rng.random(n)
    out = np.zeros(n, dtype=np.int64)
    q_forced = 1.0 - q_nat - q_guided
    if q_forced > 0:
        cone = (xi >= q_nat) & (xi < q_nat + q_forced)
        out[cone] = 1 + np.minimum(((xi[cone] - q_nat) / q_forced * n_cones).astype(np.int64), n_cones - 1)
    if q_guided > 0:
        guided = xi >= q_nat + q_forced
        out[guided] = (
            1
            + n_cones
            + np.minimum(((xi[guided] - q_nat - q_forced) / q_guided * n_cones).astype(np.int64), n_cones - 1)
        )
    return out


def _unit_toward(camera: CameraSite, x: np.ndarray) -> np.ndarray:
    """Unit vectors from the points ``x`` toward the camera."""
    v = np.array([0.0, 0.0, camera.z_m]) - x
    return v / np.maximum(np.linalg.norm(v, axis=1), 1e-300)[:, None]
