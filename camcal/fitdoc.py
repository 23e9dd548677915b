"""The ``camcal fit --json`` document: per wavelength the values or limits, errors, budget and checks."""

from __future__ import annotations

import math
from dataclasses import asdict
from typing import Any

import numpy as np

from analysis.chisq import ChiSquareFit, Estimate, SystematicBudget
from analysis.chisq.phase_results import PHASE_FIXED, PhaseFit
from analysis.chisq.quality import fit_quality
from analysis.chisq.results import cases_text, sys_text
from camcal.core import __version__
from camcal.fitset import AttenuationCheck, FolderFit


def _r(x: float | None, digits: int = 4) -> float | None:
    return None if x is None or not math.isfinite(x) else round(float(x), digits)


def _sig(values: Any, digits: int = 5) -> Any:
    """Nested lists of floats at ``digits`` significant digits; NaN and inf become None."""
    arr = np.asarray(values, dtype=np.float64)
    if arr.ndim == 0:
        x = float(arr)
        return float(f"{x:.{digits}g}") if math.isfinite(x) else None
    return [_sig(v, digits) for v in arr]


def fit_detail(fit: ChiSquareFit) -> dict[str, Any]:
    """The Δχ² map and each setting's normalised profiles (data, error, model, halo, bands used)."""
    c = fit.contour
    return {
        "contour": {
            "lambda_abs_m": _sig(c.lambda_abs_m),
            "lambda_sca_m": _sig(c.lambda_sca_m),
            "delta_chi2": _sig(c.delta_chi2, 4),
        },
        "profiles": [
            {
                "exposure_s": m.exposure_s,
                "gain_db": m.gain_db,
                "radius_px": _sig(m.radius_px),
                "data": _sig(m.data),
                "error": _sig(m.error, 3),
                "model": _sig(m.model),
                "halo": _sig(m.halo),
                "used": np.asarray(m.used, dtype=bool).tolist(),
            }
            for m in fit.settings
        ],
    }


def quality_entry(f: ChiSquareFit) -> dict[str, Any]:
    """χ²/ndof, χ² per radial band, and the verdicts (`analysis.chisq.quality`)."""
    q = fit_quality(f)
    return {
        "chi2_ndof": _r(q.chi2_ndof, 3),
        "chi2_bands": [b.to_dict() for b in q.bands],
        "fit_failed": q.failed,
        "chi2_concentrated": q.concentrated,
        "fit_quality_ok": q.ok,
        "fit_quality_reason": q.reason or None,
    }


def phase_entry(f: ChiSquareFit) -> dict[str, Any]:
    """The phase function: measured (values, errors, limits, Δχ² map) or the values the fit held fixed.

    ``mean_cos_theta`` is (1 - Rayleigh share)·(Mie ⟨cos θ⟩): Rayleigh
    scattering's mean cosine is 0. A parameter the fit held fixed says so
    (``g_mie_fixed``) and carries no error.
    """
    p: PhaseFit | None = f.phase
    if p is None:
        return {
            "g_mie": f.mie_g,
            "g_mie_err": None,
            "g_mie_fixed": True,
            "rayleigh_share": f.rayleigh_share,
            "rayleigh_share_err": None,
            "rayleigh_share_fixed": True,
            "mean_cos_theta": _r((1.0 - f.rayleigh_share) * f.mie_g, 5),
            "mean_cos_theta_err": None,
            "phase_case": PHASE_FIXED,
            "phase_case_text": (
                f"phase function held fixed at Mie ⟨cos θ⟩ {f.mie_g:g}, Rayleigh share {f.rayleigh_share:g} "
                "(not measured: its spread is in the systematic budget)"
            ),
            "phase": None,
            "phase_map": None,
            "g_mie_sys_err": None,
            "rayleigh_share_sys_err": None,
        }
    m = p.map
    return {
        "g_mie": _r(p.mie_g.value, 5),
        "g_mie_err": _r(p.mie_g.err, 5),
        "g_mie_sys_err": None,
        "g_mie_fixed": False,
        "rayleigh_share": _r(p.rayleigh_share.value, 4),
        "rayleigh_share_err": _r(p.rayleigh_share.err, 4),
        "rayleigh_share_sys_err": None,
        "rayleigh_share_fixed": False,
        "mean_cos_theta": _r(p.mean_cos_theta.value, 5),
        "mean_cos_theta_err": _r(p.mean_cos_theta.err, 5),
        "phase_case": p.case,
        "phase_case_text": p.case_text,
        "phase": {
            "best": [_r(p.best[0], 5), _r(p.best[1], 4)],
            "g_mie": p.mie_g.to_dict(),
            "rayleigh_share": p.rayleigh_share.to_dict(),
            "mean_cos_theta": p.mean_cos_theta.to_dict(),
            "corr_g_mie_lambda_sca": _r(p.corr_lambda_sca[0], 3),
            "corr_rayleigh_share_lambda_sca": _r(p.corr_lambda_sca[1], 3),
            "lambda_envelope_m": [list(e) if e else None for e in p.lambda_envelope_m],
        },
        "phase_map": {
            "g_mie": _sig(m.mie_g),
            "rayleigh_share": _sig(m.rayleigh_share),
            "dchi2": _sig(p.delta_chi2, 4),
            "lambda_abs_m": _sig(np.exp(m.ln_lambda[0]), 4),
            "lambda_sca_m": _sig(np.exp(m.ln_lambda[1]), 4),
            "best": [_r(p.best[0], 5), _r(p.best[1], 4)],
        },
    }


#: What a length's entry says in ``systematics`` when the fit was made without its budget.
NO_BUDGET = "no budget"


def estimate_entry(
    e: Estimate, sys_err_m: float, *, budget: bool = True, sys_down_up_m: tuple[float, float] | None = None
) -> dict[str, Any]:
    """One length: a value with its errors, or a one-sided limit (then ``value_m`` is null).

    ``sys_err_m`` is the systematic error's RMS, ``sys_down_up_m`` its
    downward and upward parts (`SystematicBudget.sys_down_m`; equal to
    ``sys_err_m`` when not given). ``budget=False`` (a fit made with
    ``--no-systematics``): the systematic errors are null and
    ``systematics`` says "no budget", so no reader prints ± 0.00.
    """
    quoted = e.measured and budget
    down, up = sys_down_up_m or (sys_err_m, sys_err_m)
    return {
        "status": e.status,
        "value_m": _r(e.value_m, 3),
        "err_m": _r(e.err_m, 3),
        "sys_err_m": _r(sys_err_m, 3) if quoted else None,
        "sys_err_down_m": _r(down, 3) if quoted else None,
        "sys_err_up_m": _r(up, 3) if quoted else None,
        "sys_text": sys_text(up, down) if quoted else None,  # "± 0.30" or "+4.10/−0.90", for pages
        "systematics": "budget" if budget else NO_BUDGET,
        "interval_m": [_r(v, 3) for v in e.interval_m] if e.interval_m else None,
        "limit_m": _r(e.limit_m, 3),
        "cl": e.cl,
    }


def estimate_text(entry: dict[str, Any], key: str, digits: int = 2) -> str:
    """``"39.20 ± 1.10 ± 0.30 (sys) m"`` (``+4.10/−0.90 (sys)`` where the systematic error is
    asymmetric), ``"> 180 m (95 % CL)"`` or ``"unconstrained"`` from a fit entry.

    ``key`` is ``"lambda_abs"`` or ``"lambda_sca"``; documents written before
    the estimates existed fall back to their flat keys.
    """
    e = entry.get(key)
    if e is None:
        value, err = entry.get(f"{key}_m"), entry.get(f"{key}_err_m")
        e = {"status": "measured", "value_m": value, "err_m": err, "sys_err_m": entry.get(f"{key}_sys_err_m")}
    if e["status"] == "measured" and e.get("value_m") is not None:
        if e.get("systematics") == NO_BUDGET:
            sys_txt = f" ({NO_BUDGET})"
        elif e.get("sys_err_up_m") is not None and e.get("sys_err_down_m") is not None:
            sys_txt = f" {sys_text(e['sys_err_up_m'], e['sys_err_down_m'], digits)} (sys)"
        elif e.get("sys_err_m") is not None:
            sys_txt = f" ± {e['sys_err_m']:.{digits}f} (sys)"
        else:
            sys_txt = ""
        err = e.get("err_m")
        err_txt = f" ± {err:.{digits}f}" if err is not None else ""
        return f"{e['value_m']:.{digits}f}{err_txt}{sys_txt} m"
    if e["status"] in ("lower_limit", "upper_limit"):
        sign = ">" if e["status"] == "lower_limit" else "<"
        return f"{sign} {e['limit_m']:.3g} m ({100 * (e.get('cl') or 0.95):.0f} % CL)"
    return "unconstrained"


def budget_entry(b: SystematicBudget) -> dict[str, Any]:
    """The systematic budget: each item's shifts per case and error, and the sums in quadrature."""
    return {
        "items": [
            {
                "name": i.name,
                "label": i.label,
                "cases": list(i.cases),
                "cases_text": cases_text(i.cases),
                "lambda_abs_shift_m": [_r(v, 3) for v in i.lambda_abs_shifts_m],
                "lambda_sca_shift_m": [_r(v, 3) for v in i.lambda_sca_shifts_m],
                "lambda_att_shift_m": [_r(v, 3) for v in i.lambda_att_shifts_m],
                "delta_chi2": [_r(v, 2) for v in i.delta_chi2],
                "lambda_abs_err_m": _r(i.lambda_abs_m, 3),
                "lambda_sca_err_m": _r(i.lambda_sca_m, 3),
                "lambda_att_err_m": _r(i.lambda_att_m, 3),
                "errors_up_m": [_r(v, 3) for v in i.up_m],
                "errors_down_m": [_r(v, 3) for v in i.down_m],
                "errors_text": [sys_text(u, d, 3) for u, d in zip(i.up_m, i.down_m, strict=True)],
                "profiled": i.profiled,
                "note": i.note,
            }
            for i in b.items
        ],
        "lambda_abs_sys_m": _r(b.lambda_abs_sys_m, 3),
        "lambda_sca_sys_m": _r(b.lambda_sca_sys_m, 3),
        "lambda_att_sys_m": _r(b.lambda_att_sys_m, 3),
        "sys_up_m": [_r(b.sys_up_m(k), 3) for k in range(3)],
        "sys_down_m": [_r(b.sys_down_m(k), 3) for k in range(3)],
        "sys_text": [sys_text(b.sys_up_m(k), b.sys_down_m(k), 3) for k in range(3)],
        # λ_abs, λ_sca, λ_att: how far the quoted values lie from the nominal templates' minimum
        # (the mean over the template samples; see the template_sample item)
        "sample_move_m": [_r(v, 3) for v in b.sample_move_m],
        "seconds": _r(b.seconds, 2),
    }


def fit_entry(f: ChiSquareFit, chk: AttenuationCheck) -> dict[str, Any]:
    """One wavelength's fit as ``camcal fit --json`` writes it (the report and the figures read it).

    ``lambda_abs``/``lambda_sca`` hold what to quote (`estimate_entry`); the
    flat ``lambda_*_m`` keys repeat a measured value and are null for a
    limit, and ``best_fit_m`` is the χ² minimum's position (on the grid's
    edge for a limit: for plots, not for quoting), the flat
    ``lambda_*_interval_m`` the Δχ² crossings around it. With a budget the
    quoted values (and each estimate's ``interval_m``) lie
    ``systematics.sample_move_m`` from those (the mean over the template
    samples); the contour plot keeps the χ² map's own. Errors are the fit's
    (statistical and the floated nuisances), already multiplied by
    ``error_scale``; ``*_sys_err_m`` the systematic errors.
    """
    ab, sc = f.lambda_abs, f.lambda_sca
    return {
        "wavelength_nm": f.wavelength_nm,
        "lambda_abs": estimate_entry(
            ab, f.lambda_abs_sys_err_m, budget=f.systematics is not None, sys_down_up_m=f.sys_interval_m(0)
        ),
        "lambda_sca": estimate_entry(
            sc, f.lambda_sca_sys_err_m, budget=f.systematics is not None, sys_down_up_m=f.sys_interval_m(1)
        ),
        "lambda_abs_m": _r(ab.value_m, 3),
        "lambda_abs_err_m": _r(ab.err_m, 3),
        "lambda_abs_sys_err_m": _r(f.lambda_abs_sys_err_m, 3) if ab.measured else None,
        "lambda_abs_interval_m": [_r(v, 3) for v in f.lambda_abs_interval_m],
        "lambda_sca_m": _r(sc.value_m, 3),
        "lambda_sca_err_m": _r(sc.err_m, 3),
        "lambda_sca_interval_m": [_r(v, 3) for v in f.lambda_sca_interval_m],
        "lambda_sca_sys_err_m": _r(f.lambda_sca_sys_err_m, 3) if sc.measured else None,
        "best_fit_m": [_r(f.lambda_abs_m, 3), _r(f.lambda_sca_m, 3)],
        "correlation": _r(f.correlation),
        "error_scale": _r(f.error_scale, 3),
        "errors_scaled": f.error_scale > 1.0,
        "lambda_att_fit_m": _r(chk.lambda_att_fit_m, 3),
        "lambda_att_fit_err_m": _r(chk.lambda_att_fit_err_m, 3),
        "lambda_att_sys_err_m": _r(f.lambda_att_sys_err_m, 3),
        "lambda_att_icenter_m": _r(chk.lambda_att_icenter_m, 3),
        "lambda_att_icenter_err_m": _r(chk.lambda_att_icenter_err_m, 3),
        "att_check_z": _r(chk.z, 3),
        "att_check_agrees": chk.agrees,
        "att_check_flagged": chk.flagged,
        "att_check_advice": chk.advice,
        "nuisance_check_flagged": chk.nuisances_flagged,
        "nuisance_check_advice": chk.nuisance_advice,
        # the data-allowed phase refit that keeps every calibration within 3σ: case, Δχ²/s², largest pull
        "nuisance_check_relief": list(chk.relief) if chk.relief else None,
        "chi2": _r(f.chi2, 2),
        "ndof": f.ndof,
        **quality_entry(f),
        "mie_g": f.mie_g,
        **phase_entry(f),
        "at_edge": list(f.at_edge),
        "systematics": budget_entry(f.systematics) if f.systematics else None,
        "nuisances": [
            {
                "name": n.name,
                "unit": n.unit,
                "shift": _r(n.shift, 5),
                "sigma": _r(n.sigma, 5),
                "pull": _r(n.pull, 3),
            }
            for n in f.nuisances
        ],
        "settings": [{"exposure_s": s.exposure_s, "gain_db": s.gain_db} for s in f.settings],
        "n_evaluations": f.n_evaluations,
        **fit_detail(f),
    }


def to_json(result: FolderFit) -> dict[str, Any]:
    """The ``camcal fit --json`` document."""
    out = [fit_entry(f, result.checks[wl]) for wl, f in sorted(result.fits.items())]
    return {
        "fits": out,
        "skipped": {str(k): v for k, v in sorted(result.skipped.items())},
        "notes": {str(k): v for k, v in sorted(result.notes.items())},
        "has_result": result.has_result,
        "inputs": {
            "folder": str(result.analysis.folder),
            "setup": result.analysis.setup.to_json(),
            "geometry": asdict(result.geometry),
            "templates": asdict(result.templates),
            "fit": asdict(result.options.fit),
            "systematics": asdict(result.options.systematics) if result.options.systematics else None,
        },
        "software": {"name": "camcal", "version": __version__},
    }


__all__ = ["budget_entry", "estimate_entry", "estimate_text", "fit_detail", "fit_entry", "to_json"]
