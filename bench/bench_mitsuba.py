"""The photon transport (`analysis.transport`) against Mitsuba 3's volumetric path tracer.

    pip install -e '.[validate]'          # mitsuba (scalar_rgb only)
    python bench/bench_mitsuba.py [--spp 512] [--photons 300000] [--figure docs/transport-mitsuba.png]

For three waters (clear 100/140 m, deep-sea 460 nm 65/50 m, turbid 25/25 m;
⟨cos θ⟩ 0.93 with 17 % Rayleigh) and both T-REX distances (21.56, 41.62 m),
with a uniform Lambertian LEM (0.43 m sphere, radiance 1):

* the halo: Mitsuba's radiance in 8-pixel radial bins from 1.2 disk radii
  out to 160 px (the bench's strip, `bench.mitsuba_scene`) against the
  transport's template at the same water (a one-node grid: the quadrature's
  first order plus the Monte Carlo's higher orders, reweighted nowhere),
  averaged over the same pixels; the ratio, its combined Monte Carlo error
  and χ²/ndof of the difference;
* the direct light (no scattering, an exact limit): Mitsuba with the same
  σ_t but albedo 0, at the disk's central pixels, against the exact
  transmittance exp(-σ_t s) along each pixel's ray (s from the camera to the
  sphere's surface) and against the model the fit uses
  (`BandPixels.disk_path_moments` + `disk_transmittance`: the path to the
  surface per pixel, averaged by its cumulants); until issue 13's fix the
  model was exp(-L/λ_att) with L the distance to the LEM's centre, low by
  exp(-a/λ_att).

Prints a table (markdown) and writes a figure of the ratios.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from analysis.transport.cache import TemplateCache
from analysis.transport.disk import BandPixels, disk_radius_px, disk_transmittance
from analysis.transport.scene import LEM_RADIUS_M
from analysis.transport.templates import (
    EmissionProfile,
    TemplateCamera,
    TemplateGrid,
    TemplateSettings,
    build_template_grid,
)
from bench.mitsuba_scene import MitsubaStrip, render_strip

FOCAL_PX = 1224.0 / math.tan(math.radians(8.0))
WATERS = {"clear": (100.0, 140.0), "deep-sea-460": (65.0, 50.0), "turbid": (25.0, 25.0)}
DISTANCES = (21.56, 41.62)
REACH_PX = 160
BIN_PX = 8


def transport_grid(
    distance_m: float, ls: float, photons: int, orders: int, cache: TemplateCache, seed: int = 3
) -> TemplateGrid:
    """The transport's templates for one camera at ``distance_m``, one scattering-length node ``ls``."""
    settings = TemplateSettings(
        cameras=(TemplateCamera("camera", distance_m, 1),),
        focal_px=FOCAL_PX,
        n_bands=REACH_PX,
        lambda_sca_nodes_m=(ls,),
        n_photons=photons,
        max_order=orders,
        seed=seed,
    )
    return build_template_grid(settings, cache)


def transport_profile(
    distance_m: float, la: float, ls: float, photons: int, orders: int, cache: TemplateCache
) -> tuple[np.ndarray, np.ndarray]:
    """The transport's halo per one-pixel band (radiance, error), uniform LEM, at exactly this water."""
    grid = transport_grid(distance_m, ls, photons, orders, cache)
    value, err = grid.halo(la, ls).total(EmissionProfile(1.0))
    return value[0], err[0]


def compare_halo(strip: MitsubaStrip, value: np.ndarray, err: np.ndarray, r_disk: float) -> dict[str, object]:
    """Mitsuba and transport in 8-px bins from 1.2 disk radii out, averaged over the strip's pixels."""
    start = math.ceil(1.2 * r_disk)
    edges = np.arange(start, REACH_PX + 1, BIN_PX, dtype=float)
    m, m_err = strip.binned(edges)
    band = np.minimum(strip.rho_px.ravel().astype(int), REACH_PX - 1)
    bins = np.searchsorted(edges, strip.rho_px.ravel(), side="right") - 1
    t = np.full(len(edges) - 1, np.nan)
    t_err = np.full(len(edges) - 1, np.nan)
    for i in range(len(edges) - 1):
        b = band[bins == i]
        if b.size:
            t[i] = float(value[b].mean())
            # The Monte Carlo tallies 8-px bins, interpolated onto the bands: errors of neighbouring
            # bands are correlated, so the mean's error is taken as the bands' mean error.
            t_err[i] = float(np.mean(err[b]))
    ok = np.isfinite(m) & np.isfinite(t)
    comb = np.hypot(m_err, t_err)
    chi2 = float(np.sum(((m - t) / comb)[ok] ** 2))
    ratio = m / t
    return {
        "centres_px": (0.5 * (edges[1:] + edges[:-1])).tolist(),
        "mitsuba": m.tolist(),
        "mitsuba_err": m_err.tolist(),
        "transport": t.tolist(),
        "transport_err": t_err.tolist(),
        "ratio": ratio.tolist(),
        "ratio_err": (ratio * np.hypot(m_err / m, t_err / t)).tolist(),
        "chi2": chi2,
        "ndof": int(ok.sum()),
        "max_abs_dev": float(np.nanmax(np.abs(ratio[ok] - 1.0))),
        "max_pull": float(np.nanmax(np.abs((m - t) / comb)[ok])),
    }


def compare_direct(
    strip: MitsubaStrip, distance_m: float, la: float, ls: float, r_disk: float
) -> dict[str, float]:
    """Central pixels (within half the disk radius) of the no-scattering render, against exact and model."""
    sigma_t = 1.0 / la + 1.0 / ls
    inner = strip.rho_px < 0.5 * r_disk
    psi = np.arctan(strip.rho_px[inner] / FOCAL_PX)
    a, big_l = LEM_RADIUS_M, distance_m
    s = big_l * np.cos(psi) - np.sqrt(a * a - (big_l * np.sin(psi)) ** 2)
    exact = float(np.mean(np.exp(-sigma_t * s)))
    vals = strip.radiance[inner]
    mi_mean = float(vals.mean())
    mi_err = float(vals.std(ddof=1) / math.sqrt(vals.size))
    one_band = BandPixels(
        distance_px=strip.rho_px[inner].astype(np.float64),
        band=np.zeros(int(inner.sum()), dtype=np.int32),
        count=np.array([int(inner.sum())]),
        flat_index=np.flatnonzero(inner.ravel()),
    )
    moments = one_band.disk_path_moments(r_disk, 0.0, big_l, a, FOCAL_PX)
    model = float(disk_transmittance(moments, big_l, a, 1.0 / sigma_t)[0])
    return {
        "mitsuba": mi_mean,
        "mitsuba_err": mi_err,
        "exact": exact,
        "model": model,
        "mitsuba_over_exact": mi_mean / exact,
        "model_over_exact": model / exact,
    }


def figure(results: list[dict[str, object]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4), dpi=110, sharey=True)
    for ax, dist in zip(axes, DISTANCES, strict=True):
        for res in (r for r in results if r["distance_m"] == dist):
            h = res["halo"]
            x = np.asarray(h["centres_px"])
            ax.errorbar(
                x,
                np.asarray(h["ratio"]),
                yerr=np.asarray(h["ratio_err"]),
                fmt="o-",
                ms=3,
                capsize=2,
                label=f"{res['water']} (χ²/ndof {h['chi2']:.0f}/{h['ndof']})",
            )
        ax.axhline(1.0, color="k", lw=0.8)
        ax.axhspan(0.98, 1.02, color="#ccc", alpha=0.5, lw=0)
        ax.set_title(f"camera at {dist} m")
        ax.set_xlabel("radius from the LEM's centre [px]")
        ax.legend(fontsize=7)
    axes[0].set_ylabel("halo: Mitsuba / transport")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--spp", type=int, default=512)
    ap.add_argument("--photons", type=int, default=300_000)
    ap.add_argument("--orders", type=int, default=12, help="scattering orders of both engines")
    ap.add_argument("--waters", default=",".join(WATERS))
    ap.add_argument("--cache", default=None)
    ap.add_argument("--figure", type=Path, default=None)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    cache = TemplateCache(args.cache or tempfile.mkdtemp(prefix="camcal-mitsuba-"))
    results = []
    for water in args.waters.split(","):
        la, ls = WATERS[water]
        for dist in DISTANCES:
            r_disk = disk_radius_px(dist, LEM_RADIUS_M, FOCAL_PX)
            t0 = time.perf_counter()
            value, err = transport_profile(dist, la, ls, args.photons, args.orders, cache)
            t_tr = time.perf_counter() - t0
            strip = render_strip(dist, la, ls, FOCAL_PX, spp=args.spp, max_depth=args.orders + 2)
            direct = render_strip(
                dist,
                la,
                ls,
                FOCAL_PX,
                scattering=False,
                reach_px=int(r_disk // 2) + 2,
                height_px=16,
                spp=args.spp * 4,
            )
            res = {
                "water": water,
                "lambda_abs_m": la,
                "lambda_sca_m": ls,
                "distance_m": dist,
                "halo": compare_halo(strip, value, err, r_disk),
                "direct": compare_direct(direct, dist, la, ls, r_disk),
                "seconds": {"transport": t_tr, "mitsuba": strip.seconds, "mitsuba_direct": direct.seconds},
            }
            results.append(res)
            h, d = res["halo"], res["direct"]
            print(
                f"  {water} {dist} m: halo χ²/ndof {h['chi2']:.1f}/{h['ndof']}, max |dev| "
                f"{100 * h['max_abs_dev']:.1f} %; direct Mitsuba/exact {d['mitsuba_over_exact']:.4f} ± "
                f"{d['mitsuba_err'] / d['exact']:.4f}, model/exact {d['model_over_exact']:.4f} "
                f"({strip.seconds:.0f} s + {direct.seconds:.0f} s Mitsuba, {t_tr:.0f} s transport)",
                flush=True,
            )
    print()
    print(
        f"Mitsuba 3 scalar_rgb volpath, {args.spp} spp (halo) / {4 * args.spp} spp (direct); transport "
        f"{args.photons} photons; both {args.orders} scattering orders"
    )
    print(
        "| water | L [m] | halo bins | χ²/ndof | max abs(dev) | max abs(pull) | direct: Mitsuba/exact | "
        "fit's disk model/exact |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for r in results:
        h, d = r["halo"], r["direct"]
        print(
            f"| {r['water']} | {r['distance_m']} | {h['ndof']} | {h['chi2'] / max(h['ndof'], 1):.2f} | "
            f"{100 * h['max_abs_dev']:.1f} % | {h['max_pull']:.1f} | {d['mitsuba_over_exact']:.4f} ± "
            f"{d['mitsuba_err'] / d['exact']:.4f} | {d['model_over_exact']:.4f} |"
        )
    if args.figure:
        figure(results, args.figure)
        print(f"wrote {args.figure}")
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
