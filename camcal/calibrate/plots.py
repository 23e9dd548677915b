"""Figures of the lab calibrations: each fit with its points, errors and residuals."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.patches import Circle, Ellipse
from matplotlib.ticker import NullFormatter, ScalarFormatter

from camcal.calibrate.common import FrameOutcome
from camcal.calibrate.emission import EmissionRatioCalibration
from camcal.calibrate.linearity import LinearityCalibration
from camcal.calibrate.psf import PSFCalibration
from camcal.calibrate.scans import AirScanCalibration, TankScanCalibration
from camcal.core.images import FrameReadError, read_frame
from camcal.plots import WAVELENGTH_COLORS

DPI = 110


def _color(wl: int) -> str:
    return WAVELENGTH_COLORS.get(wl, "#444444")


def _save(fig: plt.Figure, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path


def plot_linearity(cal: LinearityCalibration, out: Path) -> list[Path]:
    """Per wavelength: gray against exposure and against gain, the linear fit and relative residuals."""
    written = []
    for wl in sorted({wl for wl, _ in cal.curves}):
        sweeps = [s for s in ("exposure", "gain") if (wl, s) in cal.curves]
        fig, axes = plt.subplots(
            2,
            len(sweeps),
            figsize=(6.2 * len(sweeps), 6.2),
            dpi=DPI,
            squeeze=False,
            gridspec_kw={"height_ratios": [3, 1.3]},
            sharex="col",
        )
        for col, sweep in enumerate(sweeps):
            c = cal.curves[(wl, sweep)]
            scale = 1000.0 if sweep == "exposure" else 1.0
            x = np.asarray(c.x) * scale
            g, e, lin = np.asarray(c.gray), np.asarray(c.gray_err), np.asarray(c.linear)
            fitted = np.asarray(c.fitted)
            extra = lin & ~fitted
            ax, rax = axes[0, col], axes[1, col]
            lo, hi = c.linear_range_gray
            ax.axhspan(lo, hi, color="#2ca02c", alpha=0.08, label=f"linear range {lo:.1f}-{hi:.1f} gray")
            ax.errorbar(x[fitted], g[fitted], yerr=e[fitted], fmt="o", ms=4, color=_color(wl), label="fitted")
            if extra.any():
                ax.errorbar(
                    x[extra],
                    g[extra],
                    yerr=e[extra],
                    fmt="D",
                    ms=4,
                    mfc="none",
                    color=_color(wl),
                    label="in range, not fitted",
                )
            ax.errorbar(
                x[~lin], g[~lin], yerr=e[~lin], fmt="o", ms=5, mfc="none", color="#d62728", label="left out"
            )
            xx = np.linspace(0.0, x.max() * 1.02, 200)
            f = c.fit
            ax.plot(
                xx,
                f.predict(xx / scale),
                "-",
                color="#333",
                lw=1,
                label=f"fit: slope {f.slope:.4g} ± {f.slope_err:.2g}, dark {f.intercept:.2f} ± "
                f"{f.intercept_err:.2f}, R² = {f.r2:.5f}",
            )
            if c.departure_gray is not None:
                ax.axhline(
                    c.departure_gray,
                    color="#d62728",
                    ls="--",
                    lw=1,
                    label=f"leaves linearity ({100 * c.tolerance:g} %): {c.departure_gray:.1f} ± "
                    f"{c.departure_err_gray:.1f} gray",
                )
            ax.set_ylim(0, 275)
            ax.set_ylabel("mean gray of the same pixels")
            fixed = f"{c.fixed:g} dB" if sweep == "exposure" else f"{1000 * c.fixed:g} ms"
            ax.set_title(f"{wl} nm: {sweep} sweep at {fixed}", fontsize=10)
            ax.legend(fontsize=7, loc="lower right")
            rel = 100 * c.relative_residuals
            shown = np.clip(rel, -5, 5)
            rax.axhspan(-100 * c.tolerance, 100 * c.tolerance, color="#2ca02c", alpha=0.12)
            rax.axhline(0, color="#333", lw=0.8)
            rax.plot(x[fitted], shown[fitted], "o", ms=3, color=_color(wl))
            rax.plot(x[extra], shown[extra], "D", ms=3, mfc="none", color=_color(wl))
            rax.plot(x[~lin], shown[~lin], "o", ms=4, mfc="none", color="#d62728")
            rax.set_ylim(-5.5, 5.5)
            rax.set_ylabel("(data - fit) / signal [%]", fontsize=8)
            rax.set_xlabel("exposure [ms]" if sweep == "exposure" else "linear gain factor 10^(dB/20)")
        fig.suptitle(
            f"camera {cal.selection.camera}: linear response (residuals clipped at ±5 %)", fontsize=11
        )
        fig.tight_layout()
        written.append(_save(fig, out / f"linearity_{wl}nm.png"))
    return written


def plot_emission(cal: EmissionRatioCalibration, out: Path) -> list[Path]:
    """Per wavelength: I0'/I0 of each temperature run, the line through them, the value where needed.

    A last panel shows the change from the coldest to the warmest run, of
    the ratio and of the near hemisphere's brightness, against the ±1 % the
    T-REX lab reported.
    """
    wls = sorted(cal.results)
    fig, axes = plt.subplots(1, len(wls) + 1, figsize=(3.6 * (len(wls) + 1), 4.2), dpi=DPI, squeeze=False)
    for ax, wl in zip(axes[0][:-1], wls, strict=True):
        r = cal.results[wl]
        col = _color(wl)
        t = np.array([np.nan if run.temperature_c is None else run.temperature_c for run in r.runs])
        ratio = np.array([run.ratio for run in r.runs])
        err = np.array([run.ratio_err for run in r.runs])
        xs = np.where(np.isfinite(t), t, 0.0)
        ax.errorbar(xs, ratio, yerr=err, fmt="o", color=col, ms=5, label="temperature runs")
        if r.ratio_per_c is not None and r.temperature_c is not None:
            tt = np.linspace(min(xs.min(), r.temperature_c) - 1, max(xs.max(), r.temperature_c) + 1, 50)
            ax.plot(tt, r.ratio + r.ratio_per_c * (tt - r.temperature_c), "-", color=col, lw=1)
        t_use = r.temperature_c if r.temperature_c is not None else 0.0
        ax.errorbar(
            t_use,
            r.ratio,
            yerr=r.ratio_err,
            fmt="*",
            ms=11,
            color="#222",
            label=f"{r.ratio:.4f} ± {r.ratio_err:.4f}",
        )
        ax.set_title(f"{wl} nm", fontsize=10)
        ax.set_xlabel("temperature [°C]")
        ax.legend(fontsize=7, loc="lower right")
        ax.ticklabel_format(axis="y", useOffset=False)
    axes[0][0].set_ylabel("I0' / I0 (far hemisphere / near)")
    tax = axes[0][-1]
    shown = [(i, wl, e) for i, wl in enumerate(wls) if (e := cal.results[wl].temperature_effect) is not None]
    if shown:
        for i, wl, e in shown:
            tax.errorbar(
                i, 100 * e.ratio_change, yerr=100 * e.ratio_change_err, fmt="o", color=_color(wl), ms=6
            )
            tax.errorbar(
                i + 0.2,
                100 * e.brightness_change,
                yerr=100 * e.brightness_change_err,
                fmt="s",
                mfc="none",
                color=_color(wl),
                ms=5,
            )
        e0 = shown[0][2]
        tax.axhspan(-1, 1, color="#2ca02c", alpha=0.1, label="±1 % (T-REX lab: < 1 %)")
        tax.axhline(0, color="#333", lw=0.8)
        tax.plot([], [], "o", color="#555", label="I0'/I0")
        tax.plot([], [], "s", mfc="none", color="#555", label="brightness I0")
        tax.set_xticks(range(len(wls)), [f"{wl} nm" for wl in wls])
        tax.set_xlim(-0.5, len(wls) - 0.3)
        tax.set_ylabel("warm / cold - 1 [%]")
        tax.set_title(f"{e0.cold_c:.1f} °C -> {e0.warm_c:.1f} °C", fontsize=10)
        tax.legend(fontsize=7)
    else:
        tax.text(0.5, 0.5, "one temperature run:\nno temperature effect", ha="center", va="center")
        tax.set_axis_off()
    fig.suptitle(
        f"camera {cal.selection.camera}: emission ratio, star = value at {cal.inputs['temperature_c']:g} °C",
        fontsize=11,
    )
    fig.tight_layout()
    return [_save(fig, out / "emission_ratio.png")]


def plot_air_scan(cal: AirScanCalibration, out: Path) -> list[Path]:
    """Centre gray, total gray and Hough radius against distance, fits and residuals."""
    fig, axes = plt.subplots(
        2, 3, figsize=(15, 6.4), dpi=DPI, gridspec_kw={"height_ratios": [3, 1.3]}, sharex="col"
    )
    for wl, r in sorted(cal.results.items()):
        col = _color(wl)
        c = r.centre
        d = np.array([p.distance_m for p in c.points])
        dd = np.linspace(d.min() * 0.95, d.max() * 1.03, 200)
        ref = c.amplitude
        y = np.array([p.value for p in c.points]) / ref
        ye = np.array([p.err for p in c.points]) / ref
        axes[0, 0].errorbar(d, 100 * (y - 1), yerr=100 * ye, fmt="o", ms=4, color=col)
        axes[0, 0].plot(
            dd,
            100 * (np.exp(-c.mu_per_m * dd) - 1),
            color=col,
            lw=1,
            label=f"{wl} nm: mu = {1e3 * c.mu_per_m:.3f} ± {1e3 * c.mu_err_per_m:.3f} /km",
        )
        axes[1, 0].errorbar(d, 100 * c.fit.residuals, yerr=100 * c.fit.sigma_eff, fmt="o", ms=3, color=col)
        if r.total is not None:
            t = r.total
            dt = np.array([p.distance_m for p in t.points])
            v = np.array([p.value for p in t.points])
            axes[0, 1].errorbar(dt, v, yerr=[p.err for p in t.points], fmt="o", ms=4, color=col)
            axes[0, 1].plot(
                dd,
                np.exp(t.fit.intercept) * dd ** (-t.exponent),
                color=col,
                lw=1,
                label=f"{wl} nm: L^-n, n = {t.exponent:.3f} ± {t.exponent_err:.3f}",
            )
            axes[1, 1].errorbar(
                dt, 100 * t.fit.residuals, yerr=100 * t.fit.sigma_eff, fmt="o", ms=3, color=col
            )
        if r.pinhole is not None:
            p = r.pinhole
            dp = np.array([q.distance_m for q in p.points])
            rad = np.array([q.value for q in p.points])
            axes[0, 2].errorbar(dp, rad, yerr=[q.err for q in p.points], fmt="o", ms=4, color=col)
            axes[0, 2].plot(
                dd,
                p.radius_px(dd),
                color=col,
                lw=1,
                label=f"{wl} nm: f = {p.focal_px:.1f} ± {p.focal_err_px:.1f} px",
            )
            axes[1, 2].errorbar(dp, p.fit.residuals, yerr=p.fit.sigma_eff, fmt="o", ms=3, color=col)
    axes[0, 0].set_ylabel("centre gray / fit at L = 0 - 1 [%]")
    axes[0, 0].set_title("centre gray: constant in air, exp(-mu L)", fontsize=10)
    axes[1, 0].set_ylabel("ln(data / fit) [%]")
    for ax in axes[:, 1]:
        ax.set_xscale("log")
        ax.xaxis.set_major_formatter(ScalarFormatter())
        ax.xaxis.set_minor_formatter(NullFormatter())
    axes[1, 1].set_xticks([5, 10, 20, 40])
    axes[0, 1].set_yscale("log")
    axes[0, 1].set_ylabel("total gray per s at 0 dB")
    axes[0, 1].set_title("total gray of the source: 1/L²", fontsize=10)
    axes[1, 1].set_ylabel("ln(data / fit) [%]")
    axes[0, 2].set_ylabel("Hough radius [px]")
    axes[0, 2].set_title("disk radius: f a / sqrt(L² - a²) (pinhole)", fontsize=10)
    axes[1, 2].set_ylabel("data - fit [px]")
    for ax in axes[0]:
        ax.legend(fontsize=7)
    for ax in axes[1]:
        ax.axhline(0, color="#333", lw=0.8)
        ax.set_xlabel("distance L [m]")
    fig.suptitle(
        f"camera {cal.selection.camera}: long-distance test in air "
        "(residual error bars include the distance errors)",
        fontsize=11,
    )
    fig.tight_layout()
    written = [_save(fig, out / "air_scan.png")]
    montage = plot_hough_montage(cal, out / "air_scan_hough.png")
    if montage is not None:
        written.append(montage)
    return written


def plot_hough_montage(cal: AirScanCalibration, path: Path, n: int = 4) -> Path | None:
    """Frames at a few distances with the Hough circle drawn on them (dashed)."""
    ok = [f for f in cal.frames if f.ok and f.values.get("hough_radius_px") is not None]
    if not ok:
        return None
    wl = min(f.row.wavelength_nm for f in ok)
    by_d: dict[float, FrameOutcome] = {}
    for f in ok:
        if f.row.wavelength_nm == wl:
            by_d.setdefault(float(f.row.distance_m), f)  # type: ignore[arg-type]
    ds = sorted(by_d)
    picks = [ds[round(i)] for i in np.linspace(0, len(ds) - 1, min(n, len(ds)))]
    fig, axes = plt.subplots(1, len(picks), figsize=(3.4 * len(picks), 3.6), dpi=DPI, squeeze=False)
    for ax, d in zip(axes[0], picks, strict=True):
        f = by_d[d]
        try:
            frame = read_frame(cal.selection.folder / f.row.file)  # type: ignore[attr-defined]
        except FrameReadError:
            ax.set_axis_off()
            continue
        x, y, r = f.values["x_px"], f.values["y_px"], f.values["hough_radius_px"]  # type: ignore[attr-defined]
        half = int(max(1.6 * r, 20))
        x0, y0 = max(int(x) - half, 0), max(int(y) - half, 0)
        crop = frame[y0 : int(y) + half, x0 : int(x) + half]
        ax.imshow(
            crop,
            cmap="gray",
            vmin=0,
            vmax=255,
            extent=(x0 - 0.5, x0 + crop.shape[1] - 0.5, y0 + crop.shape[0] - 0.5, y0 - 0.5),
            interpolation="nearest",
        )
        ax.add_patch(Circle((x, y), r, fill=False, ls="--", lw=1.5, color="#ffd700"))
        ax.set_title(f"{d:g} m: r = {r:.1f} px", fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.suptitle(f"{wl} nm: Hough circles (dashed)", fontsize=10)
    fig.tight_layout()
    return _save(fig, path)


def plot_tank_scan(cal: TankScanCalibration, out: Path) -> list[Path]:
    """Centre gray against distance in water and in air: exponential fits and residuals."""
    fig, (ax, rax) = plt.subplots(
        2, 1, figsize=(7.5, 6.2), dpi=DPI, gridspec_kw={"height_ratios": [3, 1.3]}, sharex=True
    )
    for wl, r in sorted(cal.results.items()):
        col = _color(wl)
        for medium, fit, marker in (("water", r.water, "o"), ("air", r.air, "s")):
            if fit is None:
                continue
            d = np.array([p.distance_m for p in fit.points])
            v = np.array([p.value for p in fit.points])
            dd = np.linspace(d.min() * 0.95, d.max() * 1.03, 100)
            if medium == "water":
                label = f"{wl} nm water: λ_att = {fit.lambda_att_m:.2f} ± {fit.lambda_att_err_m:.2f} m"
                if r.relative is not None:
                    label += (
                        f" ({r.relative.lambda_att_m:.2f} ± {r.relative.lambda_att_err_m:.2f} m rel. to air)"
                    )
            else:
                label = f"{wl} nm air: mu = {fit.mu_per_m:.4f} ± {fit.mu_err_per_m:.4f} /m"
            ax.errorbar(
                d,
                v,
                yerr=[p.err for p in fit.points],
                fmt=marker,
                ms=4,
                color=col,
                mfc="none" if medium == "air" else col,
            )
            ax.plot(
                dd,
                fit.amplitude * np.exp(-fit.mu_per_m * dd),
                "-" if medium == "water" else ":",
                color=col,
                lw=1,
                label=label,
            )
            rax.errorbar(
                d,
                100 * fit.fit.residuals,
                yerr=100 * fit.fit.sigma_eff,
                fmt=marker,
                ms=3,
                color=col,
                mfc="none" if medium == "air" else col,
            )
    ax.set_yscale("log")
    ax.yaxis.set_major_formatter(ScalarFormatter())
    ax.yaxis.set_minor_formatter(ScalarFormatter())
    ax.set_ylabel("centre gray per s at 0 dB (I_center)")
    ax.set_title(f"camera {cal.selection.camera}: water tank, exp(-L / λ_att)", fontsize=10)
    ax.legend(fontsize=7)
    rax.axhline(0, color="#333", lw=0.8)
    rax.set_ylabel("ln(data / fit) [%]")
    rax.set_xlabel("distance L [m]")
    fig.tight_layout()
    return [_save(fig, out / "tank_scan.png")]


def plot_psf(cal: PSFCalibration, out: Path) -> list[Path]:
    """The point source nearest the centre with its fitted PSF, and the width across the field."""
    written = []
    for wl, r in sorted(cal.results.items()):
        good = [f for f in cal.frames if f.ok and f.row.wavelength_nm == wl]
        fig, (iax, ax) = plt.subplots(
            1, 2, figsize=(11, 4.4), dpi=DPI, gridspec_kw={"width_ratios": [1, 1.6]}
        )
        best = min(good, key=cal.field_radius_px)
        try:
            frame = read_frame(cal.selection.folder / best.row.file)
            v = best.values
            half = int(cal.inputs["window_px"]) // 2
            cx, cy = round(v["x_px"]), round(v["y_px"])
            win = frame[cy - half : cy + half + 1, cx - half : cx + half + 1]
            ext = (cx - half - 0.5, cx + half + 0.5, cy + half + 0.5, cy - half - 0.5)
            iax.imshow(win, cmap="magma", extent=ext, interpolation="nearest")
            for k in (1, 2):
                iax.add_patch(
                    Ellipse(
                        (v["x_px"], v["y_px"]),
                        2 * k * v["sigma_x_px"],
                        2 * k * v["sigma_y_px"],
                        fill=False,
                        ls="--",
                        lw=1,
                        color="#7fffd4",
                    )
                )
            iax.set_title(f"{best.row.file}: 1σ and 2σ of the fit", fontsize=9)
        except FrameReadError:
            iax.set_axis_off()
        rad = np.array([cal.field_radius_px(f) for f in good])
        for key, marker, lab in (("sigma_x", "o", "σ_x"), ("sigma_y", "s", "σ_y")):
            vals = np.array([f.values[f"{key}_px"] for f in good])
            errs = np.array([f.values[f"{key}_err_px"] for f in good])
            ax.errorbar(
                rad,
                vals,
                yerr=errs,
                fmt=marker,
                ms=4,
                mfc="none" if key == "sigma_y" else None,
                color=_color(wl),
                label=lab,
            )
        s = r.sigma
        ax.axhspan(s.mean - s.err, s.mean + s.err, color=_color(wl), alpha=0.2)
        ax.axhline(
            s.mean,
            color=_color(wl),
            lw=1.5,
            label=f"σ = {s.mean:.3f} ± {s.err:.3f} px (FWHM {r.fwhm_px:.2f})",
        )
        limit = cal.inputs.get("max_sigma_px")
        verdict = ""
        if limit is not None:
            verdict = f"; focus limit {limit:g} px: " + ("met" if s.mean <= limit else "MISSED")
        ax.set_xlabel("distance of the source from the frame centre [px]")
        ax.set_ylabel("PSF width [px]")
        ax.set_title(f"{wl} nm: pixel-integrated Gaussian fits, {s.n} frames{verdict}", fontsize=10)
        ax.legend(fontsize=8)
        fig.tight_layout()
        written.append(_save(fig, out / f"psf_{wl}nm.png"))
    return written
