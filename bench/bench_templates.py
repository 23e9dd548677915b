"""The smooth templates against Mitsuba and the Monte Carlo templates: accuracy, cost, reproducibility.

    nice -n 10 python bench/bench_templates.py [--builds 10] [--photons 1000000] [--workers 2]

1. Accuracy per radial band (1.2-2, 2-4 disk radii and 4 disk radii to the
   last band, per camera), at every Mitsuba halo table of ``tests/data/mitsuba``
   (an independent path tracer, 4-px bins): Mitsuba over the smooth templates
   (`analysis.transport.smooth`) and over camcal's Monte Carlo templates (one
   node at the table's own λ_sca and phase function, ``--photons``), and the
   smooth over the Monte Carlo ones, each with the noise it carries (the
   median relative error of a 4-px bin: Mitsuba's, the Monte Carlo's) and the
   smooth templates' stated error in that band. "orders≥2" is what Mitsuba
   says of the small-angle orders alone: (Mitsuba - exact first order) over
   the model's orders >= 2.
2. Cost: the smooth templates' build (every piece computed, into an empty
   cache) and their load from the cache, against a floor measured in the
   same run: the Monte Carlo grid the fit built before (7 λ_sca nodes × 10⁶
   photons, one phase function) on the same workers; one evaluation of
   `halo` and of `halo_gradient` against that grid's `TemplateGrid.halo`.
3. Reproducibility: ``--builds`` Monte Carlo builds with independent seeds
   (correlated sampling: one photon run at ⟨cos θ⟩ 0.93 / 17 % reweighted to
   0.90, 0.93 and 0.96, λ_sca 25 m): per band, how the builds scatter
   against their own stated errors (pull RMS; 1 when the errors are honest);
   then ⟨cos θ⟩ and λ_sca fitted by each build to Mitsuba's turbid halo
   (truth 0.93, 25 m; λ_att held at the truth, as the disks fix it): the
   builds' spread of ⟨cos θ⟩ against the error their templates alone give
   the fitted value (the issue asks a pull RMS of 0.7-1.3). The smooth
   templates have no random numbers (every build is the same table;
   `tests/analysis/test_smooth_templates.py` checks it): their ⟨cos θ⟩ is
   printed with its error and, apart, what their stated (systematic) error
   would allow.

``--quick`` (a coarse ⟨cos θ⟩ grid, 5·10⁴ photons, 3 builds) only checks
that the script runs.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from collections.abc import Callable
from concurrent.futures import Executor, ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from analysis.transport.cache import TemplateCache
from analysis.transport.smooth import SmoothGrid, SmoothTemplates
from analysis.transport.smooth_build import build_smooth_templates
from analysis.transport.template_settings import EmissionProfile, TemplateSettings
from analysis.transport.templates import TemplateGrid, build_template_grid

FOCAL_PX = 1224.0 / math.tan(math.radians(8.0))
DISTANCES_M = (21.56, 41.62)
N_BANDS = 320
MITSUBA = Path(__file__).resolve().parents[1] / "tests" / "data" / "mitsuba"
RANGES = ((1.2, 2.0), (2.0, 4.0), (4.0, math.inf))
EMISSION = EmissionProfile(1.0)
Bins = list[tuple[np.ndarray, np.ndarray, np.ndarray]]  # per camera: ρ [px], value, error


def settings(**kw: object) -> TemplateSettings:
    return TemplateSettings.near_far(DISTANCES_M[0], DISTANCES_M[1], FOCAL_PX, n_bands=N_BANDS, **kw)


def disk_px(camera: int, lem_radius_m: float) -> float:
    d = DISTANCES_M[camera]
    return FOCAL_PX * lem_radius_m / math.sqrt(d * d - lem_radius_m * lem_radius_m)


def binned(values: np.ndarray, rho_px: np.ndarray, width: int = 4) -> np.ndarray:
    """Values on one-pixel bands averaged by area over the ``width``-px bins centred at ``rho_px``."""
    r = np.arange(values.shape[-1]) + 0.5
    lo = np.floor(rho_px - width / 2).astype(int)
    return np.array([np.average(values[..., i : i + width], weights=r[i : i + width], axis=-1) for i in lo]).T


def wmean(x: np.ndarray, err: np.ndarray) -> float:
    return float(np.average(x, weights=err**-2.0))


@dataclass(frozen=True)
class Table:
    name: str
    water: tuple[float, float, float, float]  # λ_abs, λ_sca, Mie g, Rayleigh share
    family: str
    bins: Bins


def load_tables() -> list[Table]:
    out = []
    for path in sorted(MITSUBA.glob("*.npz")):
        with np.load(path) as z:
            water = tuple(float(z[k]) for k in ("lambda_abs_m", "lambda_sca_m", "mie_g", "rayleigh_fraction"))
            family = str(z["phase_family"]) if "phase_family" in z.files else "hg"
            bins = []
            for c in range(2):
                rho = z[f"rho_px_{c}"]
                keep = rho + 2 <= N_BANDS
                bins.append((rho[keep], z[f"halo_{c}"][keep], z[f"halo_err_{c}"][keep]))
        out.append(Table(path.stem, water, family, bins))  # type: ignore[arg-type]
    return out


def mc_grid(water: tuple[float, float, float, float], photons: int, cache: TemplateCache) -> TemplateGrid:
    """camcal's Monte Carlo templates with one node at the water's own λ_sca and phase function."""
    _, ls, g, f = water
    s = settings(lambda_sca_nodes_m=(ls,), mie_g_nodes=(g,), rayleigh_fraction=f, n_photons=photons, seed=7)
    return build_template_grid(s, cache)


# -- 1. accuracy -------------------------------------------------------------------------------------
def accuracy(st: SmoothTemplates, tables: list[Table], grids: dict[str, TemplateGrid]) -> None:
    print("\n## 1. Accuracy per radial band (ratios: weighted means over the band's 4-px bins)\n")
    print(
        "| table (λ_abs/λ_sca m, g, f) | cam | band (disk radii) | Mitsuba noise | Mitsuba/smooth | χ²/n "
        "| orders≥2 | smooth stated err | Mitsuba/MC | MC noise | smooth/MC |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    a = st.settings.lem_radius_m
    for t in tables:
        la, ls, g, f = t.water
        value, err = st.halo(la, ls, g, f).total(EMISSION)
        first, higher = (np.einsum("k,ckb->cb", EMISSION.weights(), p) for p in st.parts(la, ls, g, f))
        mc_value, mc_err = grids[t.name].halo(la, ls, g, f).total(EMISSION)
        label = (
            f"{t.name}{'' if t.family == 'hg' else ' (' + t.family + ')'} ({la:g}/{ls:g}, {g:.2f}, {f:.2f})"
        )
        for c, (rho, m, e) in enumerate(t.bins):
            rd = disk_px(c, a)
            model, model_err = binned(value[c], rho), binned(err[c], rho)
            mc, mce = binned(mc_value[c], rho), binned(mc_err[c], rho)
            fo, hi = binned(first[c], rho), binned(higher[c], rho)
            for lo_rd, hi_rd in RANGES:
                sel = (rho > lo_rd * rd) & (rho <= hi_rd * rd)
                if not np.any(sel):
                    continue
                ms, es = m[sel], e[sel]
                band = (
                    f"{lo_rd:g}-{hi_rd:g}" if hi_rd < math.inf else f"{lo_rd:g}-{rho[sel].max() + 2:.0f} px"
                )
                r_s = wmean(ms / model[sel], es / model[sel])
                chi2 = float(np.mean((ms - model[sel]) ** 2 / (es**2 + model_err[sel] ** 2)))
                r_hi = wmean((ms - fo[sel]) / hi[sel], es / hi[sel])
                r_mc = wmean(ms / mc[sel], np.hypot(es, ms * mce[sel] / mc[sel]) / mc[sel])
                r_smc = wmean(model[sel] / mc[sel], model[sel] * mce[sel] / mc[sel] ** 2)
                print(
                    f"| {label} | {c} | {band} | {np.median(es / ms):.1%} | {r_s:.4f} | {chi2:.2f} "
                    f"| {r_hi:.3f} | {np.median(model_err[sel] / model[sel]):.2%} | {r_mc:.4f} "
                    f"| {np.median(mce[sel] / mc[sel]):.2%} | {r_smc:.4f} |"
                )
                label = ""


# -- 2. cost -----------------------------------------------------------------------------------------
def per_call_ms(fns: list[Callable[[], object]], n: int = 100, rounds: int = 7) -> list[float]:
    """Milliseconds per call of each function: the best of ``rounds`` rounds of ``n`` calls, the
    functions taking turns within a round so that each meets the machine's load alike."""
    best = [math.inf] * len(fns)
    for _ in range(rounds):
        for k, fn in enumerate(fns):
            t = time.perf_counter()
            for _ in range(n):
                fn()
            best[k] = min(best[k], (time.perf_counter() - t) / n * 1e3)
    return best


def cost(pool: Executor, workers: int, grid: SmoothGrid | None) -> SmoothTemplates:
    print("\n## 2. Cost (wall time on this machine now; the ratios are what carries over)\n")
    with tempfile.TemporaryDirectory(prefix="bench-templates-") as tmp:
        cold = TemplateCache(tmp)
        t0 = time.perf_counter()
        st = build_smooth_templates(settings(), cold, executor=pool, grid=grid)
        build_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        build_smooth_templates(settings(), cold, grid=grid)
        load_s = time.perf_counter() - t0
        # The floor: the Monte Carlo grid the fit built before (7 λ_sca nodes × 10⁶ photons, one
        # phase function), into an empty cache on the same workers.
        t0 = time.perf_counter()
        mc = build_template_grid(settings(n_photons=1_000_000, seed=3), cold, executor=pool)
        floor_s = time.perf_counter() - t0
    print("| figure | time | floor | ratio |")
    print("|---|---|---|---|")
    print(
        f"| smooth build into an empty cache ({st.grid.n_g} ⟨cos θ⟩ nodes × {st.grid.n_k} 1/λ_att nodes, "
        f"{st.grid.n_orders} orders; all four parameters) | {build_s:.0f} s | the fit's Monte Carlo grid "
        f"(7 λ_sca nodes × 10⁶ photons, one phase function), the same {workers} workers: {floor_s:.0f} s "
        f"| {build_s / floor_s:.2f} |"
    )
    print(f"| smooth load from the cache | {load_s:.2f} s | (same) | {load_s / floor_s:.3f} |")
    floor, one, grad = per_call_ms(
        [
            lambda: mc.halo(30.0, 25.0),
            lambda: st.halo(30.0, 25.0, 0.93, 0.17),
            lambda: st.halo_gradient(30.0, 25.0, 0.93, 0.17),
        ]
    )
    print(f"| smooth `halo` | {one:.2f} ms | MC `TemplateGrid.halo`: {floor:.2f} ms | {one / floor:.2f} |")
    print(f"| smooth `halo_gradient` (4 derivatives) | {grad:.2f} ms | (same) | {grad / floor:.2f} |")
    return st


# -- 3. reproducibility ------------------------------------------------------------------------------
HaloOf = Callable[[float, float], tuple[np.ndarray, np.ndarray]]  # (g, λ_sca) -> value, error


def fit_g(halo_of: HaloOf, start: tuple[float, float], data: Bins) -> tuple[float, float, float, float]:
    """⟨cos θ⟩ and λ_sca (λ_att held at the truth) minimising χ² against ``data`` (data and
    template errors in quadrature, frozen at ``start``), by Gauss-Newton steps in (g, ln λ_sca):
    g, λ_sca, g's error and the part of it the template's stated errors alone give (linearised,
    the bins independent as the fit takes them)."""
    rho = [d[0] for d in data]
    m = np.concatenate([d[1] for d in data])

    def model(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        value, err = halo_of(float(p[0]), math.exp(float(p[1])))
        return (
            np.concatenate([binned(value[c], r) for c, r in enumerate(rho)]),
            np.concatenate([binned(err[c], r) for c, r in enumerate(rho)]),
        )

    p = np.array([start[0], math.log(start[1])])
    t_err = model(p)[1]
    s2 = np.concatenate([d[2] for d in data]) ** 2 + t_err**2
    steps = np.array([0.002, 0.01])
    for _ in range(6):
        t = model(p)[0]
        jac = np.stack(
            [(model(p + h)[0] - model(p - h)[0]) / (2 * h[i]) for i, h in enumerate(np.diag(steps))], 1
        )
        cov = np.linalg.inv(jac.T @ (jac / s2[:, None]))
        step = cov @ (jac.T @ ((m - t) / s2))
        p = p + step
        if abs(step[0]) < 1e-6:
            break
    gain = cov @ (jac / s2[:, None]).T  # d p / d T
    cov_t = gain @ (gain * t_err**2).T
    return float(p[0]), math.exp(float(p[1])), math.sqrt(cov[0, 0]), math.sqrt(cov_t[0, 0])


def one_build(seed: int, photons: int, cache_dir: str) -> TemplateGrid:
    s = settings(
        lambda_sca_nodes_m=(25.0,),
        mie_g_nodes=(0.90, 0.93, 0.96),
        mc_phase=(0.93, 0.17),
        n_photons=photons,
        seed=seed,
    )
    return build_template_grid(s, TemplateCache(cache_dir))


def reproducibility(
    st: SmoothTemplates, tables: list[Table], builds: int, photons: int, cache: TemplateCache, pool: Executor
) -> None:
    turbid = next(t for t in tables if t.name == "turbid")
    la, ls, _, f = turbid.water
    a = st.settings.lem_radius_m
    data = [
        (rho[sel], m[sel], e[sel])
        for c, (rho, m, e) in enumerate(turbid.bins)
        if (sel := rho > 1.2 * disk_px(c, a)).any()
    ]
    one_build(1000, 1000, str(cache.directory))  # the first-order pieces, once, before the pool shares them
    t0 = time.perf_counter()
    grids = list(
        pool.map(one_build, range(1000, 1000 + builds), [photons] * builds, [str(cache.directory)] * builds)
    )
    build_s = time.perf_counter() - t0
    print(
        f"\n## 3. Reproducibility: {builds} Monte Carlo builds, independent seeds, "
        f"{photons:.0e} photons each ({build_s:.0f} s)\n"
    )
    print(
        "| camera | band (disk radii) | MC stated error (median) | builds' spread (RMS) "
        "| pull RMS across builds |"
    )
    print("|---|---|---|---|---|")
    corr = math.sqrt(builds / (builds - 1))
    totals = [g.halo(la, ls, 0.93, f).total(EMISSION) for g in grids]
    vals, errs = np.array([t[0] for t in totals]), np.array([t[1] for t in totals])
    for c in range(2):
        rd = disk_px(c, a)
        rho = np.arange(2.0, N_BANDS - 2, 4.0)
        v = np.array([binned(x[c], rho) for x in vals])
        e = np.array([binned(x[c], rho) for x in errs])
        for lo, hi in RANGES:
            sel = (rho > lo * rd) & (rho <= hi * rd)
            if not sel.any():
                continue
            pulls = (v[:, sel] - v[:, sel].mean(axis=0)) / e[:, sel] * corr
            spread = v[:, sel].std(axis=0, ddof=1) / v[:, sel].mean(axis=0)
            band = f"{lo:g}-{hi:g}" if hi < math.inf else f"{lo:g} disk radii-{N_BANDS} px"
            print(
                f"| {c} | {band} | {np.median(e[:, sel] / v[:, sel]):.2%} | {np.median(spread):.2%} "
                f"| {math.sqrt(float(np.mean(pulls**2))):.2f} |"
            )
    k_att = 1.0 / la + 1.0 / ls

    def of(source: TemplateGrid | SmoothTemplates) -> HaloOf:
        return lambda g, sca: source.halo(1.0 / (k_att - 1.0 / sca), sca, g, f).total(EMISSION)

    fits = np.array([fit_g(of(grid), (0.93, ls), data) for grid in grids])
    mean = float(fits[:, 0].mean())
    pull_rms = math.sqrt(float(np.mean(((fits[:, 0] - mean) / fits[:, 3] * corr) ** 2)))
    print(
        "\n⟨cos θ⟩ and λ_sca fitted to Mitsuba's turbid halo (truth 0.93 and 25 m, λ_att held at the truth, "
        "both cameras from 1.2 disk radii), ⟨cos θ⟩ per build: " + ", ".join(f"{x:.4f}" for x in fits[:, 0])
    )
    print(
        f"- Monte Carlo: mean ⟨cos θ⟩ {mean:.4f}, λ_sca {fits[:, 1].mean():.2f} m; ⟨cos θ⟩'s spread across "
        f"builds (RMS) {fits[:, 0].std(ddof=1):.5f}; its error per fit {np.median(fits[:, 2]):.5f} (data and "
        f"template), from the template alone {np.median(fits[:, 3]):.5f}: "
        f"pull RMS across builds {pull_rms:.2f} (aim 0.7-1.3)"
    )
    g_s, l_s, e_s, t_s = fit_g(of(st), (0.93, ls), data)
    print(
        f"- smooth: ⟨cos θ⟩ {g_s:.4f} ± {e_s:.5f}, λ_sca {l_s:.2f} m in every build "
        f"(no random numbers: spread 0); its stated systematic error, taken independent per bin, "
        f"would allow {t_s:.5f}"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--builds", type=int, default=10)
    ap.add_argument("--photons", type=int, default=1_000_000, help="per Monte Carlo node")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--cache", default=None, help="the Monte Carlo templates' cache (default: a fresh one)")
    ap.add_argument(
        "--quick", action="store_true", help="a coarse grid, 50,000 photons, 3 builds: the script runs"
    )
    args = ap.parse_args()
    grid = None
    if args.quick:
        grid = SmoothGrid(mie_g_range=(0.85, 0.97), n_g=6, n_orders=20)
        args.photons, args.builds = 50_000, 3
    tables = load_tables()
    with (
        tempfile.TemporaryDirectory(prefix="bench-templates-mc-") as tmp,
        ProcessPoolExecutor(args.workers) as pool,
    ):
        cache = TemplateCache(args.cache or tmp)
        st = cost(pool, args.workers, grid)
        waters = sorted({t.water for t in tables})
        t0 = time.perf_counter()
        made = pool.map(mc_grid, waters, [args.photons] * len(waters), [cache] * len(waters))
        built = dict(zip(waters, made, strict=True))
        grids = {t.name: built[t.water] for t in tables}
        print(
            f"\nMonte Carlo templates at the tables' {len(waters)} waters: {time.perf_counter() - t0:.0f} s"
        )
        accuracy(st, tables, grids)
        reproducibility(st, tables, args.builds, args.photons, cache, pool)


if __name__ == "__main__":
    main()
