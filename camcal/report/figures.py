"""The report's figures: matplotlib drawn to PNG and inlined as ``data:`` URIs (nothing external)."""

from __future__ import annotations

import base64
import io
from collections.abc import Sequence
from datetime import UTC, datetime
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.dates as mdates
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.figure import Figure

from camcal.plots import WAVELENGTH_COLORS

MODULE_COLORS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#9467bd", "#8c564b")
SEVERITY_COLORS = {"MINOR": "#e6a700", "MAJOR": "#d62728", "INVALID": "#7f7f7f"}
REASON_COLORS = {
    "ok": "#2ca02c",
    "saturated": "#d62728",
    "too_dark": "#555555",
    "no_source": "#9467bd",
    "off_edge": "#ff7f0e",
    "unreadable": "#8c564b",
    "bad_format": "#e377c2",
    "bad_metadata": "#bcbd22",
    "pending": "#bbbbbb",
}
DPI = 100


def wl_color(wl: int | str) -> str:
    return WAVELENGTH_COLORS.get(int(wl), "#444444")


def png_uri(fig: Figure) -> str:
    """The figure as a base64 PNG ``data:`` URI (the figure is closed)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    plt.close(fig)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _times(ts: Sequence[float] | np.ndarray) -> np.ndarray:
    """UTC seconds as matplotlib date numbers (days)."""
    return np.asarray(mdates.date2num([datetime.fromtimestamp(t, UTC) for t in ts]), dtype=float)


def _time_axis(ax: Any) -> None:
    locator = mdates.AutoDateLocator(tz=UTC)
    ax.xaxis.set_major_locator(locator)
    ax.xaxis.set_major_formatter(mdates.ConciseDateFormatter(locator, tz=UTC))
    ax.set_xlabel("time [UTC]")


def timeline(
    sensors: dict[str, dict[str, Any]], frames: list[dict[str, Any]], alarms: list[dict[str, Any]]
) -> str:
    """Depth over time per module, the frames on it (accepted or rejected) and the alarms."""
    fig, ax = plt.subplots(figsize=(9.5, 4.2))
    for i, (m, ser) in enumerate(sorted(sensors.items())):
        pts = [(t, d) for t, d in zip(ser["t_unix_s"], ser["depth_m"], strict=True) if d is not None]
        if pts:
            t, d = zip(*pts, strict=True)
            ax.plot(_times(t), d, "-", lw=1, color=MODULE_COLORS[i % 5], label=f"module {m} depth")
    for status, marker, size in (("ok", ".", 5), ("rejected", "x", 14), ("pending", "+", 14)):
        sel = [f for f in frames if f["status"] == status and f["depth_m"] is not None]
        if sel:
            ax.scatter(
                _times([f["t_unix_s"] for f in sel]),
                [f["depth_m"] for f in sel],
                s=size,
                marker=marker,
                lw=0.8,
                color=REASON_COLORS[
                    "ok" if status == "ok" else "saturated" if status == "rejected" else status
                ],
                label=f"frames {status} ({len(sel)})",
                zorder=3,
            )
    x_end = ax.get_xlim()[1]
    for a in alarms:
        col = SEVERITY_COLORS.get(a["severity"], "#7f7f7f")
        t0 = float(_times([a["raised_unix_s"]])[0])
        ax.axvline(t0, color=col, lw=1, ls="--")
        t1 = float(_times([a["cleared_unix_s"]])[0]) if a["cleared_unix_s"] else max(x_end, t0)
        ax.axvspan(t0, t1, color=col, alpha=0.12)
    if alarms:
        ax.plot([], [], "--", color=SEVERITY_COLORS["MAJOR"], label=f"alarms raised ({len(alarms)})")
    ax.invert_yaxis()
    ax.set_ylabel("module depth [m]")  # each module's own (the frames' too); the LEM hangs below
    _time_axis(ax)
    ax.grid(alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=8, loc="lower center", bbox_to_anchor=(0.5, 1.0), ncol=5, frameon=False)
    fig.tight_layout()
    return png_uri(fig)


def quality(counts: dict[str, dict[str, int]]) -> str:
    """Frames per module, stacked by outcome (accepted, then each rejection reason)."""
    modules = sorted(counts)
    reasons = ["ok", *sorted({r for c in counts.values() for r in c} - {"ok"})]
    fig, ax = plt.subplots(figsize=(9.5, 0.6 + 0.55 * max(len(modules), 1)))
    left = np.zeros(len(modules))
    for r in reasons:
        vals = np.array([counts[m].get(r, 0) for m in modules], dtype=float)
        ax.barh(modules, vals, left=left, color=REASON_COLORS.get(r, "#17becf"), label=r)
        left += vals
    ax.set_xlabel("frames")
    ax.set_ylabel("module")
    ax.legend(fontsize=8, ncol=len(reasons), loc="lower right")
    fig.tight_layout()
    return png_uri(fig)


def linearity(checks: list[dict[str, Any]]) -> str:
    """Centre gray against exposure (or linear gain) per module and sweep, with the fits and knees."""
    panels = sorted({(c["module"], c["sweep"]) for c in checks})
    ncol = min(len(panels), 2)
    nrow = -(-len(panels) // ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(9.5, 3.3 * nrow), squeeze=False)
    for ax, (mod, sweep) in zip(axes.flat, panels, strict=False):
        for c in (c for c in checks if c["module"] == mod and c["sweep"] == sweep):
            col = wl_color(c["wavelength_nm"])
            x = np.asarray(c["points"].get("x", []), dtype=float)
            g = np.asarray(c["points"].get("gray", []), dtype=float)
            used = np.asarray(c["points"].get("used", [True] * len(x)), dtype=bool)
            ax.plot(
                x[used], g[used], "o", ms=4, color=col, label=f"{c['wavelength_nm']} nm, R² {c['r2']:.4f}"
            )
            ax.plot(x[~used], g[~used], "o", ms=4, mfc="none", color=col)
            if len(x):
                xs = np.linspace(0, x.max(), 50)
                ax.plot(xs, c["intercept_gray"] + c["slope"] * xs, "-", lw=0.9, color=col)
            if c["knee_x"] is not None:
                ax.axvline(c["knee_x"], color=col, ls=":", lw=1)
        ax.axhline(240, color="#999", lw=0.8, ls="--")
        ax.set_title(f"module {mod}: {sweep} sweep", fontsize=9)
        ax.set_xlabel("exposure [s]" if sweep == "exposure" else "linear gain factor")
        ax.set_ylabel("centre gray")
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(panels) :]:
        ax.set_visible(False)
    fig.tight_layout()
    return png_uri(fig)


def attitude(series: dict[str, dict[str, Any]]) -> str:
    """Tilt from vertical, rotation rate and heave period per module over the dive."""
    rows = (
        ("tilt_deg", "tilt [°]"),
        ("rotation_rate_dps", "rotation [°/s]"),
        ("heave_period_s", "heave period [s]"),
    )
    fig, axes = plt.subplots(3, 1, figsize=(9.5, 6.6), sharex=True)
    for i, (m, ser) in enumerate(sorted(series.items())):
        t = _times(ser["t_unix_s"])
        for ax, (key, _) in zip(axes, rows, strict=True):
            y = np.array([np.nan if v is None else v for v in ser.get(key, [])], dtype=float)
            if len(y):
                ax.plot(t, y, "-", lw=0.9, color=MODULE_COLORS[i % 5], label=f"module {m}")
    for ax, (_, label) in zip(axes, rows, strict=True):
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    _time_axis(axes[-1])
    fig.tight_layout()
    return png_uri(fig)


def _att_points(series: dict[int, list[dict[str, Any]]]) -> dict[int, dict[str, np.ndarray]]:
    out = {}
    for wl, pts in sorted(series.items()):
        # the time on the ship's clock, the dive's one axis (the timeline's too)
        ok = [
            {**p, "t_unix_s": p.get("t_ship_unix_s") or p["t_unix_s"]}
            for p in pts
            if p["lambda_att_m"] is not None
        ]
        if ok:
            out[wl] = {
                k: np.array([np.nan if p[k] is None else p[k] for p in ok], dtype=float)
                for k in ("t_unix_s", "depth_m", "lambda_att_m", "stat_err_m", "total_err_m")
            }
    return out


def attenuation_time(series: dict[int, list[dict[str, Any]]]) -> str:
    """λ_att per LEM visit and wavelength over time: statistical error bars, total (⊕ sys) lighter."""
    fig, ax = plt.subplots(figsize=(9.5, 4.0))
    for wl, p in _att_points(series).items():
        t = _times(p["t_unix_s"])
        col = wl_color(wl)
        ax.errorbar(t, p["lambda_att_m"], yerr=p["total_err_m"], fmt="none", ecolor=col, alpha=0.3, lw=4)
        ax.errorbar(
            t,
            p["lambda_att_m"],
            yerr=p["stat_err_m"],
            fmt="o-",
            ms=3,
            lw=0.8,
            color=col,
            capsize=2,
            label=f"{wl} nm",
        )
    ax.set_ylabel("λ_att [m]")
    _time_axis(ax)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, title="bars: stat; shaded: stat ⊕ sys", title_fontsize=7)
    fig.tight_layout()
    return png_uri(fig)


def attenuation_depth(series: dict[int, list[dict[str, Any]]]) -> str:
    """λ_att per wavelength against the LEM's depth (the mean over each visit's frames)."""
    fig, ax = plt.subplots(figsize=(6.5, 4.6))
    for wl, p in _att_points(series).items():
        col = wl_color(wl)
        ax.errorbar(
            p["lambda_att_m"],
            p["depth_m"],
            xerr=p["total_err_m"],
            fmt="o",
            ms=4,
            color=col,
            ecolor=col,
            elinewidth=1,
            capsize=2,
            label=f"{wl} nm",
        )
    lo, hi = ax.get_ylim()
    if hi - lo < 20.0:  # one stop: centimetres of the LEM's swell would read as a depth profile
        mid = (hi + lo) / 2
        ax.set_ylim(mid - 10.0, mid + 10.0)
    ax.invert_yaxis()
    ax.set_xlabel("λ_att [m] (error: stat ⊕ sys)")
    ax.set_ylabel("LEM depth [m]")
    ax.ticklabel_format(axis="y", useOffset=False, style="plain")  # 3420 m, not "+3.42e3" and ±0.04
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return png_uri(fig)
