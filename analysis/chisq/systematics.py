"""The systematic budget: what the fit holds fixed, varied one at a time, and the shifts it causes.

The fit holds the phase function (⟨cos θ⟩ and the Rayleigh share) and the
LEM's angular emission shape (linear in the cosine of the emission angle)
fixed; neither the real water nor the real LEM promises them. Each is
varied over a plausible range and λ_abs and λ_sca are fitted again. The
phase function's two parameters are uniform priors over their ranges that
the data narrow: each length's error is the RMS of its shift over the
parameter's posterior exp(-Δχ²/2s²) (`marginal_error`), so the data's
preferred value and its width count, and a refit that runs away where the
data exclude the parameter does not. An alternative emission shape counts
with its full shift. Their sum in quadrature, with the templates' own
accuracy on λ_sca, is the systematic error quoted.

The nuisances the fit already floats with a prior (I0'/I0, the PSF width,
the two distances) are listed too, as *impacts*: the shift when the
nuisance is held at nominal ± 1σ instead of floated, against the fit with
it held at nominal. Their error is already inside the fit error, so they
are not added to the systematic error a second time.

Refits start from the nominal minimum and use the same searches as the fit
(`analysis.chisq.fit.Objective.minimise`), without intervals or maps: a few
hundred χ² evaluations each. Alternative templates are needed only at the
scattering-length nodes around the fitted λ_sca (`variation_settings`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from analysis.attenuation import EmissionRatio
from analysis.chisq.data import SettingProfiles
from analysis.chisq.results import ChiSquareFit, SystematicBudget, SystematicShift
from analysis.chisq.wavelength import make_objective
from analysis.transport.templates import TemplateGrid, TemplateSettings


@dataclass(frozen=True)
class SystematicsConfig:
    """The ranges of the budget's variations.

    ``mie_g_range``: ⟨cos θ⟩ of the Mie part (the paper scanned 0.88-0.96
    around its 0.92-0.93); ``rayleigh_range``: the share of scattering that
    is Rayleigh (~17 % in the deep-sea model); ``emission_shapes``: the
    alternative angular emission shapes of the LEM
    (`analysis.transport.scene.EMISSION_SHAPES`). ⟨cos θ⟩ and the Rayleigh
    share are uniform priors over their ranges, narrowed by the data
    (`marginal_error`): ⟨cos θ⟩ is refitted at ``mie_g_points`` values
    evenly over its range (and the nominal), the Rayleigh share at the ends
    and the nominal. Each alternative emission shape's full shift is its
    error.
    """

    mie_g_range: tuple[float, float] = (0.88, 0.96)
    mie_g_points: int = 5
    rayleigh_range: tuple[float, float] = (0.10, 0.25)
    emission_shapes: tuple[str, ...] = ("hemispheres",)

    def __post_init__(self) -> None:
        lo, hi = self.mie_g_range
        if not -1 < lo < hi < 1:
            raise ValueError(f"mie_g_range must be increasing inside (-1, 1), got {self.mie_g_range}")
        if self.mie_g_points < 2:
            raise ValueError(f"mie_g_points must be >= 2, got {self.mie_g_points}")
        lo, hi = self.rayleigh_range
        if not 0 <= lo < hi <= 1:
            raise ValueError(f"rayleigh_range must be increasing inside [0, 1], got {self.rayleigh_range}")


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


def variation_settings(
    base: TemplateSettings, lambda_sca_m: Sequence[float], config: SystematicsConfig
) -> dict[str, TemplateSettings]:
    """The template settings each variation needs (around the fitted ``lambda_sca_m`` only).

    Keys: ``"mie_g"`` (nodes at both ends of the range and the nominal),
    ``"rayleigh=<share>"`` and ``"emission=<shape>"``. The Rayleigh and
    emission variants keep the nominal seeds, so their Monte Carlo follows the
    same photons as the nominal templates and the shifts are not buried in
    independent noise.
    """
    nodes = nodes_around(base.lambda_sca_nodes_m, lambda_sca_m)
    local = replace(base, lambda_sca_nodes_m=nodes)
    g0 = base.mie_g_nodes[0]
    out = {"mie_g": replace(local, mie_g_nodes=tuple(sorted({*config.mie_g_range, g0})))}
    for share in config.rayleigh_range:
        out[f"rayleigh={share:g}"] = replace(local, rayleigh_fraction=share)
    for shape in config.emission_shapes:
        out[f"emission={shape}"] = replace(local, emission_shape=shape)
    return out


class _Refitter:
    """Refits of one wavelength's data from the nominal minimum, with some inputs replaced."""

    def __init__(self, fit: ChiSquareFit, settings: Sequence[SettingProfiles], grid: TemplateGrid) -> None:
        self.settings = settings
        self.inputs: dict[str, object] = {
            "grid": grid,
            "geometry": fit.geometry,
            "ratio": fit.emission_ratio,
            "config": fit.config,
        }
        self.start = np.log([fit.lambda_abs_m, fit.lambda_sca_m])
        # A length the fit only bounds gets no shift: its minimum sits on the grid's edge.
        self.mask = np.array(
            [1.0 if fit.lambda_abs.measured else np.nan, 1.0 if fit.lambda_sca.measured else np.nan, 1.0, 1.0]
        )
        self.n_refits = 0
        self.edge_hits = 0
        self._refs: dict[str, np.ndarray] = {}
        self._disks: dict = {}  # type: ignore[type-arg]

    def __call__(self, **replaced: object) -> np.ndarray:
        """(λ_abs, λ_sca, λ_att, χ²) of the minimum with ``replaced`` inputs, found from the nominal one."""
        kw = {**self.inputs, **replaced}
        obj = make_objective(
            self.settings,
            kw["grid"],  # type: ignore[arg-type]
            kw["geometry"],  # type: ignore[arg-type]
            kw["ratio"],  # type: ignore[arg-type]
            kw["config"],  # type: ignore[arg-type]
            self._disks,
        )
        p = obj.minimise(self.start, near=True)
        best = np.exp(p)
        self.n_refits += 1
        if obj.on_edge(float(p[1]), 1) or obj.on_edge(float(p[0]), 0):
            self.edge_hits += 1
        return np.array([best[0], best[1], 1.0 / (1.0 / best[0] + 1.0 / best[1]), obj(p)])

    def reference(self, **replaced: object) -> np.ndarray:
        key = repr(sorted(replaced.items()))
        if key not in self._refs:
            self._refs[key] = self(**replaced)
        return self._refs[key]

    def shifts(
        self, cases: Sequence[tuple[str, Mapping[str, object]]], reference: Mapping[str, object] | None = None
    ) -> np.ndarray:
        """(case, [Δλ_abs, Δλ_sca, Δλ_att, Δχ²]) against the reference refit (NaN for a bounded length)."""
        ref = self.reference(**(reference or {}))
        # Every case goes through the same memo: a case equal to the reference is not refitted.
        return np.array([(self.reference(**kw) - ref) * self.mask for _, kw in cases])


def _shift_item(
    name: str,
    label: str,
    cases: Sequence[tuple[str, Mapping[str, object]]],
    d: np.ndarray,
    errors: np.ndarray,
    *,
    profiled: bool = False,
    note: str = "",
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
    )


def _largest(d: np.ndarray) -> np.ndarray:
    """The largest |shift| per length over the cases (NaN stays NaN)."""
    return np.max(np.abs(d[:, :3]), axis=0)


def constrained_error(
    nominal: float, ends: tuple[float, float], d: np.ndarray, error_scale: float
) -> tuple[np.ndarray, float]:
    """Errors on the three lengths from a held parameter x, narrowed by the data's own Δχ² (linearised).

    The range ``ends`` is the prior: x uniform between them (σ = width/√12).
    The data's information on x is the curvature a of the parabola
    a·δ² + b·δ (δ = x - nominal) through the nominal (Δχ² = 0) and the two
    ends' Δχ² (divided by the error scale²). The posterior width is
    1/√(a + 1/σ_prior²), and each length's error the secant slope between
    the ends times that width. Kept as the linear limit of
    `marginal_error`, which the budget uses: a refit that runs away at one
    end (λ_abs to the grid's edge) makes the secant, hence this error, huge
    even where the data exclude that end.
    """
    lo, hi = ends
    dx = np.array([lo - nominal, hi - nominal])
    y = d[:, 3] / error_scale**2
    a, _ = np.linalg.solve(np.stack([dx * dx, dx], axis=1), y)
    prior = (hi - lo) / math.sqrt(12.0)
    width = 1.0 / math.sqrt(max(float(a), 0.0) + 1.0 / prior**2)
    slope = (d[1, :3] - d[0, :3]) / (hi - lo)
    return np.abs(slope) * width, width


#: Points of the fine grid over a held parameter's range on which `marginal_error` integrates.
_MARGINAL_POINTS = 401


def marginal_error(
    x: Sequence[float], d: np.ndarray, error_scale: float
) -> tuple[np.ndarray, tuple[float, float]]:
    """Errors on the three lengths from a held parameter, marginalised over the data's posterior of it.

    ``x`` are the parameter's values at which the lengths were refitted
    (their ends span the prior's range, uniform; one of them the reference,
    with zero shifts) and ``d`` the rows (Δλ_abs, Δλ_sca, Δλ_att, Δχ²)
    against that reference. Between the points the shifts and Δχ² are
    interpolated linearly; the posterior of the parameter is
    exp(-Δχ²/(2 s²)) over the range (s the fit's error scale), and each
    length's error is the root mean square of its shift under it,
    √(E[Δλ²]) = √(var + (mean shift)²): the spread the parameter's
    uncertainty gives the length, plus how far the data's preferred value
    moves it from the reported one. Where the data pin the parameter this
    is the shift over the posterior's width; where they do not, it is the
    spread over the prior's range; a refit that runs away where the data
    exclude the parameter gets that exclusion's weight, not the secant's.
    Returns the errors and the parameter's posterior mean and standard
    deviation (what the data say of it).
    """
    order = np.argsort(np.asarray(x, dtype=float))
    xs = np.asarray(x, dtype=float)[order]
    rows = np.asarray(d, dtype=float)[order]
    fine = np.linspace(xs[0], xs[-1], _MARGINAL_POINTS)
    dchi2 = np.interp(fine, xs, rows[:, 3]) / error_scale**2
    w = np.exp(-0.5 * (dchi2 - dchi2.min()))
    w[[0, -1]] *= 0.5  # the trapezoid rule
    w /= w.sum()
    errors = np.empty(3)
    for k in range(3):
        if not np.all(np.isfinite(rows[:, k])):
            errors[k] = np.nan
            continue
        shift = np.interp(fine, xs, rows[:, k])
        errors[k] = math.sqrt(float(np.sum(w * shift * shift)))
    mean = float(np.sum(w * fine))
    return errors, (mean, math.sqrt(max(float(np.sum(w * (fine - mean) ** 2)), 0.0)))


def systematic_budget(
    fit: ChiSquareFit,
    settings: Sequence[SettingProfiles],
    grid: TemplateGrid,
    variations: Mapping[str, TemplateGrid],
    config: SystematicsConfig | None = None,
) -> SystematicBudget:
    """Refit with each variation and return the shifts of λ_abs, λ_sca and λ_att.

    ``grid`` is the fit's own template grid, ``variations`` the grids of
    `variation_settings` (built by the caller, who owns the cache and the
    workers); a variation whose grid is missing is left out of the budget.
    """
    config = config or SystematicsConfig()
    t0 = time.perf_counter()
    refit = _Refitter(fit, settings, grid)
    cfg = fit.config
    items: list[SystematicShift] = []
    held = [
        ("mie_g", "Mie ⟨cos θ⟩", fit.mie_g, config.mie_g_range),
        (
            "rayleigh_fraction",
            "Rayleigh share of scattering",
            grid.settings.rayleigh_fraction,
            config.rayleigh_range,
        ),
    ]
    for name, label, nominal, ends in held:
        if name == "mie_g":
            if "mie_g" not in variations:
                continue
            var = variations["mie_g"]
            points = sorted({*np.linspace(ends[0], ends[1], config.mie_g_points).round(4), nominal})
            cases = [(f"{g:g}", {"grid": var, "config": replace(cfg, mie_g=float(g))}) for g in points]
            reference: dict[str, object] | None = {"grid": var, "config": replace(cfg, mie_g=nominal)}
        else:
            if not all(f"rayleigh={x:g}" in variations for x in ends):
                continue
            points = [ends[0], nominal, ends[1]]
            cases = [(f"{ends[0]:g}", {"grid": variations[f"rayleigh={ends[0]:g}"]})]
            cases += [(f"{nominal:g}", {})]
            cases += [(f"{ends[1]:g}", {"grid": variations[f"rayleigh={ends[1]:g}"]})]
            reference = None
        hits = refit.edge_hits
        d = refit.shifts(cases, reference)
        errors, (mean, width) = marginal_error(points, d, fit.error_scale)
        note = (
            f"the data: {mean:.3g} ± {width:.2g} (prior uniform over {ends[0]:g}-{ends[1]:g}, nominal "
            f"{nominal:g}); error: RMS shift over that posterior"
        )
        if refit.edge_hits > hits:
            note += EDGE_NOTE
        items.append(_shift_item(name, label, cases, d, errors, note=note))
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
    rel = cfg.lambda_sca_sys_rel
    acc = np.array(
        [[0.0, fit.lambda_sca_m * rel * refit.mask[1], fit.lambda_att_m**2 / fit.lambda_sca_m * rel, 0.0]]
    )
    label = "templates' accuracy (quadrature near the limb, MC normalisation)"
    items.append(_shift_item("template_accuracy", label, [(f"±{100 * rel:g} %", {})], acc, _largest(acc)))
    items += _profiled_impacts(fit, refit)
    return SystematicBudget(tuple(items), time.perf_counter() - t0)


def _profiled_impacts(fit: ChiSquareFit, refit: _Refitter) -> list[SystematicShift]:
    """Impacts of the floated nuisances: held at nominal ± 1σ, against held at nominal."""
    geo, ratio, cfg = fit.geometry, fit.emission_ratio, fit.config
    out = []
    cases: list[tuple[str, Mapping[str, object]]]
    if ratio.err > 0:
        cases = [(f"{s:+d}σ", {"ratio": EmissionRatio(ratio.value + s * ratio.err, 0.0)}) for s in (-1, 1)]
        ref = {"ratio": EmissionRatio(ratio.value, 0.0)}
        label = f"I0'/I0 {ratio.value:g} ± {ratio.err:g}"
        out.append(_impact("emission_ratio", label, cases, refit.shifts(cases, ref)))
    if cfg.psf_sigma_err_px > 0:
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
