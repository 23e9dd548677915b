"""Benchmark of the photon transport, the template grid and the χ² fit.

    python bench/bench_transport.py [--quick]

1. photons per second of the vectorised transport (`analysis.transport.engine`)
   against the same algorithm written as a plain per-photon Python loop
   (`python_loop_transport` below), measured in the same run; both tallies
   are compared to show they compute the same thing;
2. the time to build the default template grid (7 scattering lengths, 10⁶
   photons each) into an empty cache, and to load it again;
3. the time of one χ² fit (one wavelength, five settings of stacked profiles)
   with the templates cached.
"""

from __future__ import annotations

import argparse
import math
import random
import tempfile
import time
from dataclasses import replace

import numpy as np

from analysis import FrameRecord, Setting, analyze_frame, stack_by_setting
from analysis.attenuation import EmissionRatio, Geometry
from analysis.chisq import FitConfig, collect_settings, fit_wavelength
from analysis.scattering import WaterOptics
from analysis.transport.cache import TemplateCache
from analysis.transport.engine import _proposals, run_transport
from analysis.transport.proposals import AXIS_SHARES, CAP_UNIFORM_SHARE, INNER_PSI_SHARE, ConeProposal
from analysis.transport.scene import (
    CameraSite,
    ScatteringMedium,
    TransportConfig,
    TransportScene,
    band_edges_px,
)
from analysis.transport.templates import TemplateGrid, TemplateSettings, build_template_grid
from camcal.core.parallel import process_pool
from lrm.sim import CameraModel, FrameRenderer
from lrm.sim.render import TransportHalo
from lrm.sim.scene import TREX_PLACEMENTS, Water

FOCAL_PX = 1224.0 / math.tan(math.radians(8.0))


# -- the same algorithm, one photon at a time ------------------------------------------------


def _grid(settings: TemplateSettings, cache: TemplateCache, workers: int) -> TemplateGrid:
    """The template grid, its missing pieces computed on a pool of ``workers`` processes."""
    with process_pool(max(1, workers)) as pool:
        return build_template_grid(settings, cache, executor=pool)


def _hg_sr(c: float, g: float) -> float:
    return (1 - g * g) / (4 * math.pi * (1 + g * g - 2 * g * c) ** 1.5)


def _phase_sr(c: float, g: float, f: float) -> float:
    return (1 - f) * _hg_sr(c, g) + f * 3 / (16 * math.pi) * (1 + c * c)


def _hg_cos(xi: float, g: float) -> float:
    frac = (1 - g * g) / (1 - g + 2 * g * xi)
    return max(-1.0, min(1.0, (1 + g * g - frac * frac) / (2 * g)))


def _rayleigh_cos(xi: float) -> float:
    z = 4 * xi - 2
    root = math.sqrt(z * z + 1)
    return math.copysign(abs(z + root) ** (1 / 3), z + root) + math.copysign(
        abs(z - root) ** (1 / 3), z - root
    )


def _rotate(u: tuple[float, float, float], mu: float, phi: float) -> tuple[float, float, float]:
    ux, uy, uz = u
    st = math.sqrt(max(1 - mu * mu, 0.0))
    cp, sp = math.cos(phi), math.sin(phi)
    den2 = 1 - uz * uz
    if den2 < 1e-12:
        return (st * cp, st * sp, math.copysign(mu, uz))
    den = math.sqrt(den2)
    x = st * (ux * uz * cp - uy * sp) / den + ux * mu
    y = st * (uy * uz * cp + ux * sp) / den + uy * mu
    z = -st * cp * den + uz * mu
    n = math.sqrt(x * x + y * y + z * z)
    return (x / n, y / n, z / n)


def _blocked(p: tuple[float, float, float], d: tuple[float, float, float], length: float, a: float) -> bool:
    t = min(max(-(p[0] * d[0] + p[1] * d[1] + p[2] * d[2]), 0.0), length)
    q = (p[0] + t * d[0], p[1] + t * d[1], p[2] + t * d[2])
    return q[0] ** 2 + q[1] ** 2 + q[2] ** 2 < a * a


def _cone_sample(prop: ConeProposal, rng: random.Random) -> tuple[float, float, float]:
    big_l, a = prop.camera.distance_m, prop.lem_radius_m
    xi = rng.random()
    if prop.psi_outer_rad > prop.psi_inner_rad * 1.0001:
        if rng.random() < INNER_PSI_SHARE:
            psi = prop.psi_inner_rad * xi
        else:
            psi = prop.psi_inner_rad * (prop.psi_outer_rad / prop.psi_inner_rad) ** xi
    else:
        psi = prop.psi_outer_rad * xi
    t0 = min(max(psi * big_l / prop.forward_width_rad, a), 0.5 * big_l)
    xi, pick = rng.random(), rng.random()
    if pick < AXIS_SHARES[0]:
        t = 1 / (1 / t0 - xi * (1 / t0 - 1 / big_l))
    elif pick < AXIS_SHARES[0] + AXIS_SHARES[1]:
        t = big_l * xi
    else:
        t = a * (big_l / a) ** xi
    b = (big_l - t) * math.tan(psi)
    phi = 2 * math.pi * rng.random()
    return (b * math.cos(phi), b * math.sin(phi), prop.camera.side * t)


def _cone_pdf(prop: ConeProposal, x: tuple[float, float, float]) -> float:
    return float(prop.pdf(np.array([x]))[0])  # the one density shared with the vectorised code


def python_loop_transport(
    scene: TransportScene, medium: ScatteringMedium, config: TransportConfig, seed: int
) -> np.ndarray:
    """The engine's estimator, photon by photon: Σw per camera and scattering order (fine bands)."""
    rng = random.Random(seed)
    a, lam, g, f = scene.lem_radius_m, medium.lambda_sca_m, medium.mie_g, medium.rayleigh_fraction
    props = _proposals(scene, medium)
    q_nat = config.natural_fraction
    q_cone = (1 - q_nat) / len(props)
    packet = 4 * math.pi**2 * a * a / config.n_photons
    edge = scene.band_edges_px[-1]
    out = np.zeros((len(scene.cameras), config.max_order + 1))

    def strategy() -> int:
        xi = rng.random()
        return 0 if xi < q_nat else 1 + min(int((xi - q_nat) / (1 - q_nat) * len(props)), len(props) - 1)

    for _ in range(config.n_photons):
        s = strategy()
        if s == 0:
            n = _rotate((0.0, 0.0, 1.0), 2 * rng.random() - 1, 2 * math.pi * rng.random())
            d = _rotate(n, math.sqrt(rng.random()), 2 * math.pi * rng.random())
            step = rng.expovariate(1 / lam)
            y = (a * n[0], a * n[1], a * n[2])
            x = (y[0] + step * d[0], y[1] + step * d[1], y[2] + step * d[2])
        else:
            prop = props[s - 1]
            x = _cone_sample(prop, rng)
            r = math.sqrt(x[0] ** 2 + x[1] ** 2 + x[2] ** 2)
            if r <= a:
                continue
            if rng.random() < CAP_UNIFORM_SHARE:
                cos_a = math.sqrt(1 - (a / r) ** 2)
                toward = _rotate(
                    (-x[0] / r, -x[1] / r, -x[2] / r),
                    cos_a + (1 - cos_a) * rng.random(),
                    2 * math.pi * rng.random(),
                )
            else:
                tc = (-x[0], -x[1], prop.camera.z_m - x[2])
                nc = math.sqrt(tc[0] ** 2 + tc[1] ** 2 + tc[2] ** 2)
                light = _rotate(
                    (tc[0] / nc, tc[1] / nc, tc[2] / nc), _hg_cos(rng.random(), g), 2 * math.pi * rng.random()
                )
                toward = (-light[0], -light[1], -light[2])
            b = x[0] * toward[0] + x[1] * toward[1] + x[2] * toward[2]
            disc = b * b - (r * r - a * a)
            if disc < 0 or b >= 0:
                continue
            t = -b - math.sqrt(disc)
            y = (x[0] + t * toward[0], x[1] + t * toward[1], x[2] + t * toward[2])
        seg = (x[0] - y[0], x[1] - y[1], x[2] - y[2])
        step = math.sqrt(seg[0] ** 2 + seg[1] ** 2 + seg[2] ** 2)
        d = (seg[0] / step, seg[1] / step, seg[2] / step)
        r = math.sqrt(x[0] ** 2 + x[1] ** 2 + x[2] ** 2)
        omega = 2 * math.pi * (a / r) ** 2 / (1 + math.sqrt(max(1 - (a / r) ** 2, 0.0)))
        natural = math.exp(-step / lam) / (4 * math.pi**2 * a * a * lam)
        mix = q_nat * natural
        for prop in props:
            tc = (-x[0], -x[1], prop.camera.z_m - x[2])
            nc = math.sqrt(tc[0] ** 2 + tc[1] ** 2 + tc[2] ** 2)
            guided = _hg_sr((d[0] * tc[0] + d[1] * tc[1] + d[2] * tc[2]) / nc, g)
            mix += (
                q_cone * _cone_pdf(prop, x) * (CAP_UNIFORM_SHARE / omega + (1 - CAP_UNIFORM_SHARE) * guided)
            )
        w = natural / mix
        path = step
        for order in range(1, config.max_order + 1):
            for c, cam in enumerate(scene.cameras):
                u = cam.distance_m - cam.side * x[2]
                if u <= 0 or cam.focal_px * math.hypot(x[0], x[1]) / u >= edge:
                    continue
                v = (-x[0], -x[1], cam.z_m - x[2])
                dist = math.sqrt(v[0] ** 2 + v[1] ** 2 + v[2] ** 2)
                to = (v[0] / dist, v[1] / dist, v[2] / dist)
                if _blocked(x, to, dist, a):
                    continue
                ct = d[0] * to[0] + d[1] * to[1] + d[2] * to[2]
                out[c, order] += packet * w * _phase_sr(ct, g, f) * math.exp(-dist / lam) / (dist * dist)
            if order == config.max_order:
                break
            s = strategy()
            if s == 0:
                xi = rng.random()
                mu = _rayleigh_cos(xi) if rng.random() < f else _hg_cos(xi, g)
                dn = _rotate(d, mu, 2 * math.pi * rng.random())
                step = rng.expovariate(1 / lam)
                xn = (x[0] + step * dn[0], x[1] + step * dn[1], x[2] + step * dn[2])
            else:
                xn = _cone_sample(props[s - 1], rng)
                seg = (xn[0] - x[0], xn[1] - x[1], xn[2] - x[2])
                step = max(math.sqrt(seg[0] ** 2 + seg[1] ** 2 + seg[2] ** 2), 1e-12)
                dn = (seg[0] / step, seg[1] / step, seg[2] / step)
            if _blocked(x, dn, step, a) or xn[0] ** 2 + xn[1] ** 2 + xn[2] ** 2 <= a * a:
                break
            ct = d[0] * dn[0] + d[1] * dn[1] + d[2] * dn[2]
            natural = _phase_sr(ct, g, f) * math.exp(-step / lam) / (lam * step * step)
            mix = q_nat * natural + sum(q_cone * _cone_pdf(p, xn) for p in props)
            w *= natural / mix
            path += step
            x, d = xn, dn
            if path >= config.path_max_m:
                break
    return out


# -- the benchmarks ---------------------------------------------------------------------------


def bench_photons(n_vector: int, n_loop: int) -> None:
    scene = TransportScene(
        (CameraSite("near", 21.56, 1, FOCAL_PX), CameraSite("far", 41.62, -1, FOCAL_PX)), band_edges_px(152)
    )
    medium = ScatteringMedium(40.0, 0.93, 0.17)
    cfg = TransportConfig(n_photons=n_vector, max_order=6, direct_samples=0)
    t = time.perf_counter()
    tally = run_transport(scene, medium, cfg, seed=1)
    vec_s = time.perf_counter() - t
    vec_rate = n_vector / vec_s
    t = time.perf_counter()
    loop = python_loop_transport(scene, medium, replace(cfg, n_photons=n_loop), seed=2)
    loop_s = time.perf_counter() - t
    loop_rate = n_loop / loop_s
    print("1. photon transport (two cameras, λ_sca 40 m, up to 6 scatterings, next-event estimation)")
    print(f"   vectorised numpy : {n_vector:>9,d} photons in {vec_s:6.2f} s = {vec_rate:>10,.0f} photons/s")
    print(f"   per-photon loop  : {n_loop:>9,d} photons in {loop_s:6.2f} s = {loop_rate:>10,.0f} photons/s")
    print(f"   speed-up         : {vec_rate / loop_rate:.0f} x")
    vec_o1 = tally.sum_w[:, :, 1].sum(axis=(1, 2, 3))
    print(
        "   same estimator   : order-1 flux per camera, vectorised "
        + ", ".join(f"{v:.3e}" for v in vec_o1)
        + " / loop "
        + ", ".join(f"{v:.3e}" for v in loop[:, 1])
        + f" (loop has {n_loop / n_vector:.1%} of the photons)"
    )


def bench_templates(n_photons: int, workers: int) -> TemplateSettings:
    settings = TemplateSettings.near_far(21.56, 41.62, FOCAL_PX, n_bands=144, n_photons=n_photons)
    with tempfile.TemporaryDirectory() as tmp:
        cache = TemplateCache(tmp)
        t = time.perf_counter()
        _grid(settings, cache, workers)
        build_s = time.perf_counter() - t
        t = time.perf_counter()
        grid = _grid(settings, cache, workers)
        load_s = time.perf_counter() - t
        t = time.perf_counter()
        for _ in range(100):
            grid.halo(50.0, 40.0)
        eval_ms = (time.perf_counter() - t) * 10
    nodes = len(settings.lambda_sca_nodes_m)
    print(f"2. template grid: {nodes} scattering lengths x {n_photons:,d} photons, {workers} worker(s)")
    print(f"   build {build_s:.1f} s into an empty cache, load {load_s:.2f} s, one template {eval_ms:.1f} ms")
    return settings


def bench_fit(settings: TemplateSettings, workers: int) -> None:
    cam = CameraModel(width_px=800, height_px=700, fov_deg=2 * math.degrees(math.atan(400 / FOCAL_PX)))
    water = Water({460: WaterOptics(65.0, 50.0)}, name="trex")
    with tempfile.TemporaryDirectory() as tmp:
        cache = TemplateCache(tmp)
        grid_settings = replace(settings, outer_px=1130.0, n_outer=16)
        grid = _grid(grid_settings, cache, workers)
        renderers = {
            p.camera: FrameRenderer(cam, p, water, halo_model="transport", transport=TransportHalo(grid=grid))
            for p in TREX_PLACEMENTS
        }
        rng = np.random.default_rng(0)
        records = []
        for exposure, gain in ((0.01, 14.0), (0.02, 14.0), (0.01, 18.0), (0.02, 16.0), (0.03, 14.0)):
            for _ in range(5):
                for name, r in renderers.items():
                    frame, _ = r.render(460, exposure, gain, rng=rng, offset_px=tuple(rng.normal(0, 1.5, 2)))
                    records.append(FrameRecord(name, Setting(460, exposure, gain), analyze_frame(frame)))
        profiles = collect_settings(stack_by_setting(records), 460, "A", "B")
        geometry = Geometry("A", "B", 21.56, 0.02, 41.62, 0.04)
        t = time.perf_counter()
        # Frames and templates share the Monte Carlo sample: no template errors (FitConfig).
        config = FitConfig(template_errors=False)
        fit = fit_wavelength(460, profiles, grid, geometry, EmissionRatio(1.27, 0.04), config)
        fit_s = time.perf_counter() - t
    print(
        f"3. one χ² fit (460 nm, {len(profiles)} settings, cached templates): {fit_s:.1f} s, "
        f"{fit.n_evaluations} χ² evaluations ({1000 * fit_s / fit.n_evaluations:.1f} ms each)"
    )
    print(
        f"   λ_abs {fit.lambda_abs_m:.1f} ± {fit.lambda_abs_err_m:.1f} m (true 65), "
        f"λ_sca {fit.lambda_sca_m:.2f} ± {fit.lambda_sca_err_m:.2f} m (true 50)"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer photons (a smoke run)")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    if args.quick:
        bench_photons(50_000, 500)
        settings = bench_templates(100_000, args.workers)
    else:
        bench_photons(400_000, 4_000)
        settings = bench_templates(1_000_000, args.workers)
    bench_fit(settings, args.workers)


if __name__ == "__main__":
    main()
