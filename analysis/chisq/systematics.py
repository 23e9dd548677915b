"""The systematic budget: what the fit holds fixed, varied, and the shifts it causes.

The fit holds the phase function (⟨cos θ⟩ and the Rayleigh share) and the
LEM's angular emission shape (linear in the cosine of the emission angle)
fixed; neither the real water nor the real LEM promises them.

The phase function's two parameters are varied *jointly*: the lengths
are refitted on a grid of (⟨cos θ⟩, Rayleigh share) over their ranges, on
templates that share their photons between the grid's cases (one Monte
Carlo run per scattering length, reweighted: `variation_settings`), and
each length's error is its root-mean-square shift from the nominal over a
uniform prior on that box (`marginal_posterior`). If the water's phase
function is a draw from that prior, the pulls of the lengths have an RMS
of one by construction. Varying one parameter at a time (the budget
before) missed their correlated move: in turbid water a ⟨cos θ⟩ below the
nominal with a Rayleigh share away from it shifted λ_abs by 25-35 % where
each alone said ~12 %. The data's own posterior, exp(-Δχ²/2s²) over the
box, is computed and reported in the line's note, but narrows the error
only with ``SystematicsConfig.narrow_by_data``: on independent frames it
pointed away from the truth's phase function in about half the turbid sets
(docs/transport.md). An alternative emission shape counts with its full
shift. The templates' own Monte Carlo sample is varied too: the lengths
refitted on ``template_samples`` grids of other seeds (same nodes and
photons); one sample's error is √(mean shift²/2), since two independent
samples differ by √2 of it (the higher orders of a node carry ~10 % noise
at 4·10⁵ photons, which a few heavy histories spread over many bands: the
per-band template errors inside χ² do not describe it). The values quoted
are then the mean over the nominal and those samples
(`SystematicBudget.sample_move_m`, applied by `ChiSquareFit.with_budget`),
and the line's error that mean's. Their sum in
quadrature, with the templates' accuracy near the limb on λ_sca, is the
systematic error quoted.

The nuisances the fit already floats with a prior (I0'/I0, the PSF width,
the two distances) are listed too, as *impacts*: the shift when the
nuisance is held at nominal ± 1σ instead of floated, against the fit with
it held at nominal. Their error is already inside the fit error, so they
are not added to the systematic error a second time.

Refits start from the nominal minimum and use the same searches as the fit
(`analysis.chisq.fit.Objective.minimise`), without intervals or maps: a few
hundred χ² evaluations each. Alternative templates are needed only at the
scattering-length nodes a refit can reach from the fitted λ_sca
(`variation_settings`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from analysis.attenuation import EmissionRatio
from analysis.chisq.data import SettingProfiles
from analysis.chisq.posterior import marginal_posterior
from analysis.chisq.refit import Refitter
from analysis.chisq.results import (
    DCHI2_2D_68,
    LOWER_LIMIT,
    NUISANCE_FLAG_SIGMA,
    UPPER_LIMIT,
    ChiSquareFit,
    SystematicBudget,
    SystematicShift,
)
from analysis.transport.source import HaloSource
from analysis.transport.templates import TemplateSettings


@dataclass(frozen=True)
class SystematicsConfig:
    """The ranges of the budget's variations.

    ``mie_g_range``: ⟨cos θ⟩ of the Mie part (the paper scanned 0.88-0.96
    around its 0.92-0.93); ``rayleigh_range``: the share of scattering that
    is Rayleigh (~17 % in the deep-sea model). Both are uniform priors,
    fitted jointly with the lengths: refits at ``mie_g_points`` values of
    ⟨cos θ⟩ evenly over its range (and the nominal) times the Rayleigh
    share's two ends and nominal, on templates with ``phase_photon_factor``
    times the fit's photons per node. The error is the RMS shift over the
    priors; ``narrow_by_data`` weighs it by the data's posterior instead
    (not yet trustworthy: see the module). ``emission_shapes``: the alternative
    angular emission shapes of the LEM
    (`analysis.transport.scene.EMISSION_SHAPES`), each counted with its full
    shift. ``template_samples``: independently seeded template grids the
    lengths are refitted on, to measure the templates' own Monte Carlo
    error (0: none).
    """

    mie_g_range: tuple[float, float] = (0.88, 0.96)
    mie_g_points: int = 5
    rayleigh_range: tuple[float, float] = (0.10, 0.25)
    phase_photon_factor: float = 4.0
    narrow_by_data: bool = False
    emission_shapes: tuple[str, ...] = ("hemispheres",)
    template_samples: int = 3

    def __post_init__(self) -> None:
        lo, hi = self.mie_g_range
        if not -1 < lo < hi < 1:
            raise ValueError(f"mie_g_range must be increasing inside (-1, 1), got {self.mie_g_range}")
        if self.mie_g_points < 2:
            raise ValueError(f"mie_g_points must be >= 2, got {self.mie_g_points}")
        lo, hi = self.rayleigh_range
        if not 0 <= lo < hi <= 1:
            raise ValueError(f"rayleigh_range must be increasing inside [0, 1], got {self.rayleigh_range}")
        if not self.phase_photon_factor > 0:
            raise ValueError(f"phase_photon_factor must be > 0, got {self.phase_photon_factor}")
        if self.template_samples < 0:
            raise ValueError(f"template_samples must be >= 0, got {self.template_samples}")

    def mie_g_values(self, nominal: float) -> tuple[float, ...]:
        """The ⟨cos θ⟩ values refitted, the phase templates' nodes: evenly over the range, and the nominal."""
        lo, hi = self.mie_g_range
        return tuple(sorted({*(round(float(g), 4) for g in np.linspace(lo, hi, self.mie_g_points)), nominal}))

    def rayleigh_values(self, nominal: float) -> tuple[float, ...]:
        """The Rayleigh shares refitted: the range's ends and the nominal."""
        return tuple(sorted({*self.rayleigh_range, nominal}))


#: Said of a budget line whose refit ended on the edge of the templates' range.
EDGE_NOTE = "; a refit ended on the templates' edge: the shift is a lower bound (add λ_sca nodes)"


def nodes_around(nodes: Sequence[float], values: Sequence[float]) -> tuple[float, ...]:
    """The scattering-length nodes bracketing each value, with one more node on each side."""
    nodes = sorted(nodes)
    keep: set[float] = set()
    for v in values:
        i = int(np.searchsorted(nodes, v))
        keep.update(nodes[max(i - 2, 0) : min(i + 2, len(nodes))])
    return tuple(sorted(keep))


def nodes_covering(nodes: Sequence[float], lo: float, hi: float) -> tuple[float, ...]:
    """The nodes bracketing [lo, hi], the list extended geometrically beyond its ends where needed.

    An extension continues the outermost spacing (the ratio of the two
    outermost nodes; 1.65 for a single node), so the same nominal nodes and
    range always give the same list, and the templates stay cached.
    """
    ext = sorted(float(x) for x in nodes)
    up = ext[-1] / ext[-2] if len(ext) > 1 else 1.65
    down = ext[1] / ext[0] if len(ext) > 1 else 1.65
    while ext[-1] < hi:
        ext.append(round(ext[-1] * up, 3))
    while ext[0] > lo:
        ext.insert(0, round(ext[0] / down, 3))
    i = int(np.searchsorted(ext, lo, side="right")) - 1
    j = int(np.searchsorted(ext, hi, side="left"))
    return tuple(ext[max(i, 0) : j + 1])


#: Margin on the scattering lengths a phase refit can reach (the Rayleigh share moves them too).
_REACH_MARGIN = 1.15


def variation_settings(
    base: TemplateSettings, lambda_sca_m: Sequence[float], config: SystematicsConfig
) -> dict[str, TemplateSettings]:
    """The template settings each variation needs (around the fitted ``lambda_sca_m`` only).

    Keys: ``"phase:rayleigh=<share>"`` (one per Rayleigh share of
    `SystematicsConfig.rayleigh_values`, with the ⟨cos θ⟩ nodes of
    `SystematicsConfig.mie_g_values`, ``phase_photon_factor`` times the
    photons, all of them one Monte Carlo sample per scattering length drawn
    at the nominal phase function and reweighted (``mc_phase``: the changes
    between the phase-function cases carry little Monte Carlo noise), and
    the scattering-length nodes a refit reaches: the halo's
    width holds λ_sca(1 - ⟨cos θ⟩), so a refit at ⟨cos θ⟩ = g moves λ_sca by
    (1 - g₀)/(1 - g)) and ``"emission=<shape>"`` (the nominal's nodes around
    the fitted lengths and its seed, so its Monte Carlo follows the same
    photons as the nominal templates and the shift is not buried in
    independent noise), and ``"sample=<i>"`` (the nominal's nodes around the
    fitted lengths, other seeds: the templates' own Monte Carlo error).
    """
    g0 = base.mie_g_nodes[0]
    gs = config.mie_g_values(g0)
    lo = min(lambda_sca_m) * (1 - g0) / (1 - gs[0]) / _REACH_MARGIN
    hi = max(lambda_sca_m) * (1 - g0) / (1 - gs[-1]) * _REACH_MARGIN
    phase = replace(
        base,
        lambda_sca_nodes_m=nodes_covering(base.lambda_sca_nodes_m, lo, hi),
        mie_g_nodes=gs,
        n_photons=max(1000, round(base.n_photons * config.phase_photon_factor)),
        mc_phase=(g0, base.rayleigh_fraction),
    )
    out = {
        f"phase:rayleigh={share:g}": replace(phase, rayleigh_fraction=share)
        for share in config.rayleigh_values(base.rayleigh_fraction)
    }
    local = replace(base, lambda_sca_nodes_m=nodes_around(base.lambda_sca_nodes_m, lambda_sca_m))
    for shape in config.emission_shapes:
        out[f"emission={shape}"] = replace(local, emission_shape=shape)
    for i in range(1, config.template_samples + 1):
        out[f"sample={i}"] = replace(local, seed=base.seed + SAMPLE_SEED_STEP * i)
    return out


#: How far apart the seeds of the template samples lie (the nodes' own seeds derive from them).
SAMPLE_SEED_STEP = 7919


def _shift_item(
    name: str,
    label: str,
    cases: Sequence[tuple[str, Mapping[str, object]]],
    d: np.ndarray,
    errors: np.ndarray,
    *,
    profiled: bool = False,
    note: str = "",
    sides: tuple[np.ndarray, np.ndarray] | None = None,
) -> SystematicShift:
    return SystematicShift(
        name,
        label,
        tuple(c for c, _ in cases),
        tuple(float(x) for x in d[:, 0]),
        tuple(float(x) for x in d[:, 1]),
        tuple(float(x) for x in d[:, 2]),
        tuple(float(x) for x in d[:, 3]),
        (float(errors[0]), float(errors[1]), float(errors[2])),
        profiled=profiled,
        note=note,
        errors_up_m=None if sides is None else _triple(sides[0]),
        errors_down_m=None if sides is None else _triple(sides[1]),
    )


def _triple(v: np.ndarray) -> tuple[float, float, float]:
    return float(v[0]), float(v[1]), float(v[2])


def _largest(d: np.ndarray) -> np.ndarray:
    """The largest |shift| per length over the cases (NaN stays NaN)."""
    return np.max(np.abs(d[:, :3]), axis=0)


def phase_limits(fit: ChiSquareFit, refits: Sequence[np.ndarray]) -> tuple[float | None, float | None]:
    """For a length the nominal fit only bounds: the loosest bound the phase refits reach.

    A lower limit at the nominal ⟨cos θ⟩ says nothing of the water when the
    water's ⟨cos θ⟩ is another: a refit there may put the length's minimum far
    below it (turbid water, a truth at ⟨cos θ⟩ 0.956: "λ_abs > 281 m" at the
    nominal 0.93, 24 m at 0.96, truth 30 m). The quoted limit becomes the
    smallest refitted position (the largest, for an upper limit) where that
    is looser; None where the nominal's stands.
    """
    out: list[float | None] = []
    for k, est in enumerate((fit.lambda_abs, fit.lambda_sca)):
        found = [float(r[k]) for r in refits if math.isfinite(float(r[k]))]
        lim = est.limit_m
        if not found or lim is None:
            out.append(None)
        elif est.status == LOWER_LIMIT and min(found) < lim:
            out.append(min(found))
        elif est.status == UPPER_LIMIT and max(found) > lim:
            out.append(max(found))
        else:
            out.append(None)
    return out[0], out[1]


def systematic_budget(
    fit: ChiSquareFit,
    settings: Sequence[SettingProfiles],
    grid: HaloSource,
    variations: Mapping[str, HaloSource],
    config: SystematicsConfig | None = None,
) -> SystematicBudget:
    """Refit with each variation and return the shifts of λ_abs, λ_sca and λ_att.

    ``grid`` is the fit's own template grid, ``variations`` the grids of
    `variation_settings` (built by the caller, who owns the cache and the
    workers); a variation whose grid is missing is left out of the budget.
    """
    config = config or SystematicsConfig()
    t0 = time.perf_counter()
    refit = Refitter(fit, settings, grid)
    cfg = fit.config
    items: list[SystematicShift] = []
    limits: tuple[float | None, float | None] = (None, None)
    relief: tuple[str, float, float] | None = None
    move = (0.0, 0.0, 0.0)
    g0, r0 = fit.mie_g, grid.settings.rayleigh_fraction
    gs, rs = config.mie_g_values(g0), config.rayleigh_values(r0)
    # A fit that measured the phase function has its spread inside its errors already (the lengths'
    # envelope over the phase functions the data allow): no phase line then.
    if fit.phase is None and all(f"phase:rayleigh={r:g}" in variations for r in rs):
        cases = [
            (f"{g:g}/{r:g}", {"grid": variations[f"phase:rayleigh={r:g}"], "config": replace(cfg, mie_g=g)})
            for r in rs
            for g in gs
        ]
        reference = {"grid": variations[f"phase:rayleigh={r0:g}"], "config": replace(cfg, mie_g=g0)}
        hits = refit.edge_hits
        d = refit.shifts(cases, reference)
        box = d.reshape(len(rs), len(gs), 4)
        # λ_abs's sides on its coefficient (`analysis.chisq.posterior._coefficient_sides`)
        at = (float(refit.reference(**reference)[0]), None, None)
        data = marginal_posterior([rs, gs], box, fit.error_scale, coefficient_at=at)
        flat = box.copy()
        flat[..., 3] = 0.0
        prior = marginal_posterior([rs, gs], flat, 1.0, coefficient_at=at)
        said = (
            f"the data alone: ⟨cos θ⟩ {data.mean[1]:.3f} ± {data.sd[1]:.3f}, Rayleigh share "
            f"{data.mean[0]:.2f} ± {data.sd[0]:.2f}"
        )
        box_text = (
            f"⟨cos θ⟩ {gs[0]:g}-{gs[-1]:g} × Rayleigh share {rs[0]:g}-{rs[-1]:g} (nominal {g0:g}/{r0:g})"
        )
        used = data if config.narrow_by_data else prior
        if config.narrow_by_data:
            note = f"error: RMS shift over the data's posterior on {box_text}; {said}"
        else:
            note = f"error: RMS shift over a uniform prior on {box_text}; {said} (not used)"
        note += (
            "; up and down: the RMS of the upward and of the downward shifts, each over its side "
            "(λ_abs's taken on 1/λ_abs and mapped back)"
        )
        if refit.edge_hits > hits:
            note += EDGE_NOTE
        limits = phase_limits(fit, [refit.reference(**kw) for _, kw in cases])
        relief = _phase_relief(fit, refit, cases, d)
        for k, lim in enumerate(limits):
            if lim is not None:
                name = ("λ_abs", "λ_sca")[k]
                note += (
                    f"; {name} is only bounded at the nominal phase function; a refit reaches "
                    f"{lim:.3g} m, so the limit quoted is that"
                )
        label = "phase function: Mie ⟨cos θ⟩ and Rayleigh share (jointly)"
        items.append(
            _shift_item(
                "phase_function", label, cases, d, used.rms_m, note=note, sides=(used.up_m, used.down_m)
            )
        )
    cases = [
        (shape, {"grid": variations[f"emission={shape}"]})
        for shape in config.emission_shapes
        if f"emission={shape}" in variations
    ]
    if cases:
        hits = refit.edge_hits
        d = refit.shifts(cases)
        label = "LEM angular emission shape (vs linear in cos θ)"
        note = EDGE_NOTE if refit.edge_hits > hits else ""
        items.append(_shift_item("emission_shape", label, cases, d, _largest(d), note=note))
    cases = [
        (f"seed +{SAMPLE_SEED_STEP * i}", {"grid": variations[f"sample={i}"]})
        for i in range(1, config.template_samples + 1)
        if f"sample={i}" in variations
    ]
    if cases:
        hits = refit.edge_hits
        d = refit.shifts(cases)
        label = "templates' Monte Carlo sample (refitted on other seeds)"
        # a refit on the templates' edge gives only a bound on its shift: then the values stay
        sample_err, sample_mean = template_sample_mean(d[:, :3], average=refit.edge_hits == hits)
        move = _triple(np.nan_to_num(sample_mean, nan=0.0))
        if np.isfinite(sample_mean).any():
            note = (
                f"values quoted: the mean over the nominal templates and these {len(cases)} samples; "
                f"error: that mean's, √(mean shift²/2)/√{len(cases) + 1}"
            )
        else:
            note = "error: √(mean shift²/2), two samples differing by √2 of one's error"
        note += EDGE_NOTE if refit.edge_hits > hits else ""
        items.append(_shift_item("template_sample", label, cases, d, sample_err, note=note))
    cases = [(key, {"grid": variations[key]}) for key in ("higher=-1", "higher=+1") if key in variations]
    if cases:
        hits = refit.edge_hits
        d = refit.shifts(cases)
        label = "templates' small-angle orders (≥ 2) at their stated accuracy"
        note = EDGE_NOTE if refit.edge_hits > hits else ""
        items.append(_shift_item("higher_orders", label, cases, d, _largest(d), note=note))
    rel = cfg.lambda_sca_sys_rel
    acc = np.array(
        [[0.0, fit.lambda_sca_m * rel * refit.mask[1], fit.lambda_att_m**2 / fit.lambda_sca_m * rel, 0.0]]
    )
    label = "templates' accuracy (quadrature near the limb, MC normalisation)"
    items.append(_shift_item("template_accuracy", label, [(f"±{100 * rel:g} %", {})], acc, _largest(acc)))
    items += _profiled_impacts(fit, refit)
    return SystematicBudget(tuple(items), time.perf_counter() - t0, limits, move, relief)


def _phase_relief(
    fit: ChiSquareFit,
    refit: Refitter,
    cases: Sequence[tuple[str, Mapping[str, object]]],
    d: np.ndarray,
) -> tuple[str, float, float] | None:
    """Where the fit strained a calibration at the nominal phase function: the data-allowed phase
    refit (Δχ²/s² ≤ `DCHI2_2D_68`, two parameters) with the smallest largest nuisance pull, if that
    one keeps every nuisance within `NUISANCE_FLAG_SIGMA` (`SystematicBudget.phase_relief`)."""
    if not fit.strained_nuisances:
        return None
    best: tuple[str, float, float] | None = None
    for (case, kw), row in zip(cases, d, strict=True):
        dchi2 = float(row[3]) / fit.error_scale**2
        if not dchi2 <= DCHI2_2D_68:
            continue
        pull = refit.max_pull(**kw)
        if pull <= NUISANCE_FLAG_SIGMA and (best is None or pull < best[2]):
            best = (case, dchi2, pull)
    return best


def template_sample_mean(d: np.ndarray, *, average: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """The template-sample line's error and the values' move, per length, from the refits' shifts ``d``
    (samples × lengths, each against the nominal templates).

    One sample's error is √(mean shift²/2) (two independent samples differ by √2 of it). Where every
    refit moved, the value quoted is the mean over the nominal and the n samples (the nominal's
    shift is 0: the move is Σ shift/(n+1)), and its error that of a mean, one sample's /√(n+1); a
    length a refit lost (NaN), or every length when ``average`` is False, keeps the nominal value
    and one sample's error.
    """
    n = d.shape[0]
    one = np.sqrt(np.mean(d**2, axis=0) / 2.0)
    ok = np.isfinite(d).all(axis=0) & average
    move = np.where(ok, d.sum(axis=0) / (n + 1), np.nan)
    return np.where(ok, one / math.sqrt(n + 1), one), move


def _profiled_impacts(fit: ChiSquareFit, refit: Refitter) -> list[SystematicShift]:
    """Impacts of the floated nuisances: held at nominal ± 1σ, against held at nominal."""
    geo, ratio, cfg = fit.geometry, fit.emission_ratio, fit.config
    out = []
    cases: list[tuple[str, Mapping[str, object]]]
    if ratio.err > 0:
        cases = [(f"{s:+d}σ", {"ratio": EmissionRatio(ratio.value + s * ratio.err, 0.0)}) for s in (-1, 1)]
        ref = {"ratio": EmissionRatio(ratio.value, 0.0)}
        label = f"I0'/I0 {ratio.value:g} ± {ratio.err:g}"
        out.append(_impact("emission_ratio", label, cases, refit.shifts(cases, ref)))
    if cfg.psf_sigma_err_px > 0 and not cfg.edge_sigmas_px:  # a free edge has no one PSF width
        c0 = replace(cfg, psf_sigma_err_px=0.0)
        cases = [
            (f"{s:+d}σ", {"config": replace(c0, psf_sigma_px=cfg.psf_sigma_px + s * cfg.psf_sigma_err_px)})
            for s in (-1, 1)
        ]
        label = f"PSF width {cfg.psf_sigma_px:g} ± {cfg.psf_sigma_err_px:g} px"
        out.append(_impact("psf_sigma", label, cases, refit.shifts(cases, {"config": c0})))
    for which in ("near", "far"):
        d, e = getattr(geo, f"distance_{which}_m"), getattr(geo, f"distance_{which}_err_m")
        if e <= 0:
            continue
        g0 = replace(geo, **{f"distance_{which}_err_m": 0.0})  # type: ignore[arg-type]
        cases = [
            (f"{s:+d}σ", {"geometry": replace(g0, **{f"distance_{which}_m": d + s * e})})  # type: ignore[arg-type]
            for s in (-1, 1)
        ]
        label = f"{which} distance {d:g} ± {e:g} m"
        out.append(_impact(f"distance_{which}", label, cases, refit.shifts(cases, {"geometry": g0})))
    return out


def _impact(
    name: str, label: str, cases: Sequence[tuple[str, Mapping[str, object]]], d: np.ndarray
) -> SystematicShift:
    return _shift_item(name, label, cases, d, _largest(d), profiled=True, note="")
