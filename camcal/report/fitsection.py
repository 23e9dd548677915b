"""The report's absorption-and-scattering section: the kept χ² fit, its budget and its flags."""

from __future__ import annotations

from typing import Any

from analysis.chisq.results import cases_text
from camcal.fitdoc import estimate_text
from camcal.fitplots import contour_figure, profiles_figure
from camcal.report import figures
from camcal.report.collect import ReportData
from camcal.report.html import Raw, esc, figure, iso, note, num, section, table


def fit_section(d: ReportData) -> str:
    name, data = d.dive["name"], d.data_dir
    how = (
        f"<pre>camcal fit --dive {esc(name)} --data {esc(data)}\n"
        f"camcal report {esc(name)} --data {esc(data)}</pre>"
        "<p>The first fits λ_abs and λ_sca per wavelength to the station's radial profiles (photon-transport "
        "templates are built once and cached: a few minutes) and keeps the result in the store; the second "
        "writes this report again with it.</p>"
    )
    if d.fit is None:
        return section(
            "absorption-scattering", note("No χ² fit has been kept for this dive yet. To make one:") + how
        )
    doc = d.fit["result"]
    fits = doc.get("fits", [])
    rows = []
    for f in fits:
        z = f.get("att_check_z")
        if z is None:
            verdict = "—"
        elif f["att_check_agrees"]:
            verdict = f'<span class="ok">agrees ({z:+.1f}σ)</span>'
        elif f.get("att_check_flagged"):
            verdict = f'<span class="bad"><b>flagged</b> ({z:+.1f}σ)</span>'
        else:
            verdict = f'<span class="bad">differs ({z:+.1f}σ)</span>'
        if f.get("nuisance_check_flagged"):
            verdict += '<br><span class="bad"><b>flagged</b>: a calibration pulled &gt; 3σ</span>'
        scale = f.get("error_scale") or 1.0
        rows.append(
            (
                f"{f['wavelength_nm']} nm",
                _two_lines(estimate_text(f, "lambda_abs")),
                _two_lines(estimate_text(f, "lambda_sca")),
                f"{num(f['lambda_att_fit_m'])} ± {num(f['lambda_att_fit_err_m'])}",
                f"{num(f['lambda_att_icenter_m'])} ± {num(f['lambda_att_icenter_err_m'])}",
                Raw(verdict),
                Raw(
                    f"{f['chi2']:.0f}/{f['ndof']}"
                    + (f'<br><span class="muted">errors ×{scale:.2f}</span>' if scale > 1 else "")
                ),
            )
        )
    span = d.fit["span"] or {}
    inputs = doc.get("inputs", {})
    tmpl = inputs.get("templates", {})
    body = (
        f"<p>Fit {d.fit['id']}, made {iso(d.fit['created_unix_s'])} "
        f"with camcal {esc(d.fit['software_version'])} "
        f"from run {d.fit['run_id']}'s inputs over {span.get('n_frames', '?')} frames at depth ≥ "
        f"{num(span.get('depth_min_m'), 1)} m. Templates: ⟨cos θ⟩ {tmpl.get('mie_g_nodes')}, Rayleigh share "
        f"{tmpl.get('rayleigh_fraction')}, {tmpl.get('n_photons')} photons per λ_sca node "
        f"{tmpl.get('lambda_sca_nodes_m')} m. Each length is a value (with a systematic budget, the mean "
        "over the template samples its refits used) ± the fit's error (statistical and the "
        "floated nuisances, multiplied by √(χ²/ndof) where that exceeds 1) ± the systematic error, or a "
        "one-sided 95 % CL limit where the data only bound it. The check compares 1/λ_abs + 1/λ_sca with "
        "the I_center λ_att of the same frames (agrees within 2σ; flagged beyond 3σ); a fit that moved a "
        "calibrated nuisance (I0'/I0, a distance, the PSF) beyond 3σ of its calibration is flagged too.</p>"
    )
    poor = [f"{f['wavelength_nm']} nm" for f in fits if f["ndof"] and f["chi2"] / f["ndof"] > 2]
    if poor:
        body += note(
            f"χ²/ndof is well above 1 at {', '.join(poor)}: the templates do not describe these profiles "
            "within their errors. The fit errors were scaled by √(χ²/ndof), but the lengths may still "
            "carry the model's bias: look at the pulls below and at the systematic budget."
        )
    if d.fit["run_id"] != d.run["id"]:
        body += note(
            f"This fit used run {d.fit['run_id']}'s inputs, not run {d.run['id']}'s shown elsewhere."
        )
    for f in fits:
        if f.get("att_check_flagged") and f.get("att_check_advice"):
            body += note(f"<b>{f['wavelength_nm']} nm flagged.</b> {esc(f['att_check_advice'])}")
        if f.get("nuisance_check_flagged") and f.get("nuisance_check_advice"):
            advice = f["nuisance_check_advice"]
            body += note(f"<b>{f['wavelength_nm']} nm flagged.</b> {esc(advice[0].upper() + advice[1:])}")
    body += table(
        [
            "wavelength",
            "λ_abs [m] (fit, sys)",
            "λ_sca [m] (fit, sys)",
            "λ_att fit [m]",
            "λ_att I_center [m]",
            "check",
            "χ²/ndof",
        ],
        rows,
    )
    nuis = [
        (
            f"{f['wavelength_nm']} nm",
            n["name"],
            n["unit"],
            f"{n['shift']:+.4g}",
            f"{n['sigma']:.4g}",
            f"{n['pull']:+.2f}",
        )
        for f in fits
        for n in f["nuisances"]
    ]
    if nuis:
        body += (
            "<details><summary>nuisance parameters (shift from nominal, prior width, pull)</summary>"
            + table(["wavelength", "nuisance", "unit", "shift", "prior σ", "pull"], nuis, text_cols=3)
            + "</details>"
        )
    body += _budgets(fits)
    for f in fits:
        if "contour" in f:
            body += f"<h3>{f['wavelength_nm']} nm</h3>"
            body += figure(
                figures.png_uri(contour_figure(f)),
                "Δχ² over (λ_abs, λ_sca), profiled over the "
                "nuisances: the joint 68 % (solid) and 95 % (dashed) regions, the fit with its one-"
                "parameter errors, and the I_center λ_att ± error (green).",
                "chi-square contours",
            )
            if f.get("profiles"):
                body += figure(
                    figures.png_uri(profiles_figure(f)),
                    "Both cameras' radial profiles "
                    "(normalised by the near camera's sum) with the fitted model and the pulls.",
                    "profile fit",
                )
    for wl, why in sorted(doc.get("skipped", {}).items()):
        body += note(f"{esc(wl)} nm not fitted: {esc(why)}")
    body += "<details><summary>how to fit again</summary>" + how + "</details>"
    return section("absorption-scattering", body)


_FLOATED = "floated in the fit: inside the fit error, not added. "


def _errors(item: dict[str, Any], *keys: str) -> list[str]:
    """A budget line's errors on the three lengths: "0.300" or "+4.100/−0.900" (asymmetric)."""
    if "errors_text" in item:
        return [t.removeprefix("± ") for t in item["errors_text"]]
    return [num(item[k], 3) for k in keys]


def _two_lines(text: str) -> Raw:
    """A length's text with its systematic part (or "no budget") on a second line.

    "39.20 ± 1.10 ± 0.30 (sys) m" in one unbreakable cell made the fit table
    wider than the page (its χ²/ndof column cut off at ~1000 px).
    """
    if " (no budget)" in text:
        head, tail = text.split(" (no budget)", 1)
        return Raw(f'{esc(head)}{esc(tail)}<br><span class="muted">no budget</span>')
    parts = text.split(" ± ")
    if len(parts) == 3:
        return Raw(f'{esc(parts[0])} ± {esc(parts[1])}<br><span class="muted">± {esc(parts[2])}</span>')
    if len(parts) == 2 and " +" in parts[1]:  # "39.20 ± 1.10 +4.10/−0.90 (sys) m"
        err, sys = parts[1].split(" +", 1)
        return Raw(f'{esc(parts[0])} ± {esc(err)}<br><span class="muted">+{esc(sys)}</span>')
    return Raw(esc(text))


def _budgets(fits: list[dict[str, Any]]) -> str:
    """Each wavelength's systematic budget as a table (nothing for documents without one)."""
    out = ""
    for f in fits:
        b = f.get("systematics")
        if not b:
            continue
        rows = [
            (
                i["label"],
                cases_text(i["cases"]),
                (_FLOATED if i["profiled"] else "") + i["note"],
                *_errors(i, "lambda_abs_err_m", "lambda_sca_err_m", "lambda_att_err_m"),
            )
            for i in b["items"]
        ]
        rows.append(
            (
                Raw("<b>sum in quadrature</b>"),
                "",
                f"refits took {num(b['seconds'], 1)} s",
                *(
                    [t.removeprefix("± ") for t in b["sys_text"]]
                    if "sys_text" in b
                    else [num(b[k], 3) for k in ("lambda_abs_sys_m", "lambda_sca_sys_m", "lambda_att_sys_m")]
                ),
            )
        )
        head = ["varied", "cases", "note", "λ_abs [m]", "λ_sca [m]", "λ_att [m]"]
        out += f"<h3>{f['wavelength_nm']} nm: systematic budget</h3>" + table(head, rows, text_cols=3)
    if out:
        out = (
            "<p>What the fit holds fixed, varied: each line's error on the lengths. ⟨cos θ⟩ and the "
            "Rayleigh share are varied together over a grid of refits, and their line's error is the "
            "RMS shift over a uniform prior on that box, split into the RMS of the upward and of the "
            "downward shifts (+up/−down: where λ_sca could fall to λ_att, λ_abs may lie far above the "
            "value); the values quoted above stay at the nominal phase function. The emission shape: "
            "the full shift. The sums in quadrature, each side on its own, are the systematic errors "
            "quoted above.</p>" + out
        )
    return out
