"""`fit_wavelength`: λ_abs and λ_sca of one wavelength, with scaled errors or one-sided limits."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from analysis.attenuation import EmissionRatio, Geometry
from analysis.chisq.data import FitInputError, SettingProfiles
from analysis.chisq.fit import Objective, curvature_covariance
from analysis.chisq.limits import error_scale, estimate
from analysis.chisq.model import Problem
from analysis.chisq.phase import can_float, phase_estimates, scan_phase
from analysis.chisq.phase_results import PhaseConfig, PhaseMap
from analysis.chisq.results import (
    MEASURED,
    NUISANCES,
    UNITS,
    ChiSquareFit,
    ContourMap,
    Estimate,
    FitConfig,
    Nuisance,
    SettingModel,
)
from analysis.transport.source import HaloSource


def make_objective(
    settings: Sequence[SettingProfiles],
    grid: HaloSource,
    geometry: Geometry,
    ratio: EmissionRatio,
    config: FitConfig,
    disk_cache: dict | None = None,  # type: ignore[type-arg]
) -> Objective:
    """The χ² of (ln λ_abs, ln λ_sca) over the allowed range (λ_abs's and the grid's λ_sca).

    ``disk_cache`` lets objectives of the same settings share their disk profiles.
    """
    prob = Problem(settings, grid, geometry, ratio, config, disk_cache)
    return Objective(prob, np.log([list(config.lambda_abs_range_m), list(grid.lambda_sca_range_m)]))


def phase_map(
    wavelength_nm: int,
    settings: Sequence[SettingProfiles],
    grid: HaloSource,
    geometry: Geometry,
    ratio: EmissionRatio,
    config: FitConfig,
) -> PhaseMap | None:
    """The χ² profiled over the lengths on the (Mie ⟨cos θ⟩, Rayleigh share) map, from the fit at
    the configured phase function; None when the phase function is not floated (`scan_phase`)."""
    if config.phase is None or not can_float(grid, config.phase):
        return None
    if not settings:
        raise FitInputError(f"{wavelength_nm} nm: no setting with stacked profiles of both cameras")
    obj = make_objective(settings, grid, geometry, ratio, config)
    return scan_phase(obj, obj.minimise(), config.phase)


def fit_wavelength(
    wavelength_nm: int,
    settings: Sequence[SettingProfiles],
    grid: HaloSource,
    geometry: Geometry,
    ratio: EmissionRatio,
    config: FitConfig | None = None,
    pmap: PhaseMap | None = None,
) -> ChiSquareFit:
    """Fit λ_abs and λ_sca to the profiles of one wavelength.

    1. a coarse scan of χ² over the grid's λ_sca range and a broad λ_abs
       range finds the region of the minimum;
    2. Nelder-Mead in (ln λ_abs, ln λ_sca) refines it; if the PSF width or
       the image scale moved by more than a third of their prior widths, the
       disk is recomputed there (they change its shape non-linearly) and the
       minimum refined again;
    3. the error scale s = √(χ²/ndof) (1 if that is below 1) widens every
       interval: each parameter's 68 % interval ends where the χ² profiled
       over the other rises by s²; an interval open on one side makes the
       length a one-sided 95 % limit (`analysis.chisq.limits`);
    4. the curvature of χ² at the minimum, times s², gives the covariance
       (hence λ_att's error and the correlation);
    5. Δχ²/s² is mapped on a grid around the minimum for the contour plot.

    With ``config.phase`` (and templates that span phase functions) the
    phase function is measured first (`phase_map`, or ``pmap`` when given:
    one the caller combined across wavelengths, `combine_maps`), the lengths
    refitted at its best point, and their intervals widened to the envelope
    over the phase functions the data allow.
    """
    config = config or FitConfig()
    if not settings:
        raise FitInputError(f"{wavelength_nm} nm: no setting with stacked profiles of both cameras")
    obj = make_objective(settings, grid, geometry, ratio, config)
    prob = obj.prob
    best = obj.minimise()
    if config.phase is None or not can_float(grid, config.phase):
        pmap = None
    elif pmap is None:
        pmap = scan_phase(obj, best, config.phase)
    if pmap is not None and config.phase is not None:
        best = _refit_at_best_phase(obj, pmap, config.phase)
    chi2_min = obj(best)
    ndof = prob.n_bins() - prob.n_linear() - 2 - (2 if pmap is not None else 0)
    scale = error_scale(chi2_min, ndof)
    cov = curvature_covariance(obj, best) * scale**2
    sigma = np.sqrt(np.maximum(np.diag(cov), 1e-8))
    names = ("lambda_abs", "lambda_sca")
    edges = [names[k] for k in range(2) if obj.on_edge(best[k], k)]
    estimates: list[Estimate] = []
    intervals = []
    for k in range(2):
        est_k, interval, open_side = estimate(obj, best, k, names[k], chi2_min, sigma[k], scale)
        estimates.append(est_k)
        intervals.append(interval)
        if open_side:
            edges.append(names[k])
    phase = None
    if pmap is not None and config.phase is not None:
        ln_sigma = tuple(0.5 * math.log(iv[1] / iv[0]) for iv in intervals)
        phase, _ = phase_estimates(pmap, scale, (ln_sigma[0], ln_sigma[1]), config.phase)
        for k in range(2):
            estimates[k], intervals[k] = _widened(estimates[k], intervals[k], phase.lambda_envelope_m[k])
    est = np.exp(best)
    # λ_att: 1/λ_att = 1/λ_abs + 1/λ_sca, with d(1/λ)/d(ln λ) = -1/λ.
    u = 1.0 / est
    cov_u = np.diag(-u) @ cov @ np.diag(-u)
    lam_att = 1.0 / (u[0] + u[1])
    lam_att_err = lam_att**2 * math.sqrt(max(float(cov_u.sum()), 0.0))
    corr = float(cov[0, 1] / (sigma[0] * sigma[1]))
    span = np.maximum(3.2 * np.log([iv[1] / iv[0] for iv in intervals]) / 2.0, 0.02)
    raw = obj.contour(best, span, chi2_min, config.contour_points)
    contour = ContourMap(raw.lambda_abs_m, raw.lambda_sca_m, raw.delta_chi2 / scale**2)
    att = (lam_att, lam_att_err, corr)
    fit = _result(wavelength_nm, prob, est, intervals, estimates, scale, att, edges, contour)
    return replace(fit, ndof=ndof, phase=phase)


def _refit_at_best_phase(obj: Objective, pmap: PhaseMap, cfg: PhaseConfig) -> np.ndarray:
    """Set the problem to the map's best phase function and refit the lengths there."""
    located, _ = phase_estimates(pmap, 1.0, (0.01, 0.01), cfg)
    g, f = located.best
    i = int(np.argmin(np.abs(pmap.mie_g - g)))
    j = int(np.argmin(np.abs(pmap.rayleigh_share - f)))
    start = pmap.ln_lambda[:, j, i].copy()
    start[1] += math.log((1 - pmap.mie_g[i]) / (1 - g))
    obj.prob.set_phase(g, f)
    return obj.minimise(start, near=True)


def _widened(
    est: Estimate, interval: tuple[float, float], envelope: tuple[float, float] | None
) -> tuple[Estimate, tuple[float, float]]:
    """A measured length's interval widened to its envelope over the phase functions the data allow."""
    if est.status != MEASURED or envelope is None:
        return est, interval
    lo, hi = min(interval[0], envelope[0]), max(interval[1], envelope[1])
    return replace(est, interval_m=(lo, hi), err_m=0.5 * (hi - lo)), (lo, hi)


def _result(
    wavelength_nm: int,
    prob: Problem,
    est: np.ndarray,
    intervals: list[tuple[float, float]],
    estimates: list[Estimate],
    scale: float,
    att: tuple[float, float, float],
    edges: list[str],
    contour: ContourMap,
) -> ChiSquareFit:
    chi2_val, info = prob.chi2(float(est[0]), float(est[1]), detail=True)
    shifts = np.asarray(info["shifts"])
    nuis = tuple(
        Nuisance(NUISANCES[k], UNITS[NUISANCES[k]], float(shifts[k]), float(prob.prior_sigma[k]))
        for k in prob.active
        if k < len(NUISANCES)
    )
    fit_arr, err_arr, halo_arr = (np.asarray(info[k]) for k in ("fit", "err", "halo"))
    models = tuple(
        SettingModel(
            s.exposure_s,
            s.gain_db,
            prob.radius_px,
            prob.data[i],
            err_arr[i],
            fit_arr[i],
            halo_arr[i],
            prob.used[i],
        )
        for i, s in enumerate(prob.settings)
    )
    lam_att, lam_att_err, corr = att
    return ChiSquareFit(
        wavelength_nm=int(wavelength_nm),
        lambda_abs_m=float(est[0]),
        lambda_abs_err_m=0.5 * (intervals[0][1] - intervals[0][0]),
        lambda_abs_interval_m=intervals[0],
        lambda_sca_m=float(est[1]),
        lambda_sca_err_m=0.5 * (intervals[1][1] - intervals[1][0]),
        lambda_sca_interval_m=intervals[1],
        lambda_sca_sys_err_m=float(est[1]) * prob.config.lambda_sca_sys_rel,
        lambda_att_m=lam_att,
        lambda_att_err_m=lam_att_err,
        correlation=corr,
        chi2=float(chi2_val),
        ndof=prob.n_bins() - prob.n_linear() - 2,
        mie_g=prob.mie_g,
        rayleigh_share=prob.rayleigh_share,
        nuisances=nuis,
        at_edge=tuple(sorted(set(edges))),
        contour=contour,
        settings=models,
        geometry=prob.geometry,
        emission_ratio=prob.ratio,
        config=prob.config,
        focal_px=prob.focal_px,
        templates=prob.grid.settings,
        n_evaluations=prob.n_eval,
        lambda_abs=estimates[0],
        lambda_sca=estimates[1],
        error_scale=scale,
    )
