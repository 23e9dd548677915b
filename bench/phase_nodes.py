"""What the data alone say of ⟨cos θ⟩, with the budget's phase templates built three ways.

    python bench/phase_nodes.py WATER WL G R SPACING [--cache DIR]

One frame set of ``bench_independent_truth`` (truth ⟨cos θ⟩ ``G``, Rayleigh
share ``R``, 2·10⁶ truth photons), fitted at the nominal phase function,
then the budget's phase refits on templates with the budget's own
scattering-length nodes (``SPACING`` 0), nodes spaced by the factor
``SPACING`` (> 1), or one node at the fitted λ_sca reweighted over a reach
of ``-SPACING`` (< 0). Prints the line's note (the data's posterior) and
each refit's shifts and Δχ². docs/transport.md, "Why the data do not
narrow it", has the figures.
"""

import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import bench_independent_truth as B

from analysis.chisq import FitConfig, fit_wavelength
from analysis.chisq.systematics import SystematicsConfig, systematic_budget, variation_settings
from analysis.transport.cache import TemplateCache


def main():
    cache = sys.argv[6] if len(sys.argv) > 6 else "/tmp/camcal-truth"
    tc = TemplateCache(cache)
    water, wl = sys.argv[1], int(sys.argv[2])
    g_truth, r_truth = float(sys.argv[3]), float(sys.argv[4])
    ratio = float(sys.argv[5])  # 0: the budget's nodes; > 1: their spacing; < 0: one node, this reach
    if ratio < 0:
        import analysis.transport.templates as T

        T.REWEIGHT_REACH = -ratio
    grid = B._grid(B.fit_settings(water, 400000), tc, 2)
    rend = B.renderers(water, wl, 2_000_000, cache, 0, (g_truth, r_truth), B.TRUTH_SEED + 77)
    sets = B.choose_settings(rend, wl)
    prof = B.frame_profiles(rend, wl, sets, 0)
    fit = fit_wavelength(wl, prof, grid, B.GEOMETRY, B.RATIO[wl], FitConfig(contour_points=7))
    print("fit", fit.lambda_abs.value_m, fit.lambda_sca.value_m, fit.chi2_ndof, flush=True)
    vs = variation_settings(grid.settings, [fit.lambda_sca.value_m], SystematicsConfig())
    vs = {k: v for k, v in vs.items() if k.startswith("phase")}
    if ratio < 0:
        for k, v in list(vs.items()):
            if k.startswith("phase"):
                vs[k] = replace(v, lambda_sca_nodes_m=(round(fit.lambda_sca.value_m, 1),))
    elif ratio:
        for k, v in list(vs.items()):
            if k.startswith("phase"):
                n = v.lambda_sca_nodes_m
                lo, hi = n[0], n[-1]
                m = int(np.ceil(np.log(hi / lo) / np.log(ratio)))
                dense = tuple(round(lo * (hi / lo) ** (i / m), 3) for i in range(m + 1))
                vs[k] = replace(v, lambda_sca_nodes_m=dense)
    t0 = time.time()
    var = {k: B._grid(v, tc, 2) for k, v in vs.items()}
    print("nodes", {k: v.lambda_sca_nodes_m for k, v in vs.items()}, f"{time.time() - t0:.0f} s", flush=True)
    b = systematic_budget(fit, prof, grid, var, SystematicsConfig())
    for it in b.items:
        if it.name == "phase_function":
            print(it.note)
            for c, a, s, d in zip(
                it.cases, it.lambda_abs_shifts_m, it.lambda_sca_shifts_m, it.delta_chi2, strict=True
            ):
                print(f"  {c}: dabs {a:+.2f} dsca {s:+.2f} dchi2 {d:.1f}")


if __name__ == "__main__":
    main()
