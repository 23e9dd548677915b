"""The phase function measured from the halo: Mie ⟨cos θ⟩ and the Rayleigh share, profiled.

The halo's radial shape measures mostly the transport length λ_sca(1 - g),
so at fixed lengths a phase function and a scattering length trade against
each other; what separates them is the rest of what the frames hold: the
absolute scattered-to-direct light (λ_sca, fixed through λ_att by the two
disks), the halo's growth from the near to the far camera, and the shape
near the LEM's limb against the wide-angle Rayleigh pedestal.

`scan_phase` maps the χ² profiled over everything else (λ_abs, λ_sca, the
nuisances and the linear parameters) on a grid of (g, f) over the templates'
range, each point a refit started from its neighbour's minimum.
`phase_estimates` reads that map: the best phase function (a smooth
interpolation of the map), each parameter's 68 % interval where its profile
(the map minimised over the other) has risen by s² (a one-sided 95 % limit
when open on one side, nothing when open on both), the mean cosine
(1 - f)·g likewise, and the lengths' intervals widened to the envelope of
the conditional intervals over the map: at each (g, f) the length's own χ²
parabola around that point's minimum, raised by the point's Δχ². Where the
data cannot tell g from λ_sca the map is flat along the valley, and the
envelope spans the lengths the whole range of phase functions gives: an
error that covers the truth over the range rather than a value that
pretends to know the phase function.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.interpolate import RectBivariateSpline

from analysis.chisq.fit import Objective
from analysis.chisq.phase_results import (
    PHASE_DEGENERATE,
    PHASE_LIMIT,
    PHASE_MEASURED,
    PhaseConfig,
    PhaseFit,
    PhaseMap,
    PhaseParameter,
)
from analysis.chisq.results import (
    DCHI2_1D,
    DCHI2_LIMIT_95,
    LOWER_LIMIT,
    MEASURED,
    UNCONSTRAINED,
    UPPER_LIMIT,
)


def scan_phase(obj: Objective, start: np.ndarray, config: PhaseConfig) -> PhaseMap:
    """Refit (ln λ_abs, ln λ_sca) at every (g, f) node, each from its nearest done neighbour.

    λ_sca's start follows the valley the halo holds, λ_sca(1 - g) constant.
    """
    prob = obj.prob
    (g_lo, g_hi), (f_lo, f_hi) = _ranges(prob.grid, config)
    gs = np.linspace(g_lo, g_hi, config.mie_g_points)
    fs = np.linspace(f_lo, f_hi, config.rayleigh_points)
    g0, f0 = prob.mie_g, prob.rayleigh_share
    chi2 = np.full((len(fs), len(gs)), np.nan)
    lnl = np.full((2, len(fs), len(gs)), np.nan)
    # Visit the nodes nearest the nominal first, so that every start is a near neighbour's minimum.
    order = sorted(
        ((j, i) for j in range(len(fs)) for i in range(len(gs))),
        key=lambda ji: ((gs[ji[1]] - g0) / (g_hi - g_lo)) ** 2 + ((fs[ji[0]] - f0) / (f_hi - f_lo)) ** 2,
    )
    # One set of weights for the whole map: the templates' errors frozen at the nominal minimum.
    prob.freeze_template_errors(math.exp(start[0]), math.exp(start[1]))
    done: list[tuple[int, int]] = []
    for j, i in order:
        if done:
            jn, inn = min(done, key=lambda d: (d[0] - j) ** 2 + (d[1] - i) ** 2)
            p0 = lnl[:, jn, inn].copy()
            p0[1] += math.log((1 - gs[inn]) / (1 - gs[i]))
        else:
            p0 = np.asarray(start, dtype=np.float64).copy()
            p0[1] += math.log((1 - g0) / (1 - gs[i]))
        prob.set_phase(gs[i], fs[j])
        # Newton steps where the start lies inside the range; a minimum on its edge (λ_abs beyond what
        # 20 m of baseline resolves) is Nelder-Mead's.
        inside = not (obj.on_edge(float(p0[0]), 0) or obj.on_edge(float(p0[1]), 1))
        found = obj.newton(p0) if inside else None
        best = obj.minimise(p0, near=True, refreeze=False) if found is None else found
        chi2[j, i] = obj(best)
        lnl[:, j, i] = best
        done.append((j, i))
    prob.set_phase(g0, f0)
    return PhaseMap(gs, fs, chi2, lnl, prob.n_bins() - prob.n_linear() - 4)


def source_phase_ranges(source: object) -> tuple[tuple[float, float], tuple[float, float]] | None:
    """The (Mie ⟨cos θ⟩, Rayleigh share) ranges a halo source serves, None if it tells neither.

    Template grids name them ``phase_ranges``; smooth templates ``mie_g_range`` and
    ``rayleigh_share_range``.
    """
    if hasattr(source, "phase_ranges"):
        return source.phase_ranges  # type: ignore[no-any-return]
    if hasattr(source, "mie_g_range") and hasattr(source, "rayleigh_share_range"):
        return tuple(source.mie_g_range), tuple(source.rayleigh_share_range)  # type: ignore[return-value]
    return None


def _ranges(source: object, config: PhaseConfig) -> tuple[tuple[float, float], tuple[float, float]]:
    found = source_phase_ranges(source)
    if found is None:
        raise ValueError("these templates hold one phase function: the fit cannot float it")
    (sg_lo, sg_hi), (sf_lo, sf_hi) = found
    g = (max(config.mie_g_range[0], sg_lo), min(config.mie_g_range[1], sg_hi))
    f = (max(config.rayleigh_range[0], sf_lo), min(config.rayleigh_range[1], sf_hi))
    return g, f


def can_float(source: object, config: PhaseConfig) -> bool:
    """True when the templates span a range of both ⟨cos θ⟩ and the Rayleigh share."""
    if source_phase_ranges(source) is None:
        return False
    (g_lo, g_hi), (f_lo, f_hi) = _ranges(source, config)
    return g_hi - g_lo > 0.02 and f_hi - f_lo > 0.02


class _Fine:
    """The map interpolated on a fine grid (cubic along g, as smooth as the nodes allow along f)."""

    def __init__(self, pmap: PhaseMap, n: int) -> None:
        g, f = pmap.mie_g, pmap.rayleigh_share
        kx, ky = min(3, len(g) - 1), min(3, len(f) - 1)
        self.g = np.linspace(g[0], g[-1], n)
        self.f = np.linspace(f[0], f[-1], max(n // 2, 11))

        def spline(z: np.ndarray) -> np.ndarray:
            return RectBivariateSpline(g, f, z.T, kx=kx, ky=ky, s=0)(self.g, self.f).T  # (n_f, n_g)

        self.chi2 = spline(pmap.chi2)
        self.ln_lambda = np.stack([spline(pmap.ln_lambda[k]) for k in range(2)])


def phase_estimates(
    pmap: PhaseMap, scale: float, ln_sigma: tuple[float, float], config: PhaseConfig
) -> tuple[PhaseFit, float]:
    """Read the map: the phase function, its case, the lengths' envelopes; and the χ² minimum found.

    ``ln_sigma``: the lengths' conditional 68 % half-widths in ln λ at the
    best phase function (already scaled by ``scale``).
    """
    fine = _Fine(pmap, config.fine_points)
    s2 = scale * scale
    d = (fine.chi2 - float(np.min(fine.chi2))) / s2
    j, i = np.unravel_index(int(np.argmin(d)), d.shape)
    best = (float(fine.g[i]), float(fine.f[j]))
    d_seen = d  # the data's own Δχ²/s²: the best point, the posterior's correlations
    d = np.clip(d - config.model_dchi2, 0.0, None)  # what the templates cannot yet tell apart
    g_par = _parameter("mie_g", fine.g, d.min(axis=0), best[0])
    f_par = _parameter("rayleigh_share", fine.f, d.min(axis=1), best[1])
    m_par = _mean_cosine(fine, d, best)
    env = (
        _envelope(fine.ln_lambda[0], d, ln_sigma[0], pmap.ln_lambda[0]),
        _envelope(fine.ln_lambda[1], d, ln_sigma[1], pmap.ln_lambda[1]),
    )
    post = np.exp(-0.5 * d_seen)
    corr = (
        _weighted_corr(np.broadcast_to(fine.g[None, :], d.shape), fine.ln_lambda[1], post),
        _weighted_corr(np.broadcast_to(fine.f[:, None], d.shape), fine.ln_lambda[1], post),
    )
    case, text = _case(g_par, f_par, m_par, fine)
    if pmap.joint:
        text += f"; Mie ⟨cos θ⟩ shared with {', '.join(f'{v} nm' for v in pmap.joint)}"
    if config.model_dchi2 > 0:
        text += f"; intervals allow Δχ²/s² {config.model_dchi2:g} for the templates' accuracy"
    fit = PhaseFit(
        case, text, g_par, f_par, m_par, best, corr, pmap, (pmap.chi2 - float(np.min(fine.chi2))) / s2, env
    )
    return fit, float(np.min(fine.chi2))


def _parameter(name: str, x: np.ndarray, profile: np.ndarray, best: float) -> PhaseParameter:
    """Value and 68 % interval, a one-sided 95 % limit, or nothing, from a profile Δχ²/s² over ``x``."""
    inside = profile <= DCHI2_1D
    lo_open, hi_open = bool(inside[0]), bool(inside[-1])
    idx = np.flatnonzero(inside)
    lo, hi = float(x[idx[0]]), float(x[idx[-1]])
    if not lo_open and not hi_open:
        lo, hi = _crossing(x, profile, idx[0], -1), _crossing(x, profile, idx[-1], 1)
        return PhaseParameter(name, MEASURED, best, 0.5 * (hi - lo), (lo, hi))
    if lo_open and hi_open:
        return PhaseParameter(name, UNCONSTRAINED, None, None, (lo, hi))
    limit_in = np.flatnonzero(profile <= DCHI2_LIMIT_95)
    if hi_open:
        if limit_in[0] == 0:
            return PhaseParameter(name, UNCONSTRAINED, None, None, (lo, hi))
        lim = _crossing(x, profile, limit_in[0], -1)
        return PhaseParameter(name, LOWER_LIMIT, None, None, (lo, hi), limit=lim, cl=0.95)
    if limit_in[-1] == len(x) - 1:
        return PhaseParameter(name, UNCONSTRAINED, None, None, (lo, hi))
    lim = _crossing(x, profile, limit_in[-1], 1)
    return PhaseParameter(name, UPPER_LIMIT, None, None, (lo, hi), limit=lim, cl=0.95)


def _crossing(x: np.ndarray, prof: np.ndarray, k: int, direction: int) -> float:
    """Where ``prof`` crosses its level between index ``k`` (inside) and its outer neighbour."""
    n = k + direction
    if n < 0 or n >= len(x):
        return float(x[k])
    level = DCHI2_1D if prof[k] <= DCHI2_1D and prof[n] > DCHI2_1D else DCHI2_LIMIT_95
    a, b = prof[k], prof[n]
    t = 0.0 if b == a else float(np.clip((level - a) / (b - a), 0.0, 1.0))
    return float(x[k] + t * (x[n] - x[k]))


def _mean_cosine(fine: _Fine, d: np.ndarray, best: tuple[float, float]) -> PhaseParameter:
    """(1 - f)·g: its profile is the map minimised along each line of equal mean cosine."""
    m = (1.0 - fine.f[:, None]) * fine.g[None, :]
    edges = np.linspace(float(m.min()), float(m.max()), 121)
    idx = np.clip(np.digitize(m, edges) - 1, 0, len(edges) - 2)
    prof = np.full(len(edges) - 1, np.inf)
    np.minimum.at(prof, idx.ravel(), d.ravel())
    centres = 0.5 * (edges[1:] + edges[:-1])
    ok = np.isfinite(prof)
    value = (1.0 - best[1]) * best[0]
    return _parameter("mean_cos_theta", centres[ok], prof[ok], value)


def _envelope(
    ln_l: np.ndarray, d: np.ndarray, ln_sigma: float, nodes: np.ndarray
) -> tuple[float, float] | None:
    """The 68 % interval of a length over every phase function: min over (g, f) of Δχ²/s² plus the
    length's own parabola at that point; None when a node's minimum sat on the range's end."""
    if not np.all(np.isfinite(nodes)):
        return None
    sig = max(ln_sigma, 1e-6)
    reach = np.sqrt(np.clip(DCHI2_1D - d, 0.0, None)) * sig  # half-width at each (g, f) point
    ok = d <= DCHI2_1D
    lo = float(np.min((ln_l - reach)[ok]))
    hi = float(np.max((ln_l + reach)[ok]))
    return math.exp(lo), math.exp(hi)


def _weighted_corr(a: np.ndarray, b: np.ndarray, w: np.ndarray) -> float:
    w = w / np.sum(w)
    ma, mb = float(np.sum(w * a)), float(np.sum(w * b))
    cov = float(np.sum(w * (a - ma) * (b - mb)))
    va, vb = float(np.sum(w * (a - ma) ** 2)), float(np.sum(w * (b - mb) ** 2))
    return cov / math.sqrt(va * vb) if va > 0 and vb > 0 else 0.0


def _case(g: PhaseParameter, f: PhaseParameter, m: PhaseParameter, fine: _Fine) -> tuple[str, str]:
    span = f"⟨cos θ⟩ (Mie) {fine.g[0]:.2f}-{fine.g[-1]:.2f}, Rayleigh share {fine.f[0]:.2f}-{fine.f[-1]:.2f}"
    if g.status == MEASURED:
        text = f"phase function measured from the halo: Mie ⟨cos θ⟩ {g.value:.3f} ± {g.err:.3f}"
        if f.status == MEASURED:
            text += f", Rayleigh share {f.value:.2f} ± {f.err:.2f}"
        else:
            text += f", Rayleigh share {_words(f)} (searched {fine.f[0]:.2f}-{fine.f[-1]:.2f})"
        return PHASE_MEASURED, text
    if g.status in (LOWER_LIMIT, UPPER_LIMIT):
        return PHASE_LIMIT, (
            f"the halo bounds Mie ⟨cos θ⟩ only: {_words(g)}; the lengths' errors span the phase "
            f"functions it allows ({span})"
        )
    return PHASE_DEGENERATE, (
        f"the halo does not tell ⟨cos θ⟩ from λ_sca here: every phase function in {span} fits "
        "within Δχ² = s²; the lengths' errors span that whole range"
    )


def _words(p: PhaseParameter) -> str:
    if p.status == MEASURED:
        return f"{p.value:.3f} ± {p.err:.3f}"
    if p.status == LOWER_LIMIT:
        return f"> {p.limit:.3f} (95 % CL)"
    if p.status == UPPER_LIMIT:
        return f"< {p.limit:.3f} (95 % CL)"
    return "not constrained"


def profile_in_g(pmap: PhaseMap) -> np.ndarray:
    """The map's χ² at each ⟨cos θ⟩ node, minimised over the Rayleigh share (on a fine spline)."""
    g, f = pmap.mie_g, pmap.rayleigh_share
    fine_f = np.linspace(f[0], f[-1], 81)
    ky = min(3, len(f) - 1)
    kx = min(3, len(g) - 1)
    values = RectBivariateSpline(g, f, pmap.chi2.T, kx=kx, ky=ky, s=0)(g, fine_f)  # (n_g, n_fine)
    return np.asarray(values.min(axis=1))


def combine_maps(maps: dict[int, PhaseMap]) -> dict[int, PhaseMap]:
    """Each wavelength's map with the other wavelengths' χ² profiles in ⟨cos θ⟩ added: Mie ⟨cos θ⟩
    shared by all wavelengths (the particles' phase function barely changes from 405 to 525 nm),
    each wavelength's Rayleigh share its own (pure water's grows as λ^-4.3, the particles' scattering
    less steeply). Each profile enters in units of its own error scale², then the sum is put back
    in the wavelength's own (`phase_estimates` divides by it). Maps on other ⟨cos θ⟩ nodes are left
    alone."""
    out = dict(maps)
    for wl, own in maps.items():
        others = [
            (v, m)
            for v, m in maps.items()
            if v != wl and m.mie_g.shape == own.mie_g.shape and np.allclose(m.mie_g, own.mie_g)
        ]
        if not others:
            continue
        added = np.zeros(len(own.mie_g))
        for _, m in others:
            prof = profile_in_g(m)
            added += (prof - prof.min()) / m.scale**2
        out[wl] = PhaseMap(
            own.mie_g,
            own.rayleigh_share,
            own.chi2 + own.scale**2 * added[None, :],
            own.ln_lambda,
            own.ndof,
            tuple(sorted(v for v, _ in others)),
        )
    return out
