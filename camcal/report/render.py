"""The dive report as one self-contained HTML page: inline CSS, figures as inline PNG, no script.

Nothing is fetched when the page opens (no fonts, scripts, styles or images
from anywhere), so it reads the same from a USB stick, an e-mail attachment
or a ship without internet, and prints as it shows.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Iterable
from typing import Any

from camcal.report import figures
from camcal.report.collect import ReportData
from camcal.report.fitsection import fit_section
from camcal.report.html import CSS, SECTIONS, esc, figure, iso, note, num, section, table


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
        fit_section(d),
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
