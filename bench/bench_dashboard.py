"""Benchmark of the dashboard, in one run: what a deck tablet waits for, and what browsers cost the ingest.

1. page load to first live data (navigation start to the first snapshot drawn, and to the first
   thumbnail shown), median of several loads of the live view, headless Chromium, real system;
2. thumbnail latency: a ``result`` event reaches the page -> its thumbnail is loaded and shown;
3. API latency on a 3000-frame dive (synthetic rows written through ``storage.store.Store``): the
   frame list (first page, a filtered page, a deep page), the λ_att series, the λ_att table;
4. ingest rate with 20 WebSocket clients connected against none, in alternating rounds: two
   modules push pre-encoded frames as fast as the ship's window allows; the rate is frames stored
   (acknowledged) per second and frames through the whole pipeline (stored, analysed, published)
   per second. Each client does what static/js/live.js does: asks for batched events, parses every
   event, loads the newest thumbnail per module at most every 0.5 s. Aim: within 10 %.

On a 2-core machine the clients, the server, the ingest and its analysis share the cores. The
clients stand in for tablets, so they run niced; their CPU and the server's are printed per round.

Run: ``.venv/bin/python bench/bench_dashboard.py [--loads 5] [--frames 120] [--rounds 6]``.
Needs /usr/bin/chromium and playwright (Python) for parts 1-2 (skipped without them).
"""

from __future__ import annotations

import argparse
import math
import random
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import httpx
from dashboard_ingest import bench_ingest
from dashboard_procs import cli, pct, spawn, wait_http

from tests.utils.system import CHROMIUM, CHROMIUM_ARGS, camcal_up, free_ports, stop_system, wait_until


# ------------------------------------------------------------------ 1 + 2: the live view
def bench_live(loads: int, watch_s: float) -> dict[str, Any]:
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        return {"skipped": "playwright is not installed"}
    if not CHROMIUM.exists():
        return {"skipped": f"{CHROMIUM} is missing"}
    out: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as tmp, camcal_up(Path(tmp) / "data") as system:
        wait_until(
            lambda: httpx.get(system.url("/api/frames?limit=1"), timeout=5).json()["total"] >= 4,
            90,
            "the first frames",
        )
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
            first_data, first_thumb = [], []
            for _ in range(loads):
                page = browser.new_page(viewport={"width": 1280, "height": 900})
                page.goto(system.url("/"))
                page.wait_for_function(
                    "() => window.camcal && window.camcal.stats.firstThumbAt !== null", timeout=60_000
                )
                stats = page.evaluate("window.camcal.stats")
                first_data.append(stats["firstDataAt"])
                first_thumb.append(stats["firstThumbAt"])
                page.close()
            page = browser.new_page(viewport={"width": 1280, "height": 900})
            page.goto(system.url("/"))
            page.wait_for_timeout(watch_s * 1000)
            lat = page.evaluate("window.camcal.stats.thumbLatencyMs")
            browser.close()
    out["first_data_ms"] = statistics.median(first_data)
    out["first_thumb_ms"] = statistics.median(first_thumb)
    out["thumb_latency_ms"] = (statistics.median(lat) if lat else math.nan, pct(lat, 95), len(lat))
    return out


# ------------------------------------------------------------------ 3: API on a 3000-frame dive
def build_store(data: Path, n_frames: int = 3000) -> int:
    """A dive of ``n_frames`` frames (two modules, 3 wavelengths) with results and a λ_att series."""
    from storage.store import FrameRow, Store

    rng = random.Random(42)
    store = Store.open(data)
    try:
        dive = store.create_dive("bench-3000", started_unix_s=1_800_000_000.0)
        run = store.analysis_run(dive.id, calibration={}, software_version="bench")
        assert run is not None
        t0 = dive.started_unix_s
        exposures = (0.02, 0.05, 0.07, 0.11, 0.2, 0.5, 1.0)
        gains = (2.0, 8.0, 14.0, 20.0)
        rows = []
        for i in range(n_frames):
            m = "AB"[i % 2]
            rows.append(
                FrameRow(
                    module_id=m,
                    boot="bench",
                    seq=i // 2 + 1,
                    captured_unix_s=t0 + i * 0.6,
                    received_unix_s=t0 + i * 0.6 + 0.2,
                    wavelength_nm=(405, 460, 525)[(i // 56) % 3],
                    exposure_s=exposures[(i // 8) % 7],
                    gain_db=gains[(i // 2) % 4],
                    depth_m=3420.0 + rng.gauss(0, 0.5),
                    width_px=612,
                    height_px=512,
                    path=f"frames/1/{m}/bench/{i // 2 + 1:08d}.png",
                    size_bytes=400_000,
                    sha256="0" * 64,
                )
            )
        ids = []
        for k in range(0, n_frames, 500):
            out = store.commit_batch(dive.id, rows[k : k + 500])
            ids += [out.new_frames[(r.module_id, r.boot, r.seq)] for r in rows[k : k + 500]]
        radii = [i + 0.5 for i in range(150)]
        results = []
        for fid, r in zip(ids, rows, strict=True):
            ok = rng.random() > 0.15
            results.append(
                {
                    "frame_id": fid,
                    "status": "ok" if ok else "rejected",
                    "reason": None if ok else "saturated",
                    "centroid_x_px": 306 + rng.gauss(0, 2),
                    "centroid_y_px": 256 + rng.gauss(0, 2),
                    "radius_px": 44.0 if r.module_id == "A" else 23.0,
                    "center_gray": 120.0,
                    "i_center_gray": 110.0 if ok else None,
                    "i_center_err_gray": 0.5 if ok else None,
                    "background_gray": 2.5,
                    "profile": {
                        "radius_px": radii,
                        "mean_gray": [2.5 + 100 * math.exp(-x / 30) for x in radii],
                        "sem_gray": [0.1] * 150,
                        "count": [int(6 * x) for x in radii],
                    },
                    "fit": {
                        "amplitude_gray": 100.0,
                        "scale_px": 30.0,
                        "background_gray": 2.5,
                        "r_min_px": 50,
                    },
                    "analysed_unix_s": r.received_unix_s + 0.1,
                }
            )
        for k in range(0, len(results), 500):
            store.save_results(run.id, results[k : k + 500])
        points: list[dict[str, Any]] = [
            {
                "run_id": run.id,
                "dive_id": dive.id,
                "wavelength_nm": wl,
                "t_unix_s": t0 + j * 6.0,
                "depth_m": 3420.0,
                "lambda_att_m": lam + rng.gauss(0, 0.3),
                "stat_err_m": 0.2,
                "sys_err_m": 0.8,
                "n_pairs": 6,
                "window_s": 600.0,
                "details": {"pairs": []},
            }
            for wl, lam in ((405, 20.0), (460, 28.0), (525, 21.0))
            for j in range(300)
        ]
        store.add_attenuation_points(points)
        return dive.id
    finally:
        store.close()


def bench_api(repeats: int) -> dict[str, tuple[float, float]]:
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "data"
        t = time.perf_counter()
        dive = build_store(data)
        build_s = time.perf_counter() - t
        (port,) = free_ports(1)
        proc = spawn(
            cli("serve", "--data", str(data), "--port", str(port), "--events", "none"),
            Path(tmp) / "serve.log",
        )
        try:
            base = f"http://127.0.0.1:{port}"
            wait_http(f"{base}/api/health")
            queries = {
                "frames, first page (50)": f"/api/frames?dive={dive}&limit=50",
                "frames, filtered (B, 460 nm, ok)": (
                    f"/api/frames?dive={dive}&module=B&wavelength_nm=460&status=ok&limit=50"
                ),
                "frames, page at offset 2900": f"/api/frames?dive={dive}&limit=50&offset=2900",
                "λ_att series (900 points)": f"/api/attenuation?dive={dive}",
                "λ_att table (3000 results)": f"/api/dives/{dive}/attenuation",
                "timeline": f"/api/dives/{dive}/timeline",
            }
            with httpx.Client(base_url=base, timeout=30) as c:
                for name, q in queries.items():
                    assert c.get(q).status_code == 200, q
                    times = []
                    for _ in range(repeats):
                        t = time.perf_counter()
                        r = c.get(q)
                        times.append((time.perf_counter() - t) * 1000)
                        r.raise_for_status()
                    out[name] = (statistics.median(times), pct(times, 95))
        finally:
            stop_system(proc)
    out["_build_s"] = (build_s, math.nan)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--loads", type=int, default=5, help="page loads of the live view")
    parser.add_argument("--watch", type=float, default=40.0, help="seconds of live thumbnails to time")
    parser.add_argument("--repeats", type=int, default=30, help="requests per API query")
    parser.add_argument("--frames", type=int, default=120, help="frames per module per ingest round")
    parser.add_argument("--clients", type=int, default=20, help="WebSocket clients")
    parser.add_argument("--rounds", type=int, default=6, help="ingest rounds (none, clients) alternated")
    parser.add_argument("--parts", default="live,api,ingest", help="which parts to run")
    args = parser.parse_args()
    parts = set(args.parts.split(","))

    live: dict[str, Any] = {"skipped": "not asked for"}
    api: dict[str, Any] = {"_build_s": (math.nan, math.nan)}
    ing: dict[str, Any] = {"results": {"none": [], "clients": []}, "received": []}
    if "live" in parts:
        print("1-2. live view in headless Chromium against camcal up (speed 20) ...", flush=True)
        live = bench_live(args.loads, args.watch)
    if "api" in parts:
        print("3. API on a 3000-frame dive ...", flush=True)
        api = bench_api(args.repeats)
    if "ingest" in parts:
        print(f"4. ingest rate, {args.clients} WebSocket clients against none ...", flush=True)
        ing = bench_ingest(args.frames, args.clients, args.rounds)

    print()
    print("| figure | value |")
    print("| --- | --- |")
    if "skipped" in live:
        print(f"| live view | skipped: {live['skipped']} |")
    else:
        print(f"| page load to first live data (median of {args.loads}) | {live['first_data_ms']:.0f} ms |")
        print(f"| page load to first thumbnail shown | {live['first_thumb_ms']:.0f} ms |")
        med, p95, n = live["thumb_latency_ms"]
        what = f"thumbnail latency, result event -> image shown (n={n})"
        print(f"| {what} | median {med:.0f} ms, p95 {p95:.0f} ms |")
    print(f"| building the 3000-frame store | {api.pop('_build_s')[0]:.1f} s |")
    for name, (med, p95) in api.items():
        print(f"| API: {name} | median {med:.1f} ms, p95 {p95:.1f} ms |")
    none = ing["results"]["none"]
    with_clients = ing["results"]["clients"]
    if not none:
        return
    s0 = statistics.median(r[0] for r in none)
    s1 = statistics.median(r[0] for r in with_clients)
    a0 = statistics.median(r[1] for r in none)
    a1 = statistics.median(r[1] for r in with_clients)
    k = args.clients
    print(f"| ingest, frames stored/s: no clients -> {k} clients | {s0:.0f} -> {s1:.0f} ({s1 / s0:.2f}x) |")
    print(f"| ingest, frames analysed/s: no clients -> {k} clients | {a0:.0f} -> {a1:.0f} ({a1 / a0:.2f}x) |")
    print(f"\nper round (stored/s, analysed/s): none {none}, clients {with_clients}")
    print(f"what the clients received per round: {ing['received']}")
    sc = ing["server_cpu"]
    print(
        f"server CPU per round: none {[round(v, 2) for v in sc['none']]} s, "
        f"clients {[round(v, 2) for v in sc['clients']]} s; "
        f"the clients' own CPU {[round(v, 2) for v in ing['client_cpu']]} s"
    )
    verdict = "within" if a1 / a0 >= 0.9 else "NOT within"
    print(f"aim: ingest with {args.clients} clients within 10 % of none -> {verdict} ({a1 / a0:.2f}x)")


if __name__ == "__main__":
    main()
