"""The dive report as one self-contained HTML page: inline CSS, figures as inline PNG, no script.

Nothing is fetched when the page opens (no fonts, scripts, styles or images
from anywhere), so it reads the same from a USB stick, an e-mail attachment
or a ship without internet, and prints as it shows.
"""

from __future__ import annotations

from camcal.report.collect import ReportData
from camcal.report.dive import attitude, linearity, quality, summary, timeline
from camcal.report.fitsection import fit_section
from camcal.report.html import CSS, SECTIONS, esc, iso
from camcal.report.optics import attenuation, calibration, software

__all__ = ["SECTIONS", "render"]


def render(d: ReportData) -> str:
    """The whole report as one HTML document."""
    name = esc(d.dive["name"])
    nav = "".join(f'<li><a href="#{sid}">{esc(title)}</a></li>' for sid, title in SECTIONS)
    parts = [
        summary(d),
        timeline(d),
        quality(d),
        linearity(d),
        attitude(d),
        attenuation(d),
        fit_section(d),
        calibration(d),
        software(d),
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
