"""Figures of an analysis: radial profile with background fit, linearity, λ_att per pair."""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from analysis import FrameAnalysis, SetResult
from camcal.core.frameset import ManifestRow

WAVELENGTH_COLORS = {405: "#7b4fff", 460: "#1f8fff", 525: "#22b34c"}


def _color(wl: int) -> str:
    return WAVELENGTH_COLORS.get(wl, "#444444")


def plot_profile(frame: FrameAnalysis, title: str, path: Path) -> Path:
    """Mean gray per radius band (log scale) with the exponential + constant fit."""
    prof, fit = frame.profile, frame.fit
    if prof is None or fit is None:
        raise ValueError("frame has no profile to plot")
    fig, ax = plt.subplots(figsize=(7, 4.2), dpi=110)
    ok = prof.count > 0
    ax.errorbar(
        prof.radius_px[ok],
        prof.mean_gray[ok],
        yerr=prof.sem_gray[ok],
        fmt=".",
        ms=3,
        color="#333",
        label="band mean",
    )
    r = prof.radius_px[prof.radius_px >= fit.r_min_px]
    ax.plot(
        r,
        fit.model(r),
        color="#d62728",
        lw=1.6,
        label=f"exp + const fit, background {fit.background_gray:.2f} ± {fit.background_err_gray:.2f}",
    )
    ax.axhline(fit.background_gray, color="#d62728", ls=":", lw=1)
    ax.axvline(fit.r_min_px, color="#888", ls="--", lw=0.8)
    ax.set_yscale("log")
    ax.set_xlabel("radius from centroid [px]")
    ax.set_ylabel("mean gray of band")
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def plot_linearity(result: SetResult, path: Path) -> Path | None:
    """Centre gray against exposure at fixed gain, per camera and wavelength, with fits."""
    checks = [c for c in result.linearity if c.exposure is not None]
    if not checks:
        return None
    cams = sorted({c.camera for c in checks})
    fig, axes = plt.subplots(1, len(cams), figsize=(6 * len(cams), 4.2), dpi=110, squeeze=False)
    for ax, cam in zip(axes[0], cams, strict=True):
        for c in (c for c in checks if c.camera == cam):
            fit = c.exposure
            assert fit is not None
            x, y, used = np.array(fit.x), np.array(fit.gray), np.array(fit.used)
            col = _color(c.wavelength_nm)
            ax.plot(
                x[used],
                y[used],
                "o",
                color=col,
                ms=4,
                label=f"{c.wavelength_nm} nm @ {c.fixed_gain_db:g} dB: R²={fit.r2:.4f}",
            )
            ax.plot(x[~used], y[~used], "x", color=col, ms=5)
            xx = np.linspace(0, x.max(), 50)
            ax.plot(xx, fit.slope * xx + fit.intercept_gray, "-", color=col, lw=1)
        ax.axhline(240, color="#888", ls="--", lw=0.8)
        ax.set_ylim(0, 270)
        ax.set_xlabel("exposure [s]")
        ax.set_ylabel("centre gray")
        ax.set_title(f"camera {cam}: linearity (x = outside linear range)", fontsize=10)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def plot_attenuation(result: SetResult, path: Path) -> Path | None:
    """λ_att of each near/far pair with its error and the combined value per wavelength."""
    if not result.attenuation:
        return None
    fig, ax = plt.subplots(figsize=(8, 4.5), dpi=110)
    x = 0
    ticks, labels = [], []
    for wl, res in sorted(result.attenuation.items()):
        col = _color(wl)
        start = x
        for p in res.pairs:
            if p.lambda_att_m is not None:
                ax.errorbar(x, p.lambda_att_m, yerr=p.stat_err_m, fmt="o", color=col, ms=4)
                ticks.append(x)
                labels.append(f"{p.exposure_s:g}s/{p.gain_db:g}dB")
            x += 1
        if res.lambda_att_m is not None:
            tot = res.total_err_m or 0.0
            ax.fill_between(
                [start - 0.4, x - 0.6], res.lambda_att_m - tot, res.lambda_att_m + tot, color=col, alpha=0.15
            )
            ax.hlines(
                res.lambda_att_m,
                start - 0.4,
                x - 0.6,
                color=col,
                lw=2,
                label=f"{wl} nm: {res.lambda_att_m:.1f} ± {res.stat_err_m:.1f} (stat) "
                f"± {res.sys_err_m:.1f} (sys) m",
            )
        x += 1
    ax.set_xticks(ticks)
    ax.set_xticklabels(labels, rotation=70, fontsize=6)
    ax.set_ylabel("λ_att [m]")
    ax.set_title("attenuation length per near/far setting pair (band: stat ⊕ sys)", fontsize=10)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def typical_frames(rows: list[ManifestRow], frames: list[FrameAnalysis]) -> dict[str, int]:
    """Per camera, the accepted frame whose I_center is the median of that camera's."""
    by_cam: dict[str, list[tuple[float, int]]] = {}
    for i, (row, f) in enumerate(zip(rows, frames, strict=True)):
        if f.ok and f.i_center_gray is not None and f.profile is not None:
            by_cam.setdefault(row.camera, []).append((f.i_center_gray, i))
    out = {}
    for cam, items in by_cam.items():
        items.sort()
        out[cam] = items[len(items) // 2][1]
    return out


def write_plots(analysis: object, out: Path) -> list[Path]:
    """All figures of a `camcal.pipeline.FrameSetAnalysis` into ``out``."""
    from camcal.pipeline import FrameSetAnalysis

    assert isinstance(analysis, FrameSetAnalysis)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    for cam, i in sorted(typical_frames(analysis.rows, analysis.frames).items()):
        row, f = analysis.rows[i], analysis.frames[i]
        title = (
            f"camera {cam}: {row.file} ({row.wavelength_nm} nm, {row.exposure_s:g} s, "
            f"{row.gain_db:g} dB), I_center = {f.i_center_gray:.1f} ± "
            f"{f.i_center_err_gray:.1f}"
        )
        written.append(plot_profile(f, title, out / f"profile_{cam}.png"))
    if analysis.result is not None:
        for p in (
            plot_linearity(analysis.result, out / "linearity.png"),
            plot_attenuation(analysis.result, out / "attenuation.png"),
        ):
            if p is not None:
                written.append(p)
    return written


def fmt_err(value: float | None, err: float | None) -> str:
    if value is None or err is None or not math.isfinite(value):
        return "—"
    return f"{value:.2f} ± {err:.2f}"
