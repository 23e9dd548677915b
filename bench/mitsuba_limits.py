"""Which side of the turbid disagreement is wrong: the transport against Mitsuba 3 in limits.

    python bench/mitsuba_limits.py [--spp 1024] [--photons 300000] [--distance 21.56] [--json out.json]

`bench/bench_mitsuba.py` found Mitsuba's halo 2-5 % above the transport's at
the near camera in turbid water (λ_abs = λ_sca = 25 m) at wide angles. Here
the same scene is compared order by order and in limits with exact answers:

* **single scattering** (Mitsuba ``max_depth`` 2) against the transport's
  first order, a deterministic quadrature checked against the exact
  reference (`analysis.transport.reference`): a difference here is
  Mitsuba's scene, not the transport;
* **up to two, three scatterings** (``max_depth`` 3, 4) against the
  quadrature plus the Monte Carlo's orders 2 (and 3): where the difference
  first appears names the order;
* **no absorption** (λ_abs → ∞, the same λ_sca): the transport then applies
  no path reweighting at all (exp(-ℓ/λ_abs) = 1), so a difference that
  vanishes here is in how absorption is applied after the fact;
* all orders at λ_abs = 25 m, the disagreement itself.

Each row: χ²/ndof of Mitsuba - transport over 8-px bins from 1.2 disk
radii out to 160 px (Mitsuba's pixel scatter ⊕ the transport's Monte Carlo
error) and the mean ratio. The transport's per-order tallies come from one
Monte Carlo run (one template node at exactly this water, 12 orders).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from analysis.transport.cache import TemplateCache
from analysis.transport.disk import disk_radius_px
from analysis.transport.scene import LEM_RADIUS_M
from analysis.transport.templates import TemplateGrid
from bench.bench_mitsuba import FOCAL_PX, compare_halo, transport_grid
from bench.mitsuba_scene import render_strip

ORDERS = 12


def transport_orders(grid: TemplateGrid, la: float, ls: float, up_to: int) -> tuple[np.ndarray, np.ndarray]:
    """Orders 1..``up_to`` of the transport (uniform LEM): radiance and error per one-pixel band.

    Order 1 is the quadrature; orders >= 2 the Monte Carlo node at exactly
    this λ_sca (no reweighting in λ_sca), absorption applied from the paths
    as the templates do. Reads the grid's pieces directly (a diagnostic).
    """
    g = grid.settings.mie_g_nodes[0]
    k_abs = 0.0 if math.isinf(la) else 1.0 / la
    first, _ = grid.first[g].reweight(1.0 / ls + k_abs)
    value = first[0].sum(axis=0) / ls  # components summed: the uniform LEM
    var = np.zeros_like(value)
    if up_to >= 2:
        node = grid.nodes[(g, ls)]
        v, w = node.moments.reweight(k_abs)  # (camera, component, order, coarse bin)
        sel = slice(0, up_to - 1)
        omega = grid._coarse_omega[0]
        hv = v[0, :, sel].sum(axis=(0, 1)) / omega
        hw = w[0, :, sel].sum(axis=(0, 1)) / omega**2 * node.variance_factor[0]
        mat = grid._coarse_to_fine
        value = value + mat @ hv
        var = var + (mat**2) @ hw
    return value, np.sqrt(var)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--spp", type=int, default=1024)
    ap.add_argument("--photons", type=int, default=300_000)
    ap.add_argument("--distance", type=float, default=21.56)
    ap.add_argument("--lambda-sca", type=float, default=25.0)
    ap.add_argument("--lambda-abs", type=float, default=25.0)
    ap.add_argument(
        "--seeds",
        type=int,
        default=1,
        help="independent transport runs averaged (error: their scatter, honest for heavy tails)",
    )
    ap.add_argument("--cache", default=None)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    cache = TemplateCache(args.cache or tempfile.mkdtemp(prefix="camcal-limits-"))
    dist, ls, la = args.distance, args.lambda_sca, args.lambda_abs
    r_disk = disk_radius_px(dist, LEM_RADIUS_M, FOCAL_PX)
    grids = [transport_grid(dist, ls, args.photons, ORDERS, cache, 3 + i) for i in range(args.seeds)]
    cases = [
        ("single scattering", la, 1),
        ("up to 2 scatterings", la, 2),
        ("up to 3 scatterings", la, 3),
        ("no absorption, all orders", math.inf, ORDERS),
        ("all orders", la, ORDERS),
    ]
    rows = []
    for name, lam_abs, k in cases:
        runs = [transport_orders(g, lam_abs, ls, k) for g in grids]
        value = np.mean([v for v, _ in runs], axis=0)
        if len(runs) > 1:
            # Bands of one 8-px Monte Carlo bin move together: the scatter of the runs' values (their
            # band means inside each comparison bin are formed by compare_halo from these bands).
            err = np.std([v for v, _ in runs], axis=0, ddof=1) / np.sqrt(len(runs))
        else:
            err = runs[0][1]
        strip = render_strip(
            dist, 1e12 if math.isinf(lam_abs) else lam_abs, ls, FOCAL_PX, spp=args.spp, max_depth=k + 1
        )
        h = compare_halo(strip, value, err, r_disk)
        ratio = np.asarray(h["ratio"])
        row = {
            "case": name,
            "lambda_abs_m": lam_abs,
            "orders": k,
            "chi2_ndof": h["chi2"] / max(h["ndof"], 1),
            "ndof": h["ndof"],
            "mean_ratio": float(np.nanmean(ratio)),
            "ratio": h["ratio"],
            "ratio_err": h["ratio_err"],
            "centres_px": h["centres_px"],
            "mitsuba_s": strip.seconds,
        }
        rows.append(row)
        print(
            f"  {name}: χ²/ndof {row['chi2_ndof']:.2f} ({h['ndof']} bins), Mitsuba/transport "
            f"{row['mean_ratio']:.4f}, bins {' '.join(f'{x:.3f}' for x in ratio)} ({strip.seconds:.0f} s)",
            flush=True,
        )
    print()
    print(
        f"camera at {dist} m, λ_abs/λ_sca {la:g}/{ls:g} m; Mitsuba {args.spp} spp; transport "
        f"{args.seeds} x {args.photons} photons"
    )
    print("| case | λ_abs m | orders | χ²/ndof | Mitsuba/transport (mean over bins) |")
    print("|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['case']} | {r['lambda_abs_m']:g} | ≤ {r['orders']} | {r['chi2_ndof']:.2f} | "
            f"{r['mean_ratio']:.4f} |"
        )
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
