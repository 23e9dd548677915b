"""The dive report as one self-contained HTML page: inline CSS, figures as inline PNG, no script.

Nothing is fetched when the page opens (no fonts, scripts, styles or images
from anywhere), so it reads the same from a USB stick, an e-mail attachment
or a ship without internet, and prints as it shows.
"""

from __future__ import annotations

import html
import math
import statistics
from collections.abc import Iterable, Sequence
from datetime import UTC, datetime
from typing import Any

from camcal.fitplots import contour_figure, profiles_figure
from camcal.report import figures
from camcal.report.collect import ReportData

SECTIONS = (
    ("summary", "Summary"),
    ("timeline", "Timeline"),
    ("quality", "Frame quality"),
    ("linearity", "Linearity"),
    ("attitude", "Attitude"),
    ("attenuation", "Attenuation length λ_att"),
    ("absorption-scattering", "Absorption and scattering"),
    ("calibration", "Calibration inputs"),
    ("software", "Software and provenance"),
)

CSS = """
:root { --ink: #1d2330; --muted: #5b6474; --rule: #d5dae3; --bg: #f6f8fb; --ok: #1e7b34; --bad: #b3261e; }
* { box-sizing: border-box; }
body { font: 15px/1.45 system-ui, -apple-system, "Segoe UI", Roboto, "Helvetica Neue", Arial, sans-serif;
       color: var(--ink); margin: 0; background: #fff; }
main { max-width: 1040px; margin: 0 auto; padding: 1.2rem 1.4rem 3rem; }
header { border-bottom: 3px solid var(--ink); padding-bottom: .6rem; margin-bottom: 1rem; }
h1 { font-size: 1.6rem; margin: 0 0 .2rem; }
h2 { font-size: 1.25rem; margin: 2.2rem 0 .6rem; padding-top: .4rem; border-top: 1px solid var(--rule); }
h3 { font-size: 1.02rem; margin: 1.2rem 0 .4rem; }
.muted, figcaption { color: var(--muted); font-size: .88rem; }
nav ol { columns: 3; margin: .4rem 0 0; padding-left: 1.3rem; }
table { border-collapse: collapse; margin: .4rem 0 .8rem; font-size: .9rem; }
th, td { border-bottom: 1px solid var(--rule); padding: .25rem .6rem; text-align: right;
         vertical-align: top; }
th { background: var(--bg); font-weight: 600; }
th:first-child, td:first-child, td.text, th.text { text-align: left; }
td.num { font-variant-numeric: tabular-nums; white-space: nowrap; }
.scroll { overflow-x: auto; }
figure { margin: .6rem 0 1rem; page-break-inside: avoid; }
figure img { max-width: 100%; height: auto; border: 1px solid var(--rule); }
.ok { color: var(--ok); font-weight: 600; } .bad { color: var(--bad); font-weight: 600; }
.note { background: var(--bg); border-left: 4px solid var(--muted); padding: .5rem .8rem; margin: .6rem 0; }
code, pre { font-family: ui-monospace, "SFMono-Regular", Menlo, Consolas, monospace; font-size: .86rem; }
pre { background: var(--bg); padding: .5rem .8rem; overflow-x: auto; }
details { margin: .4rem 0; } summary { cursor: pointer; color: var(--muted); }
@media print { nav { display: none; } h2 { page-break-after: avoid; } main { max-width: none; } }
"""


def esc(x: object) -> str:
    return html.escape(str(x), quote=True)


def num(x: float | None, digits: int = 2) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "—"
    return f"{x:.{digits}f}"


def iso(t: float | None) -> str:
    if t is None:
        return "—"
    return datetime.fromtimestamp(t, UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def table(headers: Sequence[str] | None, rows: Iterable[Sequence[object]], *, text_cols: int = 1) -> str:
    """A table (no header row if ``headers`` is None); cells are escaped unless wrapped in `Raw`; the
    first ``text_cols`` columns align left."""

    def cell(i: int, v: object) -> str:
        cls = "text" if i < text_cols else "num"
        return f'<td class="{cls}">{v.html if isinstance(v, Raw) else esc(v)}</td>'

    body = "".join("<tr>" + "".join(cell(i, v) for i, v in enumerate(r)) + "</tr>" for r in rows)
    if headers is None:
        return f'<div class="scroll"><table><tbody>{body}</tbody></table></div>'
    head = "".join(
        f'<th class="{"text" if i < text_cols else ""}">{esc(h)}</th>' for i, h in enumerate(headers)
    )
    return f'<div class="scroll"><table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table></div>'


class Raw:
    """Trusted HTML for a table cell."""

    def __init__(self, html_text: str) -> None:
        self.html = html_text


def figure(uri: str, caption: str, alt: str) -> str:
    return f'<figure><img src="{uri}" alt="{esc(alt)}"><figcaption>{esc(caption)}</figcaption></figure>'


def note(text_html: str) -> str:
    return f'<p class="note">{text_html}</p>'


def section(sid: str, body: str) -> str:
    title = dict(SECTIONS)[sid]
    return f'<section id="{sid}"><h2>{esc(title)}</h2>{body}</section>'


# ---------------------------------------------------------------- sections
def _summary(d: ReportData) -> str:
    dv = d.dive
    t0, t1 = dv["first_frame_unix_s"], dv["last_frame_unix_s"]
    dur = f"{(t1 - t0) / 60:.1f} min" if t0 is not None and t1 is not None else "—"
    facts = [
        ("dive", f"{dv['name']} (id {dv['id']})"),
        ("started / ended", f"{iso(dv['started_unix_s'])} / {iso(dv['ended_unix_s'])}"),
        ("frames", f"{dv['n_frames']} from {iso(t0)} to {iso(t1)} ({dur})"),
        ("deepest frame", f"{num(dv['max_depth_m'], 1)} m"),
        (
            "station span",
            f"frames at depth ≥ {num(d.span['depth_min_m'], 1)} m ({d.span['n_frames']} frames)",
        ),
        ("analysis run", f"{d.run['id']} ({d.run['kind']}{', ' + d.run['label'] if d.run['label'] else ''})"),
        ("calibration", _calibration_name(d)),
    ]
    att = table(
        ["wavelength", "λ_att [m]", "stat [m]", "sys [m]"],
        [
            (f"{r['wavelength_nm']} nm", num(r["lambda_att_m"]), num(r["stat_err_m"]), num(r["sys_err_m"]))
            for r in d.attenuation
        ],
    )
    fit_line = "no χ² fit kept yet (see below)"
    if d.fit:
        fits = d.fit["result"].get("fits", [])
        fit_line = (
            "; ".join(
                f"{f['wavelength_nm']} nm: λ_abs {num(f['lambda_abs_m'], 1)} m, "
                f"λ_sca {num(f['lambda_sca_m'], 1)} m"
                for f in fits
            )
            or "the kept fit holds no wavelength"
        )
    return section(
        "summary",
        table(None, facts, text_cols=2)
        + "<h3>λ_att at the station (I_center method)</h3>"
        + (att if d.attenuation else note("No wavelength has near and far frames at the station."))
        + f"<p><b>Absorption and scattering:</b> {esc(fit_line)}</p>",
    )


def _calibration_name(d: ReportData) -> str:
    c = d.calibration
    if c is None:
        return "the run's own inputs (no calibration record)"
    return f"{c['name']} v{c['version']} (record {c['id']})"


def _cleared(a: dict[str, Any]) -> str:
    if a["cleared_unix_s"]:
        return iso(a["cleared_unix_s"])
    return "still active" if a["active"] else "—"


def _timeline(d: ReportData) -> str:
    t0 = d.dive["first_frame_unix_s"] or d.dive["started_unix_s"]
    t1 = d.dive["last_frame_unix_s"] or d.dive["ended_unix_s"] or t0
    alarms = [a for a in d.timeline["alarms"] if t0 - 3600 <= a["raised_unix_s"] <= t1 + 3600]
    if not d.frames and not any(ser["n_samples"] for ser in d.sensors.values()):
        return section("timeline", note("No frame and no sensor sample of this dive is stored."))
    body = figure(
        figures.timeline(d.sensors, d.frames, alarms),
        "Depth of each module over the dive (lines, from its pressure sensor), every frame at its depth "
        "(dots: accepted, crosses: rejected) and the alarms (dashed: raised; shaded: until cleared, or to "
        "the end if still active).",
        "depth over time with frames and alarms",
    )
    if alarms:
        body += table(
            ["raised", "severity", "module", "kind", "message", "cleared", "acknowledged"],
            [
                (
                    iso(a["raised_unix_s"]),
                    a["severity"],
                    a["module"] or "—",
                    a["kind"],
                    a["message"],
                    _cleared(a),
                    f"{a['acked_by']} {iso(a['acked_unix_s'])}" if a["acked_by"] else "—",
                )
                for a in sorted(alarms, key=lambda a: a["raised_unix_s"])
            ],
            text_cols=5,
        )
    else:
        body += "<p>No alarm was raised during the dive.</p>"
    return section("timeline", body)


def _quality(d: ReportData) -> str:
    q = d.quality
    if not q:
        return section("quality", note("No frame of this run has been analysed."))
    reasons = ["ok", *sorted({r for c in q.values() for r in c} - {"ok"})]
    rows = []
    for m in sorted(q):
        total = sum(q[m].values())
        ok = q[m].get("ok", 0)
        rows.append(
            [m, *[q[m].get(r, 0) for r in reasons], total, f"{100.0 * ok / total:.0f} %" if total else "—"]
        )
    return section(
        "quality",
        figure(
            figures.quality(q),
            "Frames per module by outcome (the rejection reasons of docs/conventions.md).",
            "frame outcomes per module",
        )
        + table(
            ["module", *("accepted" if r == "ok" else r for r in reasons), "total", "accepted share"], rows
        ),
    )


def _fixed(c: dict[str, Any]) -> str:
    """What a sweep held fixed: the gain of an exposure sweep, the exposure of a gain sweep."""
    if c["fixed_value"] is None:
        return "—"
    return f"{c['fixed_value']:g} dB" if c["sweep"] == "exposure" else f"{c['fixed_value']:g} s"


def _linearity(d: ReportData) -> str:
    checks = d.linearity
    if not checks:
        return section(
            "linearity", note("No linearity fit yet: it needs three or more settings in the linear range.")
        )
    rows = [
        (
            c["module"],
            f"{c['wavelength_nm']} nm",
            c["sweep"],
            _fixed(c),
            f"{c['slope']:.4g}" + (f" ± {c['slope_err']:.2g}" if c["slope_err"] else ""),
            num(c["intercept_gray"]),
            f"{c['r2']:.5f}",
            c["n_used"],
            num(c["linear_max_gray"], 1),
            "—" if c["knee_x"] is None else f"{c['knee_x']:g}" + (" s" if c["sweep"] == "exposure" else "×"),
        )
        for c in checks
    ]
    return section(
        "linearity",
        figure(
            figures.linearity(checks),
            "Centre gray against exposure (gain fixed) or linear gain factor "
            "(exposure fixed): filled points enter the fit, open ones lie outside the linear range; dotted: "
            "the knee, the first setting where the response leaves the line; dashed: gray 240.",
            "linearity fits",
        )
        + table(
            [
                "module",
                "wavelength",
                "sweep",
                "fixed at",
                "slope",
                "intercept [gray]",
                "R²",
                "points",
                "linear up to [gray]",
                "knee",
            ],
            rows,
            text_cols=3,
        ),
    )


def _stats(values: Iterable[float | None]) -> tuple[float | None, float | None]:
    v = [x for x in values if x is not None and math.isfinite(x)]
    return (statistics.median(v), max(v)) if v else (None, None)


def _attitude(d: ReportData) -> str:
    if not any(a["t_unix_s"] for a in d.attitude.values()):
        return section("attitude", note("No attitude samples (the modules' sensors sent none)."))
    rows = []
    for m, a in sorted(d.attitude.items()):
        tilt = _stats(a.get("tilt_deg", []))
        rot = _stats(a.get("rotation_rate_dps", []))
        heave = _stats(a.get("heave_period_s", []))
        amp = _stats(a.get("heave_amplitude_m_s2", []))
        rows.append(
            (
                m,
                num(tilt[0]),
                num(tilt[1]),
                num(rot[0]),
                num(rot[1]),
                num(heave[0], 1),
                num(amp[0], 3),
                a["n_samples"],
            )
        )
    return section(
        "attitude",
        figure(
            figures.attitude(d.attitude),
            "Tilt from vertical, rotation rate and the heave period (from the "
            "vertical acceleration) of each module.",
            "attitude over time",
        )
        + table(
            [
                "module",
                "tilt median [°]",
                "tilt max [°]",
                "rotation median [°/s]",
                "rotation max [°/s]",
                "heave period median [s]",
                "heave amplitude median [m/s²]",
                "samples",
            ],
            rows,
        ),
    )


def _attenuation(d: ReportData) -> str:
    span = d.span
    head = (
        f"<p>Over the station: frames at depth ≥ {num(span['depth_min_m'], 1)} m "
        f"({span['n_frames']} frames), "
        "near/far pairs of equal exposure and gain combined per wavelength; statistical errors from the gray "
        "values, systematic from the distances and I0'/I0. This is the API's "
        f"<code>/api/dives/{d.dive['id']}/attenuation</code>.</p>"
    )
    rows = [
        (
            f"{r['wavelength_nm']} nm",
            num(r["lambda_att_m"]),
            num(r["stat_err_m"]),
            num(r["sys_err_m"]),
            num(r["total_err_m"]),
            r["n_pairs"],
            num(r["chi2_ndof"]),
            f"{r['emission_ratio']:.3f} ± {r['emission_ratio_err']:.3f}",
            r["note"] or "",
        )
        for r in d.attenuation
    ]
    body = head + (
        table(
            [
                "wavelength",
                "λ_att [m]",
                "stat [m]",
                "sys [m]",
                "total [m]",
                "pairs",
                "χ²/ndof",
                "I0'/I0",
                "note",
            ],
            rows,
        )
        if rows
        else note("No wavelength has near and far frames at the station.")
    )
    pairs = [
        (
            f"{r['wavelength_nm']} nm",
            f"{p['exposure_s']:g} s",
            f"{p['gain_db']:g} dB",
            num(p["i_near_gray"]),
            num(p["i_far_gray"]),
            f"{p['n_near']}/{p['n_far']}",
            num(p["lambda_att_m"]),
            num(p["stat_err_m"]),
        )
        for r in d.attenuation
        for p in r["pairs"]
    ]
    if pairs:
        body += (
            "<details><summary>the near/far pairs behind the table</summary>"
            + table(
                [
                    "wavelength",
                    "exposure",
                    "gain",
                    "I near [gray]",
                    "I far [gray]",
                    "frames",
                    "λ_att [m]",
                    "stat [m]",
                ],
                pairs,
                text_cols=3,
            )
            + "</details>"
        )
    if any(d.series.values()):
        body += figure(
            figures.attenuation_time(d.series),
            "λ_att per LEM visit (each point combines the frames of one visit of the LEM's "
            "colour, at their mean time) per wavelength: statistical error bars, shaded stat ⊕ sys.",
            "attenuation length over time",
        )
        body += figure(
            figures.attenuation_depth(d.series),
            "λ_att per LEM visit against the LEM's mean depth during the visit: "
            "the test stops and the station.",
            "attenuation length against depth",
        )
    else:
        body += note("No λ_att points were stored for this run.")
    return section("attenuation", body)


def _fit(d: ReportData) -> str:
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
        verdict = (
            "—"
            if z is None
            else (
                f'<span class="ok">agrees ({z:+.1f}σ)</span>'
                if f["att_check_agrees"]
                else f'<span class="bad">differs ({z:+.1f}σ)</span>'
            )
        )
        rows.append(
            (
                f"{f['wavelength_nm']} nm",
                f"{num(f['lambda_abs_m'])} ± {num(f['lambda_abs_err_m'])}",
                f"{num(f['lambda_sca_m'])} ± {num(f['lambda_sca_err_m'])} ± {num(f['lambda_sca_sys_err_m'])}",
                f"{num(f['lambda_att_fit_m'])} ± {num(f['lambda_att_fit_err_m'])}",
                f"{num(f['lambda_att_icenter_m'])} ± {num(f['lambda_att_icenter_err_m'])}",
                Raw(verdict),
                f"{f['chi2']:.0f}/{f['ndof']}",
                ", ".join(f["at_edge"]) or "—",
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
        f"{tmpl.get('lambda_sca_nodes_m')} m. λ_sca's second error is the templates' systematic; the check "
        "compares 1/λ_abs + 1/λ_sca with the I_center λ_att of the same frames (agrees within 2σ).</p>"
    )
    poor = [f"{f['wavelength_nm']} nm" for f in fits if f["ndof"] and f["chi2"] / f["ndof"] > 2]
    if poor:
        body += note(
            f"χ²/ndof is well above 1 at {', '.join(poor)}: the templates do not describe these profiles "
            "within their errors, so the quoted errors are too small and the lengths carry the model's bias. "
            "Look at the pulls below."
        )
    if d.fit["run_id"] != d.run["id"]:
        body += note(
            f"This fit used run {d.fit['run_id']}'s inputs, not run {d.run['id']}'s shown elsewhere."
        )
    body += table(
        [
            "wavelength",
            "λ_abs [m]",
            "λ_sca [m] (stat, sys)",
            "λ_att fit [m]",
            "λ_att I_center [m]",
            "check",
            "χ²/ndof",
            "at grid edge",
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


def _calibration(d: ReportData) -> str:
    s = d.setup
    cams = table(
        ["camera", "distance to the LEM [m]", "error [m]"],
        [(c, f"{v.distance_m:.2f}", f"{v.distance_err_m:.2f}") for c, v in sorted(s.cameras.items())],
    )
    ratios = table(
        ["wavelength", "I0'/I0", "error"],
        [(f"{wl} nm", f"{r.value:.3f}", f"{r.err:.3f}") for wl, r in sorted(s.emission_ratio.items())],
    )
    body = (
        f"<p>The inputs of run {d.run['id']} ({esc(d.run['kind'])}, made {iso(d.run['created_unix_s'])}), "
        "as the λ_att table and the fit use them.</p><h3>Distances</h3>"
        + cams
        + "<h3>Emission ratio I0'/I0 (toward the far camera over toward the near one)</h3>"
        + ratios
        + f"<h3>Linear range</h3><p>gray {s.linear_range[0]:g} to {s.linear_range[1]:g}</p>"
    )
    c = d.calibration
    body += "<h3>Calibration record</h3>"
    if c is None:
        body += "<p>None: the run's inputs came from the ingest's settings or setup.json, not a record.</p>"
    else:
        body += table(
            ["", ""],
            [
                ("name, version", f"{c['name']} v{c['version']} (id {c['id']})"),
                ("source", c["source"] or "—"),
                ("valid", f"{iso(c['valid_from_unix_s'])} to {iso(c['valid_to_unix_s'])}"),
                ("created", iso(c["created_unix_s"])),
                ("sources", "; ".join(c["values"].get("sources", [])) or "—"),
            ],
            text_cols=2,
        )
    body += "<h3>Analysis runs of this dive</h3>" + table(
        ["run", "kind", "label", "calibration record", "camcal", "created", "status", "frames"],
        [
            (
                r["id"],
                r["kind"],
                r["label"] or "—",
                r["calibration_id"] or "—",
                r["software_version"] or "—",
                iso(r["created_unix_s"]),
                r["status"],
                r["n_frames"],
            )
            for r in d.runs
        ],
        text_cols=3,
    )
    return section("calibration", body)


def _software(d: ReportData) -> str:
    rows = [(k, v) for k, v in d.software.items()]
    return section(
        "software",
        f"<p>Report written {iso(d.generated_unix_s)} by camcal {esc(d.software['camcal'])} "
        "from the store in "
        f"<code>{esc(d.data_dir)}</code>. The run's analysis: camcal {esc(d.run['software_version'] or '—')}"
        + (f"; the fit: camcal {esc(d.fit['software_version'])}" if d.fit else "")
        + ".</p>"
        + table(["component", "version"], rows, text_cols=2),
    )


def render(d: ReportData) -> str:
    """The whole report as one HTML document."""
    name = esc(d.dive["name"])
    nav = "".join(f'<li><a href="#{sid}">{esc(title)}</a></li>' for sid, title in SECTIONS)
    parts = [
        _summary(d),
        _timeline(d),
        _quality(d),
        _linearity(d),
        _attitude(d),
        _attenuation(d),
        _fit(d),
        _calibration(d),
        _software(d),
    ]
    return (
        "<!DOCTYPE html>\n"
        f'<html lang="en"><head><meta charset="utf-8"><meta name="viewport" content="width=device-width">'
        f'<meta name="generator" content="camcal {esc(d.software["camcal"])}">'
        f"<title>Dive report {name}</title><style>{CSS}</style></head><body><main>"
        f"<header><h1>Dive report: {name}</h1>"
        f'<div class="muted">camcal {esc(d.software["camcal"])} · written {iso(d.generated_unix_s)} · '
        "camera-based optical calibration (T-REX / TRIDENT)</div></header>"
        f"<nav><b>Contents</b><ol>{nav}</ol></nav>" + "".join(parts) + "</main></body></html>\n"
    )
