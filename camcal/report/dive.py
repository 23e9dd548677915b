"""Report sections about the dive itself: summary, timeline, frame quality, linearity, attitude."""

from __future__ import annotations

import math
import statistics
from collections.abc import Iterable
from typing import Any

from camcal.report import figures
from camcal.report.collect import ReportData
from camcal.report.html import esc, figure, iso, note, num, section, table


def summary(d: ReportData) -> str:
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
        ("calibration", calibration_name(d)),
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


def calibration_name(d: ReportData) -> str:
    c = d.calibration
    if c is None:
        return "the run's own inputs (no calibration record)"
    return f"{c['name']} v{c['version']} (record {c['id']})"


def _cleared(a: dict[str, Any]) -> str:
    if a["cleared_unix_s"]:
        return iso(a["cleared_unix_s"])
    return "still active" if a["active"] else "—"


def timeline(d: ReportData) -> str:
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


def quality(d: ReportData) -> str:
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


def linearity(d: ReportData) -> str:
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


def stats(values: Iterable[float | None]) -> tuple[float | None, float | None]:
    v = [x for x in values if x is not None and math.isfinite(x)]
    return (statistics.median(v), max(v)) if v else (None, None)


def attitude(d: ReportData) -> str:
    if not any(a["t_unix_s"] for a in d.attitude.values()):
        return section("attitude", note("No attitude samples (the modules' sensors sent none)."))
    rows = []
    for m, a in sorted(d.attitude.items()):
        tilt = stats(a.get("tilt_deg", []))
        rot = stats(a.get("rotation_rate_dps", []))
        heave = stats(a.get("heave_period_s", []))
        amp = stats(a.get("heave_amplitude_m_s2", []))
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
