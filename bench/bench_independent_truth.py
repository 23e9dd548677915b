"""The χ² fit against frames it did not make: bias, pulls and χ²/ndof over many seeds.

    python bench/bench_independent_truth.py [--seeds 10] [--photons 200000] [--json out.json]

Frames of both T-REX cameras (21.56 and 41.62 m, the T-REX emission ratios
1.04 / 1.27 / 1.23, a small 800 x 700 sensor at the T-REX focal length) are
rendered with a halo from the photon transport run *independently of the
fit's templates*: its own Monte Carlo seed, exactly at each water (no
reweighting between nodes) and with twice the scattering orders (12 against
the templates' 6). Two waters, three wavelengths each: deep-sea (λ_abs /
λ_sca 39/39, 65/50, 31/65 m) and turbid (28/14, 32/16, 30/15 m).

For each water and wavelength, ``--seeds`` frame sets (independent sensor
noise and pointing jitter) are fitted, each with its systematic budget
(the phase function's line: the RMS shift over its priors, or over the
data's posterior with ``--narrow-by-data``, upward and downward apart),
added in quadrature to the fit error, the side toward the truth. Printed
per water and wavelength: the mean relative bias of λ_abs and λ_sca, the
pulls (value - truth) / total error (mean, RMS), the median χ²/ndof and how
many fits gave a limit instead of a value; then each of the issue's targets
with PASS or FAIL. Also timed: building the templates the budget needs
(one-off) and one fit with its budget (cached templates).

Shared with the fit: the first order of the halo (the quadrature of
`analysis.transport.single`, exact and deterministic) and the LEM model
(uniform disks, emission linear in cos θ). See docs/transport.md.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from analysis import FrameRecord, Setting, analyze_frame, stack_by_setting
from analysis.attenuation import EmissionRatio, Geometry
from analysis.chisq import (
    NUISANCE_FLAG_SIGMA,
    FitConfig,
    FitInputError,
    SettingProfiles,
    collect_settings,
    fit_wavelength,
)
from analysis.chisq.systematics import SystematicsConfig, systematic_budget, variation_settings
from analysis.scattering import WaterOptics
from analysis.transport.cache import TemplateCache
from analysis.transport.templates import TemplateGrid, TemplateSettings, build_template_grid
from camcal.core.parallel import process_pool
from lrm.sim import CameraModel, FrameRenderer
from lrm.sim.render import TransportHalo
from lrm.sim.scene import TREX_PLACEMENTS, LEMModel, Water

FOCAL_PX = 1224.0 / math.tan(math.radians(8.0))
GEOMETRY = Geometry("A", "B", 21.56, 0.02, 41.62, 0.04)
RATIO = {405: EmissionRatio(1.04, 0.03), 460: EmissionRatio(1.27, 0.04), 525: EmissionRatio(1.23, 0.04)}
WATERS = {
    "deep-sea": {405: (39.0, 39.0), 460: (65.0, 50.0), 525: (31.0, 65.0)},
    "turbid": {405: (28.0, 14.0), 460: (32.0, 16.0), 525: (30.0, 15.0)},
}
NODES = {"deep-sea": (20.0, 33.0, 55.0, 90.0), "turbid": (12.0, 20.0)}
EXPOSURES_S = (0.01, 0.02, 0.05, 0.07, 0.11, 0.2, 0.5)
GAINS_DB = tuple(float(g) for g in range(2, 21, 2))
REPEATS = 4
TRUTH_ORDERS = 12
TRUTH_SEED = 101


def _grid(settings: TemplateSettings, cache: TemplateCache, workers: int) -> TemplateGrid:
    """The template grid, its missing pieces computed on a pool of ``workers`` processes."""
    with process_pool(max(1, workers)) as pool:
        return build_template_grid(settings, cache, executor=pool)


def small_camera() -> CameraModel:
    return CameraModel(width_px=800, height_px=700, fov_deg=2.0 * math.degrees(math.atan(400.0 / FOCAL_PX)))


def fit_settings(water: str, photons: int, orders: int = 6) -> TemplateSettings:
    return TemplateSettings.near_far(
        GEOMETRY.distance_near_m,
        GEOMETRY.distance_far_m,
        FOCAL_PX,
        n_bands=144,
        lambda_sca_nodes_m=NODES[water],
        n_photons=photons,
        max_order=orders,
        seed=0,
    )


def renderers(
    water: str,
    wl: int,
    truth_photons: int,
    cache: str,
    seed: int,
    phase: tuple[float, float] = (0.93, 0.17),
    truth_seed: int = TRUTH_SEED,
) -> dict[str, FrameRenderer]:
    a, s = WATERS[water][wl]
    w = Water({wl: WaterOptics(a, s, mie_g=phase[0], rayleigh_fraction=phase[1])}, name=water)
    halo = TransportHalo(cache_dir=cache, n_photons=truth_photons, max_order=TRUTH_ORDERS, seed=truth_seed)
    cam = small_camera()
    return {
        p.camera: FrameRenderer(cam, p, w, LEMModel(), seed=seed, halo_model="transport", transport=halo)
        for p in TREX_PLACEMENTS
    }


def choose_settings(rend: dict[str, FrameRenderer], wl: int) -> list[tuple[float, float]]:
    """Up to three settings with both disks in the linear range, the far one as bright as possible."""
    ok = []
    for e in EXPOSURES_S:
        for g in GAINS_DB:
            near = rend["A"].expected_center_gray(wl, e, g)
            far = rend["B"].expected_center_gray(wl, e, g)
            if near <= 200.0 and far >= 20.0:
                ok.append((far, e, g))
    ok.sort(reverse=True)
    return sorted((e, g) for _, e, g in ok[:3])


def frame_profiles(
    rend: dict[str, FrameRenderer], wl: int, settings: list[tuple[float, float]], seed: int
) -> list[SettingProfiles]:
    """``REPEATS`` frames per setting and camera (sensor noise and pointing jitter of ``seed``),
    analysed and stacked into the fit's per-setting profiles."""
    rng = np.random.default_rng([seed, wl])
    records = []
    for e, g in settings:
        for _ in range(REPEATS):
            for name, r in rend.items():
                frame, _ = r.render(wl, e, g, rng=rng, offset_px=tuple(rng.normal(0, 1.5, 2)))
                records.append(FrameRecord(name, Setting(wl, e, g), analyze_frame(frame)))
    return collect_settings(stack_by_setting(records), wl, "A", "B")


@dataclass
class Job:
    water: str
    wl: int
    seeds: int
    grid: TemplateGrid
    variations: dict[str, TemplateGrid]
    truth_photons: int
    cache: str
    sample_systematics: bool = False
    narrow: bool = False


def truth_phase(job: Job, seed: int) -> tuple[tuple[float, float], int]:
    """The truth's (⟨cos θ⟩, Rayleigh share) and transport seed for one frame set.

    Fixed at the fit's nominal values and one transport seed by default; with
    ``sample_systematics`` drawn per frame set from the budget's priors
    (uniform over 0.88-0.96 and 0.10-0.25) with a transport seed of its own,
    so that the pulls test the total error's coverage, systematic part
    included.
    """
    if not job.sample_systematics:
        return (0.93, 0.17), TRUTH_SEED
    # Stratified (a Latin hypercube): each of the ``seeds`` equal slices of either prior holds one
    # draw, so that ten sets span the priors evenly and the pulls' mean tests the error, not the luck
    # of the draw (ten independent draws for 405 nm once all fell below 0.917).
    n = max(job.seeds, 1)
    slots = np.random.default_rng([job.wl, 0x5157])  # the same two permutations for every set
    jitter = np.random.default_rng([seed, job.wl, 0x5157])
    cfg = SystematicsConfig()
    draws = []
    for lo, hi in (cfg.mie_g_range, cfg.rayleigh_range):
        slot = int(slots.permutation(n)[seed % n])
        draws.append(round(lo + (hi - lo) * (slot + float(jitter.uniform())) / n, 4))
    return (draws[0], draws[1]), TRUTH_SEED + 1 + seed


def run_job(job: Job) -> dict[str, object]:
    a_true, s_true = WATERS[job.water][job.wl]
    out: dict[str, object] = {"water": job.water, "wavelength_nm": job.wl, "truth": [a_true, s_true]}
    out["sample_systematics"] = job.sample_systematics
    config = FitConfig(contour_points=7)
    rows = []
    settings_used = None
    for seed in range(job.seeds):
        phase, truth_seed = truth_phase(job, seed)
        rend = renderers(job.water, job.wl, job.truth_photons, job.cache, seed, phase, truth_seed)
        if settings_used is None:
            settings_used = choose_settings(rend, job.wl)
            out["settings"] = settings_used
        try:
            prof = frame_profiles(rend, job.wl, settings_used, seed)
            t0 = time.perf_counter()
            fit = fit_wavelength(job.wl, prof, job.grid, GEOMETRY, RATIO[job.wl], config)
            t_fit = time.perf_counter() - t0
        except (FitInputError, ValueError) as exc:
            rows.append({"seed": seed, "error": str(exc)})
            continue
        # Per frame set: the data's posterior of the phase function (reported, and the error with
        # --narrow-by-data) belongs to each set's data.
        sys_config = SystematicsConfig(narrow_by_data=job.narrow)
        budget = systematic_budget(fit, prof, job.grid, job.variations, sys_config)
        fit = fit.with_budget(budget)  # a limit loosened by the phase refits, as `camcal fit` quotes it
        line = next((i for i in budget.items if i.name == "phase_function"), None)
        sample_line = next((i for i in budget.items if i.name == "template_sample"), None)
        if "budget" not in out:
            out["budget_seconds"] = budget.seconds
            out["fit_seconds"] = t_fit
            out["budget"] = {i.name: [i.lambda_abs_m, i.lambda_sca_m, i.profiled] for i in budget.items}
        rows.append(
            {
                "seed": seed,
                "abs": [
                    fit.lambda_abs.status,
                    fit.lambda_abs.value_m,
                    fit.lambda_abs.err_m,
                    fit.lambda_abs.limit_m,
                ],
                "sca": [
                    fit.lambda_sca.status,
                    fit.lambda_sca.value_m,
                    fit.lambda_sca.err_m,
                    fit.lambda_sca.limit_m,
                ],
                "sys": [budget.lambda_abs_sys_m, budget.lambda_sca_sys_m],
                # each side on its own: the truth below the value meets the downward error
                "sys_down": [budget.sys_down_m(0), budget.sys_down_m(1)],
                "sys_up": [budget.sys_up_m(0), budget.sys_up_m(1)],
                # The phase line's refits, so that other ways of weighing them can be studied offline.
                "phase": None
                if line is None
                else {
                    "cases": list(line.cases),
                    "abs": list(line.lambda_abs_shifts_m),
                    "sca": list(line.lambda_sca_shifts_m),
                    "dchi2": list(line.delta_chi2),
                    "note": line.note,
                },
                # The template-sample line's refits (one per other template seed): the mean over
                # samples can be studied offline.
                "samples": None
                if sample_line is None
                else {
                    "abs": list(sample_line.lambda_abs_shifts_m),
                    "sca": list(sample_line.lambda_sca_shifts_m),
                },
                "chi2_ndof": fit.chi2_ndof,
                "error_scale": fit.error_scale,
                # How far the fit moved each calibration it floats, in σ of its prior: beyond
                # NUISANCE_FLAG_SIGMA `camcal fit` flags the wavelength ("calibration FLAGGED").
                "nuisance_pulls": {n.name: n.pull for n in fit.nuisances},
                "nuisance_strained": bool(fit.strained_nuisances),
                "nuisance_flagged": fit.calibration_flagged,
                "phase_relief": fit.phase_relief,
                "truth_phase": list(phase),
            }
        )
    out["fits"] = rows
    return out


def side_sys(row: dict, idx: int, truth: float) -> float:
    """The systematic error toward the truth: downward when the value lies above it, else upward."""
    key = "abs" if idx == 0 else "sca"
    side = "sys_down" if row[key][1] > truth else "sys_up"
    return float(row[side][idx] if side in row else row["sys"][idx])


def summarise(res: dict[str, object]) -> dict[str, object]:
    a_true, s_true = res["truth"]  # type: ignore[misc]
    fits = [r for r in res["fits"] if "error" not in r]  # type: ignore[union-attr]
    s: dict[str, object] = {"n": len(fits), "failed": len(res["fits"]) - len(fits)}  # type: ignore[arg-type]
    for key, truth in (("abs", a_true), ("sca", s_true)):
        measured = [r for r in fits if r[key][0] == "measured"]
        limits = [r for r in fits if r[key][0] in ("lower_limit", "upper_limit")]
        s[f"{key}_limits"] = len(limits)
        s[f"{key}_limits_correct"] = sum(
            1
            for r in limits
            if (r[key][0] == "lower_limit" and truth > r[key][3])
            or (r[key][0] == "upper_limit" and truth < r[key][3])
        )
        if measured:
            idx = 0 if key == "abs" else 1
            vals = np.array([r[key][1] for r in measured])
            tot = np.array([math.hypot(r[key][2], side_sys(r, idx, truth)) for r in measured])
            pulls = (vals - truth) / tot
            s[f"{key}_bias"] = float(np.mean(vals) / truth - 1.0)
            s[f"{key}_pull_mean"] = float(np.mean(pulls))
            s[f"{key}_pull_rms"] = float(np.sqrt(np.mean(pulls**2)))
            s[f"{key}_within_1"] = float(np.mean(np.abs(pulls) <= 1.0))  # 68 % for honest Gaussian errors
            s[f"{key}_rel_err"] = float(np.mean(tot) / truth)
    s["chi2_ndof_median"] = float(statistics.median(r["chi2_ndof"] for r in fits)) if fits else float("nan")
    s["nuisance_flagged"] = sum(bool(r.get("nuisance_flagged")) for r in fits)
    s["nuisance_strained"] = sum(bool(r.get("nuisance_strained")) for r in fits)
    return s


def verdicts(res: dict[str, object], s: dict[str, object]) -> list[tuple[str, bool]]:
    a_true, _ = res["truth"]  # type: ignore[misc]
    out = []
    # With the truth's phase function drawn over the prior the values follow the draws (the fit holds
    # ⟨cos θ⟩ 0.93): the bias targets belong to the truth at the nominal, the pulls test coverage here.
    drawn = bool(res.get("sample_systematics"))
    if "sca_bias" in s and not drawn:
        out.append(("λ_sca within 5 %", abs(s["sca_bias"]) <= 0.05))  # type: ignore[arg-type]
    if a_true < 100 and "abs_bias" in s and not drawn:
        out.append(("λ_abs within 10 %", abs(s["abs_bias"]) <= 0.10))  # type: ignore[arg-type]
    if s.get("abs_limits"):
        out.append(("λ_abs limits correct", s["abs_limits_correct"] == s["abs_limits"]))
    for key in ("abs", "sca"):
        if f"{key}_pull_mean" in s:
            out.append((f"λ_{key} pull mean in ±0.5", abs(s[f"{key}_pull_mean"]) <= 0.5))  # type: ignore[arg-type]
            out.append((f"λ_{key} pull RMS 0.7-1.3", 0.7 <= s[f"{key}_pull_rms"] <= 1.3))  # type: ignore[operator]
    out.append(("median χ²/ndof ≤ 1.5", s["chi2_ndof_median"] <= 1.5))  # type: ignore[operator]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--photons", type=int, default=200_000, help="per template node (the fit's)")
    ap.add_argument("--truth-photons", type=int, default=300_000, help="per camera and water (the truth's)")
    ap.add_argument("--waters", default="deep-sea,turbid")
    ap.add_argument("--template-orders", type=int, default=6, help="scattering orders of the fit's templates")
    ap.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1))
    ap.add_argument("--cache", default=None, help="template cache (default: a temporary directory)")
    ap.add_argument(
        "--sample-systematics",
        action="store_true",
        help="draw the truth's ⟨cos θ⟩ and Rayleigh share per frame set from the budget's priors",
    )
    ap.add_argument(
        "--narrow-by-data",
        action="store_true",
        help="weigh the phase function's refits by the data's posterior instead of the uniform prior",
    )
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    cache = args.cache or tempfile.mkdtemp(prefix="camcal-truth-")
    tc = TemplateCache(cache)
    waters = args.waters.split(",")
    jobs = []
    t_build = time.perf_counter()
    grids: dict[str, TemplateGrid] = {}
    var_grids: dict[str, dict[str, TemplateGrid]] = {}
    for water in waters:
        grids[water] = _grid(fit_settings(water, args.photons, args.template_orders), tc, args.workers)
    t_fit_templates = time.perf_counter() - t_build
    t0 = time.perf_counter()
    for water in waters:
        lam = [s for _, s in WATERS[water].values()]
        vs = variation_settings(grids[water].settings, lam, SystematicsConfig())
        n = sum(len(v.mie_g_nodes) * (1 + len(v.lambda_sca_nodes_m)) for v in vs.values())
        done = 0
        var_grids[water] = {}
        for name, v in vs.items():
            var_grids[water][name] = _grid(v, tc, args.workers)
            done += len(v.mie_g_nodes) * (1 + len(v.lambda_sca_nodes_m))
            print(
                f"  budget templates {water}: {done}/{n} pieces ({time.perf_counter() - t0:.0f} s)",
                flush=True,
            )
    t_var_templates = time.perf_counter() - t0
    print(
        f"templates: fit {t_fit_templates:.0f} s, budget variants {t_var_templates:.0f} s (one-off)",
        flush=True,
    )
    for water in waters:
        for wl in sorted(WATERS[water]):
            jobs.append(
                Job(
                    water,
                    wl,
                    args.seeds,
                    grids[water],
                    var_grids[water],
                    args.truth_photons,
                    cache,
                    args.sample_systematics,
                    args.narrow_by_data,
                )
            )
    t0 = time.perf_counter()
    results = []
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        for res in pool.map(run_job, jobs):
            results.append(res)
            print(
                f"  {res['water']} {res['wavelength_nm']} nm done ({time.perf_counter() - t0:.0f} s)",
                flush=True,
            )
    report(results, t_fit_templates, t_var_templates, args)
    if args.json:
        args.json.write_text(
            json.dumps(
                {"results": results, "args": vars(args) | {"json": str(args.json)}}, indent=1, default=str
            )
        )


def _pct(s: dict[str, object], k: str) -> str:
    return f"{100 * s[k]:+.1f} %" if k in s else "—"  # type: ignore[operator]


def _pull(s: dict[str, object], k: str) -> str:
    if f"{k}_pull_mean" not in s:
        return "—"
    return f"{s[f'{k}_pull_mean']:+.2f} / {s[f'{k}_pull_rms']:.2f} ({100 * s[f'{k}_within_1']:.0f} % ≤ 1)"


def report(results: list[dict[str, object]], t_fit: float, t_var: float, args: argparse.Namespace) -> None:
    print()
    print(
        f"{args.seeds} seeds per water and wavelength; templates {args.photons} photons/node, truth "
        f"{args.truth_photons} photons/camera, {TRUTH_ORDERS} orders; the truth's ⟨cos θ⟩ and Rayleigh "
        + (
            "share drawn per frame set from the budget's priors, its own transport seed each"
            if args.sample_systematics
            else f"share fixed at 0.93 and 0.17, transport seed {TRUTH_SEED}"
        )
    )
    head = (
        "water",
        "λ nm",
        "truth abs/sca m",
        "bias abs",
        "bias sca",
        "pull abs mean/RMS (share |pull| ≤ 1)",
        "pull sca mean/RMS (share |pull| ≤ 1)",
        "χ²/ndof med",
        "abs limits",
        "σ_tot abs/sca",
        "calibration flagged (strained at nominal phase)",
    )
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    n_pass = n_all = 0
    lines = []
    for res in results:
        s = summarise(res)
        a, sc = res["truth"]  # type: ignore[misc]

        errs = "/".join(f"{100 * s[k]:.1f} %" if k in s else "—" for k in ("abs_rel_err", "sca_rel_err"))
        print(
            f"| {res['water']} | {res['wavelength_nm']} | {a:g}/{sc:g} | {_pct(s, 'abs_bias')} | "
            f"{_pct(s, 'sca_bias')} | {_pull(s, 'abs')} | {_pull(s, 'sca')} | {s['chi2_ndof_median']:.2f} | "
            f"{s['abs_limits']} ({s['abs_limits_correct']} correct) | {errs} | "
            f"{s['nuisance_flagged']}/{s['n']} ({s['nuisance_strained']}) |"
        )
        for name, ok in verdicts(res, s):
            n_all += 1
            n_pass += ok
            lines.append(f"  {res['water']:8s} {res['wavelength_nm']} nm  {'PASS' if ok else 'FAIL'}  {name}")
    print()
    print("\n".join(lines))
    print(f"\n{n_pass}/{n_all} targets met")
    nuisance_report(results)
    fit_s = [r.get("fit_seconds") for r in results if r.get("fit_seconds")]
    bud_s = [r.get("budget_seconds") for r in results if r.get("budget_seconds")]
    if fit_s and bud_s:
        print(
            f"one wavelength: fit {statistics.median(fit_s):.1f} s + budget {statistics.median(bud_s):.1f} s "
            f"(median; three wavelengths run on {args.workers} workers); templates: fit {t_fit:.0f} s, "
            f"budget variants {t_var:.0f} s (one-off)"
        )


def nuisance_report(results: list[dict[str, object]]) -> None:
    """How far the fits moved each floated calibration (σ of its prior) over all frame sets: honest
    fits of frames the fit did not make should rarely pass NUISANCE_FLAG_SIGMA."""
    pulls: dict[str, list[float]] = {}
    for res in results:
        for r in res["fits"]:  # type: ignore[attr-defined]
            for name, q in r.get("nuisance_pulls", {}).items():
                pulls.setdefault(name, []).append(float(q))
    if not pulls:
        return
    print(f"\nnuisance pulls over all fits (flag beyond {NUISANCE_FLAG_SIGMA:g}σ):")
    for name, qs in sorted(pulls.items()):
        arr = np.array(qs)
        print(
            f"  {name:16s} n {arr.size:3d}  mean {arr.mean():+.2f}  RMS {np.sqrt(np.mean(arr**2)):.2f}  "
            f"max |pull| {np.max(np.abs(arr)):.2f}  beyond: {int(np.sum(np.abs(arr) > NUISANCE_FLAG_SIGMA))}"
        )


if __name__ == "__main__":
    main()
