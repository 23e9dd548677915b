"""Halo templates over λ_abs, λ_sca and ⟨cos θ⟩, built from the transport and cached on disk.

A template is the scattered-light radiance each camera sees, per image band,
in units of the LEM's surface radiance toward the near camera, for one water.
It is assembled from two pieces:

* the **first order** by quadrature (`analysis.transport.single`): computed
  once per ⟨cos θ⟩, exact for any λ_abs and λ_sca;
* the **higher orders** by Monte Carlo (`analysis.transport.engine`), run once
  per grid node (λ_sca, ⟨cos θ⟩). Absorption is applied exactly from the
  recorded path moments, for any λ_abs. A photon history with n scatterings
  and path ℓ has probability ∝ λ^-n exp(-ℓ/λ), so the same histories serve a
  neighbouring scattering length λ with the weight (λ₀/λ)^n
  exp(-ℓ(1/λ - 1/λ₀)); between two nodes both estimates are blended
  linearly in log λ (each is unbiased, so the blend is too).

⟨cos θ⟩ is interpolated linearly between its nodes. The direct disk is not
part of a template: it is analytic (`analysis.transport.disk`).

The refractive index is recorded with the templates but enters nothing here:
for a steady source only the arrival *time* of light depends on it, and the
camera's in-water angular scale is already its focal length in pixels.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Executor
from dataclasses import dataclass, field
from functools import partial

import numpy as np

from analysis.transport.cache import TemplateCache, cache_key
from analysis.transport.engine import run_transport, run_transport_reweighted
from analysis.transport.scene import (
    LEM_RADIUS_M,
    ScatteringMedium,
)
from analysis.transport.single import (
    CAP_TABLE_ARRAYS,
    CapTable,
    FirstOrderLines,
    bin_first_order,
    build_cap_table,
    first_order_lines,
)
from analysis.transport.tally import PathMoments
from analysis.transport.template_settings import (
    EmissionProfile,
    HaloTemplate,
    TemplateCamera,
    TemplateSettings,
    band_centres_px,
)

#: How far beyond the outermost nodes the scattering length may be reweighted (factor).
REWEIGHT_REACH = 1.5


@dataclass(frozen=True)
class _MCNode:
    """Orders >= 2 of one Monte Carlo node, as sparse path moments per (camera, component, order, bin)."""

    lambda_sca_m: float
    mie_g: float
    moments: PathMoments = field(repr=False)
    variance_factor: np.ndarray = field(repr=False)  # per camera and Monte Carlo bin, >= 1


@dataclass(frozen=True)
class TemplateGrid:
    """The cached pieces of one `TemplateSettings`, evaluated at any water inside the grid."""

    settings: TemplateSettings
    first: Mapping[float, PathMoments] = field(repr=False)
    nodes: Mapping[tuple[float, float], _MCNode] = field(repr=False)
    _coarse_to_fine: np.ndarray = field(repr=False)
    _coarse_omega: np.ndarray = field(repr=False)

    @property
    def lambda_sca_range_m(self) -> tuple[float, float]:
        """Scattering lengths the grid can serve (the nodes, reweighted by `REWEIGHT_REACH` beyond)."""
        nodes = self.settings.lambda_sca_nodes_m
        return nodes[0] / REWEIGHT_REACH, nodes[-1] * REWEIGHT_REACH

    @property
    def phase_ranges(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """The (Mie ⟨cos θ⟩, Rayleigh share) ranges the grid serves: its ⟨cos θ⟩ nodes, its one share."""
        s = self.settings
        return (s.mie_g_nodes[0], s.mie_g_nodes[-1]), (s.rayleigh_fraction, s.rayleigh_fraction)

    def halo(
        self,
        lambda_abs_m: float,
        lambda_sca_m: float,
        mie_g: float | None = None,
        rayleigh_share: float | None = None,
    ) -> HaloTemplate:
        """The scattered-light template at one water.

        Raises `ValueError` naming the parameter when it lies outside the grid
        (a grid holds one Rayleigh share: another raises).
        """
        s = self.settings
        if rayleigh_share is not None and abs(rayleigh_share - s.rayleigh_fraction) > 1e-9:
            raise ValueError(
                f"rayleigh_share {rayleigh_share:g}: these templates hold only {s.rayleigh_fraction:g}"
            )
        g = s.mie_g_nodes[0] if mie_g is None else float(mie_g)
        if not lambda_abs_m > 0:
            raise ValueError(f"lambda_abs_m must be > 0, got {lambda_abs_m}")
        lo, hi = self.lambda_sca_range_m
        if not lo * (1 - 1e-9) <= lambda_sca_m <= hi * (1 + 1e-9):
            raise ValueError(
                f"lambda_sca_m {lambda_sca_m:.4g} m outside the template grid [{lo:.4g}, {hi:.4g}] m"
            )
        lambda_sca_m = min(max(lambda_sca_m, lo), hi)
        g_lo, g_hi, tg = _bracket(s.mie_g_nodes, g, log=False, name="mie_g")
        value, var = self._at_g(g_lo, lambda_abs_m, lambda_sca_m)
        if tg > 0:
            v2, var2 = self._at_g(g_hi, lambda_abs_m, lambda_sca_m)
            value = (1 - tg) * value + tg * v2
            var = (1 - tg) ** 2 * var + tg**2 * var2
        return HaloTemplate(lambda_abs_m, lambda_sca_m, g, value, np.sqrt(var))

    def halo_at_psi(
        self,
        psi_rad: np.ndarray,
        camera: int,
        lambda_abs_m: float,
        lambda_sca_m: float,
        mie_g: float | None,
        emission: EmissionProfile,
    ) -> np.ndarray:
        """One camera's scattered-light radiance at angles ``psi_rad`` (interpolated between bands).

        Band values sit at the bands' area centroids; ψ beyond the last band
        raises `ValueError` (build the grid with ``outer_px`` to cover a frame).
        """
        psi = np.asarray(psi_rad, dtype=np.float64)
        edges = np.asarray(self.settings.scene().band_edges_px)
        reach = math.atan(edges[-1] / self.settings.focal_px)
        if psi.size and float(psi.max()) > reach * (1 + 1e-9):
            raise ValueError(
                f"psi_rad reaches {float(psi.max()):.4g} rad but the templates' bands end at "
                f"{edges[-1]:.0f} px ({reach:.4g} rad); build them with a larger outer_px"
            )
        value, _ = self.halo(lambda_abs_m, lambda_sca_m, mie_g).total(emission)
        return np.interp(psi, np.arctan(band_centres_px(edges) / self.settings.focal_px), value[camera])

    def higher_orders(
        self, lambda_abs_m: float, lambda_sca_m: float, mie_g: float | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """The Monte Carlo part (orders >= 2) on the Monte Carlo's own bins: radiance and variance
        per camera, component and bin (before interpolation onto the bands)."""
        g = self.settings.mie_g_nodes[0] if mie_g is None else float(mie_g)
        nodes = self.settings.lambda_sca_nodes_m
        clipped = min(max(lambda_sca_m, nodes[0]), nodes[-1])
        l_lo, l_hi, t = _bracket(nodes, clipped, log=True, name="lambda_sca_m")
        value, var = self._higher(self.nodes[(g, l_lo)], lambda_abs_m, lambda_sca_m)
        if t > 0:
            v2, var2 = self._higher(self.nodes[(g, l_hi)], lambda_abs_m, lambda_sca_m)
            value = (1 - t) * value + t * v2
            var = (1 - t) ** 2 * var + t**2 * var2
        return value, var

    def camera_index(self, distance_m: float, side: int) -> int:
        """The index of the grid's camera at ``distance_m`` on ``side``; `ValueError` if none."""
        for i, c in enumerate(self.settings.cameras):
            if c.side == side and abs(c.distance_m - distance_m) < 1e-6:
                return i
        have = ", ".join(f"{c.distance_m} m side {c.side:+d}" for c in self.settings.cameras)
        raise ValueError(f"no template camera at {distance_m} m on side {side:+d} (templates have: {have})")

    def _at_g(self, g: float, lambda_abs_m: float, lambda_sca_m: float) -> tuple[np.ndarray, np.ndarray]:
        first, _ = self.first[g].reweight(1.0 / lambda_sca_m + 1.0 / lambda_abs_m)
        first = first / lambda_sca_m
        higher, var = self.higher_orders(lambda_abs_m, lambda_sca_m, g)
        fine = np.einsum("fj,ckj->ckf", self._coarse_to_fine, higher)
        fine_var = np.einsum("fj,ckj->ckf", self._coarse_to_fine**2, var)
        return first + fine, fine_var

    def _higher(
        self, node: _MCNode, lambda_abs_m: float, lambda_sca_m: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Orders >= 2 of one MC node, moved to (λ_abs, λ_sca): radiance and variance per coarse bin."""
        lam0 = node.lambda_sca_m
        k = 1.0 / lambda_abs_m + 1.0 / lambda_sca_m - 1.0 / lam0
        value, var = node.moments.reweight(k)
        orders = np.arange(2, 2 + value.shape[2])
        factor = (lam0 / lambda_sca_m) ** orders
        value = np.einsum("ckob,o->ckb", value, factor) / self._coarse_omega[:, None, :]
        var = np.einsum("ckob,o->ckb", var, factor * factor) / self._coarse_omega[:, None, :] ** 2
        var = var * node.variance_factor[:, None, :]
        return value, var


def _bracket(nodes: Sequence[float], x: float, *, log: bool, name: str) -> tuple[float, float, float]:
    """The nodes around ``x`` and the interpolation fraction (0 at the lower node)."""
    if len(nodes) == 1 or x <= nodes[0]:
        if x < nodes[0] * (1 - 1e-9) and not log:
            raise ValueError(f"{name} {x} outside the template nodes {tuple(nodes)}")
        return nodes[0], nodes[0], 0.0
    if x >= nodes[-1]:
        if x > nodes[-1] * (1 + 1e-9) and not log:
            raise ValueError(f"{name} {x} outside the template nodes {tuple(nodes)}")
        return nodes[-1], nodes[-1], 0.0
    j = int(np.searchsorted(nodes, x, side="right")) - 1
    lo, hi = nodes[j], nodes[j + 1]
    t = math.log(x / lo) / math.log(hi / lo) if log else (x - lo) / (hi - lo)
    return lo, hi, float(t)


def _coarse_to_fine_matrix(settings: TemplateSettings) -> tuple[np.ndarray, np.ndarray]:
    """Linear interpolation from the MC bins' centres to the bands' centres, and the MC bins' solid angles."""
    fine = np.asarray(settings.scene().band_edges_px)
    mc_scene = settings.mc_scene()
    coarse = np.asarray(mc_scene.band_edges_px)

    cf, cc = band_centres_px(fine), band_centres_px(coarse)
    mat = np.zeros((len(cf), len(cc)))
    for i, r in enumerate(cf):
        j = int(np.clip(np.searchsorted(cc, r) - 1, 0, len(cc) - 2))
        t = float(np.clip((r - cc[j]) / (cc[j + 1] - cc[j]), 0.0, 1.0))
        mat[i, j] += 1 - t
        mat[i, j + 1] += t
    omega = np.stack([mc_scene.band_solid_angle_sr(c) for c in range(len(settings.cameras))])
    return mat, omega


def cached_cap_table(
    lem_radius_m: float, mie_g: float, rayleigh_fraction: float, r_max_m: float, cache: TemplateCache
) -> CapTable:
    """The cap table of one phase function (`build_cap_table`), cached on its own: all geometries share it."""
    desc = {
        "lem_radius_m": lem_radius_m,
        "mie_g": mie_g,
        "rayleigh_fraction": rayleigh_fraction,
        "r_max_m": r_max_m,
    }

    def compute() -> dict[str, np.ndarray]:
        t = build_cap_table(lem_radius_m, mie_g, rayleigh_fraction, r_max_m=r_max_m)
        return {k: getattr(t, k) for k in CAP_TABLE_ARRAYS}

    arr = cache.get(cache_key("cap-table", desc), desc, compute)
    return CapTable(lem_radius_m, mie_g, rayleigh_fraction, **{k: arr[k] for k in CAP_TABLE_ARRAYS})


def _lines_piece(settings: TemplateSettings, g: float, cache: TemplateCache) -> dict[str, np.ndarray]:
    table = cached_cap_table(settings.lem_radius_m, g, settings.rayleigh_fraction, settings.path_max_m, cache)
    lines = first_order_lines(settings.scene(), table, path_max_m=settings.path_max_m)
    return {"weight": lines.weight, "path_m": lines.path_m, "spread_m2": lines.spread_m2}


def _node_seed(settings: TemplateSettings, lambda_sca_m: float, g: float) -> int:
    seq = np.random.SeedSequence([settings.seed, round(lambda_sca_m * 1000), round((g + 1) * 1e6)])
    return int(seq.generate_state(1, dtype=np.uint64)[0])


def _mc_piece(args: tuple[TemplateSettings, float, tuple[float, ...]]) -> list[dict[str, np.ndarray]]:
    """The Monte Carlo of one scattering-length node for the ⟨cos θ⟩ values ``gs``: a run each, or one
    run reweighted to all of them (``settings.mc_phase``)."""
    settings, lam, gs = args
    r = settings.rayleigh_fraction
    if settings.mc_phase is None:
        tallies = [
            run_transport(
                settings.mc_scene(),
                ScatteringMedium(lam, g, r),
                settings.mc_config(),
                seed=_node_seed(settings, lam, g),
            )
            for g in gs
        ]
    else:
        g0, r0 = settings.mc_phase
        tallies = run_transport_reweighted(
            settings.mc_scene(),
            ScatteringMedium(lam, g0, r0),
            settings.mc_config(),
            [ScatteringMedium(lam, g, r) for g in gs],
            seed=_node_seed(settings, lam, g0),
        )
    return [
        {
            "sum_w": t.sum_w,
            "sum_wl": t.sum_wl,
            "sum_wl2": t.sum_wl2,
            "sum_w2": t.sum_w2,
            "group_w": t.group_w,
        }
        for t in tallies
    ]


def build_template_grid(
    settings: TemplateSettings,
    cache: TemplateCache | None = None,
    *,
    executor: Executor | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> TemplateGrid:
    """Load the grid's pieces from the cache, computing the missing ones (on ``executor`` if given).

    The caller owns the executor (the command line passes its one worker
    pool, `camcal.core.parallel.process_pool`); without one the pieces are
    computed here, one after the other.

    Each Monte Carlo node has its own seed derived from ``settings.seed`` and
    the node, so the grid is the same whatever the number of workers and
    whichever pieces were cached before.
    """
    cache = cache or TemplateCache()
    geo = settings.geometry_description()
    total = len(settings.mie_g_nodes) * (1 + len(settings.lambda_sca_nodes_m))
    done = 0
    first: dict[float, PathMoments] = {}
    path_edges = settings.mc_config().path_edges_m()
    dist = np.array([c.distance_m - settings.lem_radius_m for c in settings.cameras])
    for g in settings.mie_g_nodes:
        desc = {"geometry": geo, "mie_g": g, "path_max_m": settings.path_max_m}
        arr = cache.get(cache_key("first-order", desc), desc, partial(_lines_piece, settings, g, cache))
        lines = FirstOrderLines(arr["weight"], arr["path_m"], arr["spread_m2"])
        first[g] = bin_first_order(lines, path_edges, dist)
        done += 1
        if progress:
            progress(done, total)
    wanted: dict[tuple[float, float], tuple[str, dict[str, object]]] = {}
    nodes: dict[tuple[float, float], _MCNode] = {}
    for g in settings.mie_g_nodes:
        for lam in settings.lambda_sca_nodes_m:
            desc = {
                "geometry": geo,
                "mie_g": g,
                "lambda_sca_m": lam,
                "seed": settings.seed,
                "n_photons": settings.n_photons,
                "max_order": settings.max_order,
                "path_max_m": settings.path_max_m,
            }
            if settings.mc_phase is not None:
                desc["mc_phase"] = list(settings.mc_phase)
            key = cache_key("higher-orders", desc)
            found = cache.load(key)
            if found is None:
                wanted[(g, lam)] = (key, desc)
                continue
            nodes[(g, lam)] = _node(lam, g, found)
            done += 1
            if progress:
                progress(done, total)
    jobs: list[tuple[TemplateSettings, float, tuple[float, ...]]]
    if settings.mc_phase is None:
        jobs = [(settings, lam, (g,)) for (g, lam) in wanted]
    else:  # one run per scattering length serves every ⟨cos θ⟩ node
        lams = sorted({lam for _, lam in wanted})
        jobs = [(settings, lam, tuple(g for (g, x) in wanted if x == lam)) for lam in lams]
    if executor is not None and len(jobs) > 1:
        results = executor.map(_mc_piece, jobs)
        for job, arrays in zip(jobs, results, strict=True):
            done = _store(cache, wanted, nodes, job, arrays, done, total, progress)
    else:
        for job in jobs:
            done = _store(cache, wanted, nodes, job, _mc_piece(job), done, total, progress)
    mat, omega = _coarse_to_fine_matrix(settings)
    return TemplateGrid(settings, first, nodes, mat, omega)


def _node(lam: float, g: float, arrays: Mapping[str, np.ndarray]) -> _MCNode:
    parts = (arrays[k][:, :, 2:] for k in ("sum_w", "sum_wl", "sum_wl2", "sum_w2"))
    return _MCNode(
        lam, g, PathMoments.from_sums(*parts), variance_factor(arrays["sum_w2"], arrays["group_w"])
    )


def variance_factor(sum_w2: np.ndarray, group_w: np.ndarray) -> np.ndarray:
    """Per camera and Monte Carlo bin, how much the scatter between batch groups exceeds Σw².

    Σw² misses the correlation between one photon's contributions and, with
    heavy-tailed weights, the rare large ones a finite run has not met. The
    variance of the total over G independent groups, G·var(group sums), is
    compared with Σw² bin by bin (summed over components). Each bin's errors
    are scaled by the larger of the camera's mean ratio over the bins that
    hold light (the mean, not the median: the rare heavy bins are the point)
    and the bin's own ratio averaged with its two neighbours (16 groups
    measure one bin's variance to ±37 %), never by less than 1. A per-camera
    factor alone left bins whose scatter between independent runs was 2-2.4
    times their error (the near camera in turbid water, next to the disk and
    at its widest bins), which Mitsuba's halo then disagreed with by "5σ".
    """
    n_groups = group_w.shape[0]
    n_cam, n_bin = group_w.shape[1], group_w.shape[3]
    out = np.ones((n_cam, n_bin))
    if n_groups < 4:
        return out
    w2 = sum_w2[:, :, 2:].sum(axis=(1, 2, 4))  # (camera, band)
    totals = group_w.sum(axis=2)  # (group, camera, band)
    between = n_groups * totals.var(axis=0, ddof=1)
    for c in range(n_cam):
        ok = w2[c] > 0
        if np.count_nonzero(ok) >= 3:
            ratio = np.where(ok, between[c] / np.where(ok, w2[c], 1.0), 0.0)
            mean = float(np.mean(ratio[ok]))
            num = np.convolve(ratio, np.ones(3), mode="same")
            den = np.convolve(ok.astype(float), np.ones(3), mode="same")
            local = np.where(den > 0, num / np.maximum(den, 1.0), 0.0)
            out[c] = np.maximum(np.maximum(mean, local), 1.0)
    return out


def _store(
    cache: TemplateCache,
    wanted: Mapping[tuple[float, float], tuple[str, dict[str, object]]],
    nodes: dict[tuple[float, float], _MCNode],
    job: tuple[TemplateSettings, float, tuple[float, ...]],
    pieces: Sequence[Mapping[str, np.ndarray]],
    done: int,
    total: int,
    progress: Callable[[int, int], None] | None,
) -> int:
    _, lam, gs = job
    for g, arrays in zip(gs, pieces, strict=True):
        key, desc = wanted[(g, lam)]
        cache.save(key, arrays, desc)
        nodes[(g, lam)] = _node(lam, g, arrays)
        done += 1
        if progress:
            progress(done, total)
    return done


def default_workers() -> int:
    """Worker processes for building templates: all cores."""
    return os.cpu_count() or 1


def camera_halo(
    psi_rad: np.ndarray,
    distance_m: float,
    side: int,
    focal_px: float,
    lambda_abs_m: float,
    lambda_sca_m: float,
    mie_g: float,
    rayleigh_fraction: float,
    emission: EmissionProfile,
    *,
    lem_radius_m: float = LEM_RADIUS_M,
    refractive_index: float = 1.35,
    n_bands: int = 168,
    n_photons: int = 1_000_000,
    max_order: int = 6,
    mc_band_px: int = 8,
    seed: int = 7,
    cache: TemplateCache | None = None,
) -> np.ndarray:
    """Scattered-light radiance (LEM radiance toward the near camera = 1) at angles ``psi_rad``.

    For one camera at ``distance_m`` on ``side`` (+1: the near side), from
    a one-node template grid at exactly this water (no reweighting), with
    one-pixel bands out to ``n_bands`` px and logarithmic bins beyond, out to
    the largest ψ asked for. Band values are placed at the bands' area
    centroids and interpolated linearly in ψ.
    """
    psi = np.asarray(psi_rad, dtype=np.float64)
    outer = max(float(focal_px * math.tan(float(psi.max()))) * 1.02, n_bands + 8.0)
    settings = TemplateSettings(
        cameras=(TemplateCamera("camera", distance_m, side),),
        focal_px=focal_px,
        n_bands=n_bands,
        outer_px=outer,
        n_outer=48,
        lem_radius_m=lem_radius_m,
        rayleigh_fraction=rayleigh_fraction,
        refractive_index=refractive_index,
        lambda_sca_nodes_m=(float(lambda_sca_m),),
        mie_g_nodes=(float(mie_g),),
        n_photons=n_photons,
        max_order=max_order,
        mc_band_px=mc_band_px,
        seed=seed,
    )
    grid = build_template_grid(settings, cache)
    return grid.halo_at_psi(psi, 0, lambda_abs_m, lambda_sca_m, mie_g, emission)
