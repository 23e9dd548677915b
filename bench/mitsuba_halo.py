"""Halo tables rendered by Mitsuba 3, for frame sets whose scattered light camcal's transport never made.

    python bench/mitsuba_halo.py [--spp 1024] [--reach 320] [--out tests/data/mitsuba]

For each water (deep-sea 460 nm: λ_abs 65 m, λ_sca 50 m; turbid: 25/25 m;
⟨cos θ⟩ 0.93 with 17 % Rayleigh, a uniform Lambertian LEM) and both T-REX
distances, Mitsuba renders the strip from the LEM's centre outward
(`bench.mitsuba_scene.render_strip`), and the halo h(ρ), scattered radiance
over the LEM's surface radiance, is written per radial bin with its error
into ``<water>.npz``:

* outside the disk (ρ ≥ r_disk + 2 px): the strip's mean per bin;
* inside it (ρ ≤ r_disk − 2 px): the strip less the exact direct light
  exp(−s/λ_att), s the path to the sphere's surface (Mitsuba's direct light
  matches it to 10⁻⁴, `bench/bench_mitsuba.py`), in four wide bins (the
  direct light is a stochastic hit of the emitter in Mitsuba, so it is
  noisy per pixel);
* across the limb nothing (the box filter mixes disk and halo there): a
  reader interpolates.

`lrm.sim.render.TransportHalo.table` renders frames with such a table
(`tests/cli/test_fit_mitsuba.py` fits them). The tables are checked in:
rendering them takes minutes (printed), fitting frames made with them
seconds.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from analysis.transport.disk import disk_radius_px, surface_path_m
from analysis.transport.scene import LEM_RADIUS_M
from bench.mitsuba_scene import MitsubaStrip, render_strip

FOCAL_PX = 1224.0 / math.tan(math.radians(8.0))
DISTANCES_M = (21.56, 41.62)
#: name: λ_abs, λ_sca (m), Mie ⟨cos θ⟩, Rayleigh share. The first two are the fit's test sets
#: (`tests/analysis/test_fit_mitsuba.py`); the others check the smooth templates away from the
#: nominal phase function and in very turbid water (`tests/analysis/test_smooth_templates.py`).
WATERS = {
    "deep-sea-460": (65.0, 50.0, 0.93, 0.17),
    "turbid": (25.0, 25.0, 0.93, 0.17),
    "turbid-g85-r35": (25.0, 25.0, 0.85, 0.35),
    "turbid-g97-r05": (25.0, 25.0, 0.97, 0.05),
    "very-turbid": (30.0, 10.0, 0.93, 0.17),
    "very-turbid-g88-r30": (100.0, 8.0, 0.88, 0.30),
}
#: The fit's test sets by default: the others are rendered when named.
DEFAULT_WATERS = ("deep-sea-460", "turbid")


def halo_table(
    distance_m: float,
    la: float,
    ls: float,
    *,
    spp: int,
    reach_px: int,
    seed: int,
    mie_g: float = 0.93,
    rayleigh_fraction: float = 0.17,
    max_depth: int = 14,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Bin centres [px], halo and its error per bin, and the render's seconds, for one camera."""
    r_disk = disk_radius_px(distance_m, LEM_RADIUS_M, FOCAL_PX)
    strip = render_strip(
        distance_m,
        la,
        ls,
        FOCAL_PX,
        reach_px=reach_px,
        height_px=16,
        spp=spp,
        seed=seed,
        mie_g=mie_g,
        rayleigh_fraction=rayleigh_fraction,
        max_depth=max_depth,
    )
    att = 1.0 / (1.0 / la + 1.0 / ls)
    direct = np.where(
        strip.rho_px < r_disk,
        np.exp(-surface_path_m(np.minimum(strip.rho_px, r_disk), distance_m, LEM_RADIUS_M, FOCAL_PX) / att),
        0.0,
    )
    scattered = MitsubaStrip(strip.radiance - direct, strip.rho_px, strip.seconds)
    inner = np.linspace(0.0, r_disk - 2.0, 5)
    outer = np.arange(math.ceil(r_disk + 2.0), reach_px - 4, 4.0)
    centres, values, errors = [], [], []
    for edges in (inner, outer):
        mean, err = scattered.binned(edges)
        centres.append(0.5 * (edges[:-1] + edges[1:]))
        values.append(mean)
        errors.append(err)
    c, v, e = (np.concatenate(x) for x in (centres, values, errors))
    ok = np.isfinite(v)
    return c[ok], v[ok], e[ok], strip.seconds


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spp", type=int, default=1024)
    ap.add_argument("--reach", type=int, default=320, help="strip length [px] from the LEM's centre")
    ap.add_argument("--waters", default=",".join(DEFAULT_WATERS), help=f"of {', '.join(WATERS)}")
    ap.add_argument("--max-depth", type=int, default=14, help="Mitsuba's max_depth: scatterings + 1")
    ap.add_argument("--out", type=Path, default=Path("tests/data/mitsuba"))
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    for name in args.waters.split(","):
        la, ls, g, f = WATERS[name]
        arrays: dict[str, np.ndarray] = {
            "lambda_abs_m": np.array(la),
            "lambda_sca_m": np.array(ls),
            "mie_g": np.array(g),
            "rayleigh_fraction": np.array(f),
            "focal_px": np.array(FOCAL_PX),
            "distances_m": np.array(DISTANCES_M),
            "spp": np.array(args.spp),
            "max_depth": np.array(args.max_depth),
        }
        t0 = time.perf_counter()
        for k, dist in enumerate(DISTANCES_M):
            c, v, e, secs = halo_table(
                dist,
                la,
                ls,
                spp=args.spp,
                reach_px=args.reach,
                seed=11 + k,
                mie_g=g,
                rayleigh_fraction=f,
                max_depth=args.max_depth,
            )
            arrays[f"rho_px_{k}"], arrays[f"halo_{k}"], arrays[f"halo_err_{k}"] = c, v, e
            rel = np.median(e / np.abs(v))
            print(f"{name} {dist} m: {len(c)} bins, median error {100 * rel:.1f} %, {secs:.0f} s", flush=True)
        np.savez_compressed(args.out / f"{name}.npz", **arrays)
        print(f"{name}: {time.perf_counter() - t0:.0f} s -> {args.out / (name + '.npz')}", flush=True)


if __name__ == "__main__":
    main()
