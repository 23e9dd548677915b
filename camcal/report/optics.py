"""Report sections about the water and the instrument: λ_att, the χ² fit, calibration, software."""

from __future__ import annotations

from camcal.report import figures
from camcal.report.collect import ReportData
from camcal.report.html import esc, figure, iso, note, num, section, table


def attenuation(d: ReportData) -> str:
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
            num(r["chi2_ndof"]) if r["n_pairs"] > 1 else "–",  # one pair: no degree of freedom
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


def calibration(d: ReportData) -> str:
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


def software(d: ReportData) -> str:
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
