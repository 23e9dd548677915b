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
import asyncio
import json
import math
import os
import random
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import cv2  # noqa: E402
import httpx  # noqa: E402
import numpy as np  # noqa: E402
import zmq  # noqa: E402

from camcal.core import wire  # noqa: E402
from tests.utils.system import CHROMIUM, CHROMIUM_ARGS, camcal_up, free_ports, stop_system, wait_until  # noqa: E402


def pct(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else math.nan


def cli(*args: str) -> list[str]:
    return [sys.executable, "-c", "from camcal.cli import main; main()", *args]


def spawn(args: list[str], log: Path) -> subprocess.Popen[bytes]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("CAMCAL_")}
    env["PYTHONPATH"] = str(REPO)
    env["CAMCAL_HTTP_MAX_CONNECTIONS_PER_CLIENT"] = "64"  # the simulated browsers share one address
    with log.open("ab") as fh:
        return subprocess.Popen(args, stdout=fh, stderr=subprocess.STDOUT, env=env, cwd=log.parent)


def wait_http(url: str, timeout_s: float = 60) -> None:
    def up() -> bool:
        try:
            return httpx.get(url, timeout=2).status_code == 200
        except httpx.HTTPError:
            return False

    wait_until(up, timeout_s, url, every_s=0.2)


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
        points = [
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


# ------------------------------------------------------------------ 4: ingest rate with browsers
def encoded_frames() -> list[tuple[str, int, float, float, bytes]]:
    """PNG frames of both modules (small sensor, T-REX plate scale), rendered once."""
    from tests.utils.sim import SMALL_CAMERA, renderer

    out = []
    rng = np.random.default_rng(7)
    for m, dist, far in (("A", 21.56, False), ("B", 41.62, True)):
        r = renderer("trex", dist, far, SMALL_CAMERA, m)
        for wl in (405, 460, 525):
            for e, g in ((0.05, 8.0), (0.07, 8.0), (0.11, 2.0), (0.05, 14.0)):
                frame, _ = r.render(wl, e, g, rng=rng)
                _, buf = cv2.imencode(".png", frame)
                out.append((m, wl, e, g, buf.tobytes()))
    return out


class Sender:
    """A module that pushes pre-encoded frames as fast as the ship's window allows."""

    def __init__(self, ctx: zmq.Context[Any], endpoint: str, module: str) -> None:
        self.module = module
        self.boot = f"bench{int(time.time() * 1000) % 10**9}{module}"
        self.sock = wire.module_socket(ctx, endpoint, module)
        self.window = 1
        self.welcomed = False
        self.in_flight: set[int] = set()
        self.seq = 0
        self.acked = 0

    def hello(self) -> None:
        self.sock.send_multipart(wire.encode(wire.Hello(module=self.module, boot=self.boot)))

    def send(self, frame: tuple[str, int, float, float, bytes], shape: tuple[int, int]) -> None:
        _, wl, e, g, png = frame
        self.seq += 1
        msg = wire.FrameMsg(
            module=self.module,
            boot=self.boot,
            seq=self.seq,
            captured_at=datetime.now(UTC),
            camera=self.module,
            wavelength_nm=wl,
            exposure_s=e,
            gain_db=g,
            depth_m=3420.0,
            width_px=shape[1],
            height_px=shape[0],
            size=len(png),
            sha256=wire.sha256_hex(png),
        )
        self.sock.send_multipart(wire.encode(msg, png))
        self.in_flight.add(self.seq)

    def receive(self) -> bool:
        got = False
        while True:
            try:
                parts = self.sock.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                return got
            msg, _ = wire.decode(parts, allowed=wire.SHIP_TYPES)
            got = True
            if msg.type == "welcome":
                self.window = msg.window
                self.welcomed = True
            elif msg.type in ("ack", "ship_heartbeat"):
                self.window = msg.window
                for _boot, a, b in getattr(msg, "ranges", ()):
                    for q in range(a, b + 1):
                        if q in self.in_flight:
                            self.in_flight.discard(q)
                            self.acked += 1
            elif msg.type == "nack":
                self.in_flight.discard(msg.seq)


def analysed(base: str) -> int:
    c = httpx.get(f"{base}/api/health", timeout=5).json().get("counters") or {}
    return int(c.get("frames_analysed", 0))


def push(endpoint: str, base: str, frames: list[Any], n: int) -> tuple[float, float]:
    """Send ``n`` frames per module; frames/s stored (acked) and analysed (all results in)."""
    shape = (512, 640)
    ctx = zmq.Context()
    senders = [Sender(ctx, endpoint, m) for m in ("A", "B")]
    by_module = {m: [f for f in frames if f[0] == m] for m in ("A", "B")}
    try:
        for s in senders:
            s.hello()
        wait_until(
            lambda: [s.receive() for s in senders] and all(s.welcomed for s in senders), 20, "welcome", 0.05
        )
        start_analysed = analysed(base)
        t0 = time.perf_counter()
        poller = zmq.Poller()
        for s in senders:
            poller.register(s.sock, zmq.POLLIN)
        while any(s.acked < n for s in senders):
            for s in senders:
                while s.seq < n and len(s.in_flight) < s.window:
                    s.send(by_module[s.module][s.seq % len(by_module[s.module])], shape)
            poller.poll(50)
            for s in senders:
                s.receive()
        stored_s = time.perf_counter() - t0
        wait_until(lambda: analysed(base) - start_analysed >= 2 * n, 300, "every frame analysed", every_s=0.1)
        analysed_s = time.perf_counter() - t0
        return 2 * n / stored_s, 2 * n / analysed_s
    finally:
        for s in senders:
            s.sock.close(0)
        ctx.term()


async def _client(url: str, base: str, stop: asyncio.Event, counts: dict[str, int]) -> None:
    """One live view: parse every event; per module, load the newest thumbnail, one at a time and at
    most one every 0.5 s (what static/js/live.js does)."""
    import websockets

    pending: dict[str, str] = {}
    wake: dict[str, asyncio.Event] = {}

    async def loader(http: httpx.AsyncClient, module: str) -> None:
        while not stop.is_set():
            await wake[module].wait()
            wake[module].clear()
            url = pending.pop(module, None)
            if url is None:
                continue
            t = time.monotonic()
            r = await http.get(url)
            counts["thumbs"] += 1 if r.status_code == 200 else 0
            await asyncio.sleep(max(0.0, 0.5 - (time.monotonic() - t)))
            if module in pending:
                wake[module].set()

    async with (
        httpx.AsyncClient(base_url=base, timeout=10) as http,
        websockets.connect(url, max_size=None) as ws,
    ):
        loaders = []
        await ws.send(json.dumps({"type": "batch"}))
        queue: list[dict[str, Any]] = []
        while not stop.is_set():
            if not queue:
                try:
                    raw = await asyncio.wait_for(ws.recv(), timeout=1)
                except TimeoutError:
                    continue
                got = json.loads(raw)
                queue = got["messages"] if got.get("type") == "batch" else [got]
            msg = queue.pop(0)
            counts["messages"] += 1
            if msg.get("type") == "missed":
                counts["missed"] += sum(msg.get("dropped", {}).values())
                if msg.get("resync"):
                    await ws.send(json.dumps({"type": "resync"}))
            if msg.get("kind") == "result" and msg["payload"].get("thumb"):
                m = msg["module"]
                if m not in wake:
                    wake[m] = asyncio.Event()
                    loaders.append(asyncio.create_task(loader(http, m)))
                pending[m] = msg["payload"]["thumb"]
                wake[m].set()
        for t in loaders:
            t.cancel()


def run_clients(base: str, n: int, seconds: float) -> None:
    """Child process: ``n`` live-view clients until SIGINT (or ``seconds``); prints what they received."""
    url = base.replace("http://", "ws://") + "/ws/live"
    counts = {"messages": 0, "thumbs": 0, "missed": 0}

    async def main() -> None:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        loop.add_signal_handler(signal.SIGINT, stop.set)
        loop.call_later(seconds, stop.set)
        await asyncio.gather(*(_client(url, base, stop, counts) for _ in range(n)))

    asyncio.run(main())
    print(json.dumps(counts), flush=True)


def cpu_s(pid: int) -> float:
    """CPU seconds (user + system) a process has used so far."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def bench_ingest(n_frames: int, n_clients: int, rounds: int) -> dict[str, Any]:
    frames = encoded_frames()
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "data"
        port, ingest_port, events_port = free_ports(3)
        endpoint = f"tcp://127.0.0.1:{ingest_port}"
        events = f"tcp://127.0.0.1:{events_port}"
        base = f"http://127.0.0.1:{port}"
        from storage.store import Store

        Store.open(data).close()  # create the database before either process opens it
        procs = [
            spawn(
                # Plaintext: this bench measures what browsers cost the ship, not the link's encryption.
                cli(
                    "ingest",
                    "--data",
                    str(data),
                    "--bind",
                    endpoint,
                    "--events",
                    events,
                    "--no-fsync",
                    "--plaintext",
                ),
                Path(tmp) / "ingest.log",
            )
        ]
        procs.append(
            spawn(
                cli("serve", "--data", str(data), "--port", str(port), "--events", events),
                Path(tmp) / "serve.log",
            )
        )
        try:
            wait_http(f"{base}/api/health")
            wait_until(
                lambda: httpx.get(f"{base}/api/health", timeout=2).json()["ingest"]["up"], 30, "ingest up"
            )
            push(endpoint, base, frames, 20)  # warm-up: pool, caches, thumbnails folder
            results: dict[str, list[tuple[float, float]]] = {"none": [], "clients": []}
            server_cpu: dict[str, list[float]] = {"none": [], "clients": []}
            client_cpu: list[float] = []
            received = []
            for _ in range(rounds):
                c0 = cpu_s(procs[1].pid)
                results["none"].append(push(endpoint, base, frames, n_frames))
                server_cpu["none"].append(cpu_s(procs[1].pid) - c0)
                # The clients stand in for tablets: niced, so they take only CPU the ship would not use.
                child = subprocess.Popen(
                    [
                        "nice",
                        "-n",
                        "19",
                        sys.executable,
                        __file__,
                        "--run-clients",
                        base,
                        str(n_clients),
                        "600",
                    ],
                    stdout=subprocess.PIPE,
                    env={**os.environ, "PYTHONPATH": str(REPO)},
                )
                wait_until(
                    lambda: (
                        httpx.get(f"{base}/api/health", timeout=2).json()["server"]["clients"] >= n_clients
                    ),
                    30,
                    f"{n_clients} clients connected",
                )
                c0, k0 = cpu_s(procs[1].pid), cpu_s(child.pid)
                results["clients"].append(push(endpoint, base, frames, n_frames))
                server_cpu["clients"].append(cpu_s(procs[1].pid) - c0)
                client_cpu.append(cpu_s(child.pid) - k0)
                child.send_signal(signal.SIGINT)
                try:
                    out, _ = child.communicate(timeout=60)
                    received.append(out.decode().strip())
                except subprocess.TimeoutExpired:
                    child.kill()
        finally:
            for p in reversed(procs):
                stop_system(p)
    return {"results": results, "received": received, "server_cpu": server_cpu, "client_cpu": client_cpu}


def main() -> None:
    if len(sys.argv) == 5 and sys.argv[1] == "--run-clients":
        run_clients(sys.argv[2], int(sys.argv[3]), float(sys.argv[4]))
        return
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
