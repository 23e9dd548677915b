"""Figures of the χ² method: Δχ² contours, the fit over the data, the c₁/c₂ coefficients."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from analysis.chisq import DCHI2_2D_68, DCHI2_2D_95, ChiSquareFit
from analysis.transport.coefficients import SpherePaths
from camcal.fitset import AttenuationCheck, FolderFit
from camcal.plots import WAVELENGTH_COLORS


def _color(wl: int) -> str:
    return WAVELENGTH_COLORS.get(wl, "#444444")


def plot_contour(fit: ChiSquareFit, check: AttenuationCheck | None, path: Path) -> Path:
    """Δχ² over (λ_abs, λ_sca): the 68 % and 95 % joint regions, the best fit with its 1-D errors,
    and the band of the I_center λ_att (1/λ_abs + 1/λ_sca = 1/λ_att)."""
    c = fit.contour
    fig, ax = plt.subplots(figsize=(6.4, 5.2), dpi=110)
    levels = [0, 1, 2.3, 4, 6.18, 9, 16, 25]
    filled = ax.contourf(
        c.lambda_abs_m, c.lambda_sca_m, c.delta_chi2, levels=levels, cmap="Blues_r", extend="max"
    )
    fig.colorbar(filled, ax=ax, label="Δχ² (profiled)")
    lines = ax.contour(
        c.lambda_abs_m,
        c.lambda_sca_m,
        c.delta_chi2,
        levels=[DCHI2_2D_68, DCHI2_2D_95],
        colors=["k", "k"],
        linestyles=["-", "--"],
        linewidths=1.2,
    )
    ax.clabel(lines, fmt={DCHI2_2D_68: "68 %", DCHI2_2D_95: "95 %"}, fontsize=8)
    lo_a, hi_a = fit.lambda_abs_interval_m
    lo_s, hi_s = fit.lambda_sca_interval_m
    ax.errorbar(
        fit.lambda_abs_m,
        fit.lambda_sca_m,
        xerr=[[fit.lambda_abs_m - lo_a], [hi_a - fit.lambda_abs_m]],
        yerr=[[fit.lambda_sca_m - lo_s], [hi_s - fit.lambda_sca_m]],
        fmt="o",
        color="#d62728",
        ms=5,
        capsize=3,
        label=f"λ_abs = {fit.lambda_abs_m:.1f} ± {fit.lambda_abs_err_m:.1f} m\n"
        f"λ_sca = {fit.lambda_sca_m:.1f} ± {fit.lambda_sca_err_m:.1f} (stat) "
        f"± {fit.lambda_sca_sys_err_m:.1f} (sys) m",
    )
    if (
        check is not None
        and check.lambda_att_icenter_m is not None
        and check.lambda_att_icenter_err_m is not None
    ):
        xa = np.linspace(c.lambda_abs_m[0], c.lambda_abs_m[-1], 200)
        for lam, style in (
            (check.lambda_att_icenter_m, "-"),
            (check.lambda_att_icenter_m - check.lambda_att_icenter_err_m, ":"),
            (check.lambda_att_icenter_m + check.lambda_att_icenter_err_m, ":"),
        ):
            inv = 1.0 / lam - 1.0 / xa
            ys = np.where(inv > 0, 1.0 / np.where(inv > 0, inv, 1.0), np.nan)
            ax.plot(
                xa,
                ys,
                style,
                color="#2ca02c",
                lw=1.2,
                label=f"I_center λ_att = {check.lambda_att_icenter_m:.1f} ± "
                f"{check.lambda_att_icenter_err_m:.1f} m"
                if style == "-"
                else None,
            )
    ax.set_xlim(c.lambda_abs_m[0], c.lambda_abs_m[-1])
    ax.set_ylim(c.lambda_sca_m[0], c.lambda_sca_m[-1])
    ax.set_xlabel("absorption length λ_abs [m]")
    ax.set_ylabel("scattering length λ_sca [m]")
    ax.set_title(
        f"{fit.wavelength_nm} nm: χ²/ndof = {fit.chi2:.0f}/{fit.ndof}, ⟨cos θ⟩ = {fit.mie_g:g}", fontsize=10
    )
    ax.legend(fontsize=7.5, loc="upper right")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def plot_profiles(fit: ChiSquareFit, path: Path) -> Path:
    """Both cameras' normalised profiles with the best-fit model (disk + halo) and the pulls.

    Shown for the setting with the most bands in the fit; the others look
    alike. The halo part is drawn as it enters the background-subtracted
    data: with the fitted offset that gives back what the background fit took.
    """
    best = max(fit.settings, key=lambda s: int(s.used.sum()))
    fig, (ax, axr) = plt.subplots(2, 1, figsize=(7.5, 6.2), dpi=110, sharex=True, height_ratios=[3, 1.2])
    r = best.radius_px
    for cam, (label, col) in enumerate((("near", "#1f77b4"), ("far", "#ff7f0e"))):
        used = best.used[cam]
        ax.errorbar(
            r[used],
            best.data[cam][used],
            yerr=best.error[cam][used],
            fmt=".",
            ms=2.5,
            color=col,
            elinewidth=0.6,
            label=f"{label} camera: data",
        )
        ax.plot(r, best.model[cam], "-", color="k", lw=0.9, label="fit: disk + halo" if cam == 0 else None)
        halo = best.halo[cam]
        ax.plot(
            r, np.where(halo > 0, halo, np.nan), "--", color=col, lw=0.9, label=f"{label} camera: halo part"
        )
        pulls = (best.data[cam] - best.model[cam]) / best.error[cam]
        axr.plot(r[used], pulls[used], ".", ms=2.5, color=col)
    ax.set_yscale("log")
    ax.set_ylabel("gray / near camera's Σ G_i")
    ax.set_title(
        f"{fit.wavelength_nm} nm, {best.exposure_s:g} s / {best.gain_db:g} dB: "
        f"λ_abs = {fit.lambda_abs_m:.1f} m, λ_sca = {fit.lambda_sca_m:.1f} m",
        fontsize=10,
    )
    ax.legend(fontsize=7.5, ncol=2)
    axr.axhline(0, color="#888", lw=0.8)
    axr.set_ylim(-5, 5)
    axr.set_ylabel("pull")
    axr.set_xlabel("radius from centroid [px]")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def write_fit_plots(result: FolderFit, out: Path) -> list[Path]:
    """Contour and profile figures of every fitted wavelength into ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for wl, fit in sorted(result.fits.items()):
        written.append(plot_contour(fit, result.checks.get(wl), out / f"contour_{wl}.png"))
        written.append(plot_profiles(fit, out / f"fit_{wl}.png"))
    return written


def plot_c_coefficients(
    radius_m: np.ndarray,
    c1: np.ndarray,
    c2: np.ndarray,
    mc: Sequence[SpherePaths],
    title: str,
    path: Path,
) -> Path:
    """c₁ and c₂ against R (quadrature lines) with the Monte Carlo points and their errors."""
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2), dpi=110)
    for ax, values, key, name in ((axes[0], c1, "c1", "c₁ = L̄₁ / R"), (axes[1], c2, "c2", "c₂ = L̄₂ / R")):
        ax.plot(radius_m, values, "-", color="#1f77b4", lw=1.6, label="numerical integration")
        if mc:
            ax.errorbar(
                [m.radius_m for m in mc],
                [getattr(m, key) for m in mc],
                yerr=[getattr(m, key + "_err") for m in mc],
                fmt="o",
                ms=4,
                color="#d62728",
                capsize=3,
                label="Monte Carlo",
            )
        ax.set_xlabel("R [m]")
        ax.set_ylabel(name)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path
