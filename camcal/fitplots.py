"""Figures of the χ² method: Δχ² contours, the fit over the data, the c₁/c₂ coefficients."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.figure import Figure

from analysis.chisq import DCHI2_2D_68, DCHI2_2D_95, ChiSquareFit
from analysis.transport.coefficients import SpherePaths
from camcal.fitdoc import estimate_text, fit_entry
from camcal.fitset import AttenuationCheck, FolderFit
from camcal.plots import WAVELENGTH_COLORS


def _color(wl: int) -> str:
    return WAVELENGTH_COLORS.get(wl, "#444444")


def _best(entry: dict[str, Any]) -> tuple[float, float]:
    """The χ² minimum's position (older documents: their flat values)."""
    best = entry.get("best_fit_m") or [entry["lambda_abs_m"], entry["lambda_sca_m"]]
    return float(best[0]), float(best[1])


def _interval(entry: dict[str, Any], key: str) -> tuple[float, float]:
    lo, hi = entry[f"{key}_interval_m"]
    x = _best(entry)[0 if key == "lambda_abs" else 1]
    return max(x - lo, 0.0), max(hi - x, 0.0)


def _quoted(entry: dict[str, Any], key: str) -> str:
    text = estimate_text(entry, key, 1)
    return text if text[0] in "<>u" else f"= {text}"


def contour_figure(entry: dict[str, Any]) -> Figure:
    """Δχ² over (λ_abs, λ_sca): the 68 % and 95 % joint regions, the best fit with its 1-D errors,
    and the band of the I_center λ_att (1/λ_abs + 1/λ_sca = 1/λ_att).

    ``entry`` is one wavelength of the fit document (`camcal.fitset.fit_entry`).
    """
    c = entry["contour"]
    xa_grid = np.asarray(c["lambda_abs_m"], dtype=float)
    ys_grid = np.asarray(c["lambda_sca_m"], dtype=float)
    dchi2 = np.asarray(c["delta_chi2"], dtype=float)
    fig, ax = plt.subplots(figsize=(6.4, 5.2), dpi=110)
    levels = [0, 1, 2.3, 4, 6.18, 9, 16, 25]
    filled = ax.contourf(xa_grid, ys_grid, dchi2, levels=levels, cmap="Blues_r", extend="max")
    fig.colorbar(filled, ax=ax, label="Δχ² (profiled)" + (" / χ²/ndof" if entry.get("errors_scaled") else ""))
    if np.nanmin(dchi2) < DCHI2_2D_95 < np.nanmax(dchi2):
        lines = ax.contour(
            xa_grid,
            ys_grid,
            dchi2,
            levels=[DCHI2_2D_68, DCHI2_2D_95],
            colors=["k", "k"],
            linestyles=["-", "--"],
            linewidths=1.2,
        )
        ax.clabel(lines, fmt={DCHI2_2D_68: "68 %", DCHI2_2D_95: "95 %"}, fontsize=8)
    la, ls = _best(entry)
    ax.errorbar(
        la,
        ls,
        xerr=[[v] for v in _interval(entry, "lambda_abs")],
        yerr=[[v] for v in _interval(entry, "lambda_sca")],
        fmt="o",
        color="#d62728",
        ms=5,
        capsize=3,
        label=f"λ_abs {_quoted(entry, 'lambda_abs')}\nλ_sca {_quoted(entry, 'lambda_sca')}",
    )
    att, att_err = entry.get("lambda_att_icenter_m"), entry.get("lambda_att_icenter_err_m")
    if att is not None and att_err is not None:
        xa = np.linspace(xa_grid[0], xa_grid[-1], 200)
        for lam, style in ((att, "-"), (att - att_err, ":"), (att + att_err, ":")):
            inv = 1.0 / lam - 1.0 / xa
            ys = np.where(inv > 0, 1.0 / np.where(inv > 0, inv, 1.0), np.nan)
            label = f"I_center λ_att = {att:.1f} ± {att_err:.1f} m" if style == "-" else None
            ax.plot(xa, ys, style, color="#2ca02c", lw=1.2, label=label)
    ax.set_xlim(xa_grid[0], xa_grid[-1])
    ax.set_ylim(ys_grid[0], ys_grid[-1])
    ax.set_xlabel("absorption length λ_abs [m]")
    ax.set_ylabel("scattering length λ_sca [m]")
    ax.set_title(
        f"{entry['wavelength_nm']} nm: χ²/ndof = {entry['chi2']:.0f}/{entry['ndof']}"
        + (f" (errors ×{entry['error_scale']:.2f})" if entry.get("errors_scaled") else "")
        + ", "
        f"⟨cos θ⟩ = {entry['mie_g']:g}",
        fontsize=10,
    )
    ax.legend(fontsize=7.5, loc="upper right")
    fig.tight_layout()
    return fig


def profiles_figure(entry: dict[str, Any]) -> Figure:
    """Both cameras' normalised profiles with the best-fit model (disk + halo) and the pulls.

    Shown for the setting with the most bands in the fit; the others look
    alike. The halo part is drawn as it enters the background-subtracted
    data: with the fitted offset that gives back what the background fit took.
    """
    best = max(entry["profiles"], key=lambda p: int(np.sum(np.asarray(p["used"]))))
    arr = {k: np.asarray(best[k], dtype=float) for k in ("radius_px", "data", "error", "model", "halo")}
    used_all = np.asarray(best["used"], dtype=bool)
    fig, (ax, axr) = plt.subplots(2, 1, figsize=(7.5, 6.2), dpi=110, sharex=True, height_ratios=[3, 1.2])
    r = arr["radius_px"]
    for cam, (label, col) in enumerate((("near", "#1f77b4"), ("far", "#ff7f0e"))):
        used = used_all[cam]
        data, err, model = arr["data"][cam], arr["error"][cam], arr["model"][cam]
        ax.errorbar(
            r[used],
            data[used],
            yerr=err[used],
            fmt=".",
            ms=2.5,
            color=col,
            elinewidth=0.6,
            label=f"{label} camera: data",
        )
        ax.plot(r, model, "-", color="k", lw=0.9, label="fit: disk + halo" if cam == 0 else None)
        halo = arr["halo"][cam]
        ax.plot(
            r, np.where(halo > 0, halo, np.nan), "--", color=col, lw=0.9, label=f"{label} camera: halo part"
        )
        axr.plot(r[used], ((data - model) / err)[used], ".", ms=2.5, color=col)
    ax.set_yscale("log")
    ax.set_ylabel("gray / near camera's Σ G_i")
    ax.set_title(
        f"{entry['wavelength_nm']} nm, {best['exposure_s']:g} s / {best['gain_db']:g} dB: "
        f"λ_abs = {entry['lambda_abs_m']:.1f} m, λ_sca = {entry['lambda_sca_m']:.1f} m",
        fontsize=10,
    )
    ax.legend(fontsize=7.5, ncol=2)
    axr.axhline(0, color="#888", lw=0.8)
    axr.set_ylim(-5, 5)
    axr.set_ylabel("pull")
    axr.set_xlabel("radius from centroid [px]")
    fig.tight_layout()
    return fig


def _save(fig: Figure, path: Path) -> Path:
    fig.savefig(path)
    plt.close(fig)
    return path


def _entry(fit: ChiSquareFit, check: AttenuationCheck | None) -> dict[str, Any]:
    check = check or AttenuationCheck(fit.lambda_att_m, fit.lambda_att_err_m, None, None, None)
    return fit_entry(fit, check)


def plot_contour(fit: ChiSquareFit, check: AttenuationCheck | None, path: Path) -> Path:
    """`contour_figure` of one fit, written to ``path``."""
    return _save(contour_figure(_entry(fit, check)), path)


def plot_profiles(fit: ChiSquareFit, path: Path) -> Path:
    """`profiles_figure` of one fit, written to ``path``."""
    return _save(profiles_figure(_entry(fit, None)), path)


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
