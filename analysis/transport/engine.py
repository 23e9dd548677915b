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
from collections.abc import Sequence

import numpy as np

from analysis.scattering import henyey_greenstein_sr
from analysis.transport.proposals import (
    CAP_UNIFORM_SHARE,
    ConeProposal,
    cap_solid_angle_sr,
    emission_point_for,
    strategies,
    unit_toward,
)
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
from analysis.transport.tally import TransportTally

#: Independent groups of batches whose scatter measures the higher orders' error.
N_GROUPS = 16


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
    return run_transport_reweighted(scene, medium, config, [medium], seed)[0]


def run_transport_reweighted(
    scene: TransportScene,
    medium: ScatteringMedium,
    config: TransportConfig,
    targets: Sequence[ScatteringMedium],
    seed: int = 0,
) -> list[TransportTally]:
    """One run sampled in ``medium``, tallied for each of ``targets`` (other phase functions).

    The photons are drawn as in `run_transport` for ``medium``; each target's
    weight takes, at every scattering, the ratio of its phase function to
    the sampling density (the natural part of which is ``medium``'s), and
    its next-event estimates use its own phase function. Each tally is an
    unbiased estimate for its target, and all share the same photons: their
    differences (the halo's change with ⟨cos θ⟩ or the Rayleigh share) carry
    far less Monte Carlo noise than independent runs' would. Targets must
    share ``medium``'s scattering length (reweighting in λ_sca is done
    afterwards from the path moments). A target equal to ``medium`` gives
    exactly `run_transport`'s tally: the random stream does not depend on
    the targets.
    """
    if not targets:
        raise ValueError("targets: at least one phase function to tally")
    for t in targets:
        if t.lambda_sca_m != medium.lambda_sca_m:
            raise ValueError(
                f"target lambda_sca_m {t.lambda_sca_m} differs from the sampled {medium.lambda_sca_m}"
            )
    rng = np.random.default_rng(seed)
    accs = [_Accumulator(scene, config) for _ in targets]
    proposals = _proposals(scene, medium)
    left = config.n_photons
    i = 0
    while left > 0:
        n = min(config.batch_size, left)
        for acc in accs:
            acc.group = i % acc.n_groups
        _scattered_batch(rng, n, scene, medium, config, proposals, accs, targets)
        left -= n
        i += 1
    left = config.direct_samples
    while left > 0:
        n = min(config.batch_size, left)
        _direct_batch(rng, n, scene, medium, config, accs)
        left -= n
    out = []
    for target, acc in zip(targets, accs, strict=True):
        s0, s1, s2, q = acc.arrays()
        out.append(TransportTally(scene, target, config, seed, s0, s1, s2, q, acc.path_edges, acc.group_w))
    return out


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
    accs: Sequence[_Accumulator],
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
        for acc in accs:  # the same for every phase function
            acc.add(c, v[:, 2] / d, 0, r_px, d, value)


def _scattered_batch(
    rng: np.random.Generator,
    n: int,
    scene: TransportScene,
    medium: ScatteringMedium,
    config: TransportConfig,
    proposals: list[ConeProposal],
    accs: Sequence[_Accumulator],
    targets: Sequence[ScatteringMedium],
) -> None:
    """Follow ``n`` photons from their first scattering vertex to ``max_order``.

    Sampled in ``medium``; one weight per target phase function (row of
    ``weights``), tallied into that target's accumulator.
    """
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
    strategy = strategies(rng, n, q_nat, len(proposals))
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
        yc, toward, hit = emission_point_for(rng, xc, prop.camera, a, medium.mie_g)
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
        q_dir = CAP_UNIFORM_SHARE / omega_cap + (1.0 - CAP_UNIFORM_SHARE) * guided
        mix = mix + q_cone * prop.pdf(x_safe) * q_dir
    weight = np.where(valid, natural / np.maximum(mix, 1e-300), 0.0)
    emission_mu = direction[:, 2].copy()
    path = s
    order = 1
    live = weight > 0
    # The first flight does not depend on the phase function: every target starts with this weight.
    weights = np.repeat(weight[live][None], len(targets), axis=0)
    x, direction, path = x[live], direction[live], path[live]
    emission_mu = emission_mu[live]

    while weights.shape[1]:
        # --- next-event estimate toward each camera from this vertex.
        for c, cam in enumerate(scene.cameras):
            r_px, in_front = _camera_view(cam, x)
            near = in_front & (r_px < accs[0].edges_px[-1])
            if not np.any(near):
                continue
            xv, dv = x[near], direction[near]
            v = np.array([0.0, 0.0, cam.z_m]) - xv
            d = np.linalg.norm(v, axis=1)
            to_cam = v / d[:, None]
            cos_theta = np.einsum("ij,ij->i", dv, to_cam)
            blocked = segment_hits_sphere(xv, to_cam, d, a)
            seen = np.where(blocked, 0.0, packet * np.exp(-d / lam) / (d * d))
            for t, (target, acc) in enumerate(zip(targets, accs, strict=True)):
                phase = mixed_phase_sr(cos_theta, target.mie_g, target.rayleigh_fraction)
                value = seen * weights[t, near] * phase
                acc.add(c, emission_mu[near], order, r_px[near], path[near] + d, value)
        if order >= config.max_order:
            break
        # --- next flight: natural, forced into one camera's cone, or guided toward a camera.
        n_live = weights.shape[1]
        strategy = strategies(rng, n_live, q_nat, n_cones, q_guided)
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
                aim = unit_toward(prop.camera, x[sel])
                d_new = rotate(aim, sample_hg_cos(rng.random(m), guide_g), 2.0 * np.pi * rng.random(m))
                new_x[sel] = x[sel] + rng.exponential(lam, m)[:, None] * d_new
        step = new_x - x
        s = np.linalg.norm(step, axis=1)
        s_safe = np.maximum(s, 1e-12)
        new_dir = step / s_safe[:, None]
        blocked = segment_hits_sphere(x, new_dir, s_safe, a) | (np.linalg.norm(new_x, axis=1) <= a)
        cos_theta = np.einsum("ij,ij->i", direction, new_dir)
        free_path = np.exp(-s_safe / lam) / (lam * s_safe * s_safe)
        mix = q_nat * mixed_phase_sr(cos_theta, medium.mie_g, medium.rayleigh_fraction) * free_path
        for prop in proposals:
            mix = mix + q_next * prop.pdf(new_x)
            if q_guide > 0:
                aim = unit_toward(prop.camera, x)
                guided = henyey_greenstein_sr(np.einsum("ij,ij->i", new_dir, aim), guide_g)
                mix = mix + q_guide * guided * free_path
        per_mix = np.where(blocked, 0.0, free_path / np.maximum(mix, 1e-300))
        for t, target in enumerate(targets):
            weights[t] *= mixed_phase_sr(cos_theta, target.mie_g, target.rayleigh_fraction) * per_mix
        path = path + s
        order += 1
        live = (per_mix > 0) & np.any(weights > 0, axis=0) & (path < config.path_max_m)
        x, direction, weights, path = new_x[live], new_dir[live], weights[:, live], path[live]
        emission_mu = emission_mu[live]
