"""Many modules into one ingest: frames/s, bytes/s and p95 latency as the module count grows.

For each module count (default 2, 8 and 32) a fresh ``camcal ingest`` runs in
its own process (analysis pool of ``--workers``, frame files fsynced as in
production), and the modules run as real `lrm.agent.Agent` instances spread
over a few processes, each sampling its sensors at 10 Hz (a message a second,
as a real module does) and sending small simulated frames (320 x 256 PNGs
cut from a T-REX camera, the LEM at its true size in pixels) at ``--rate``
frames per second for ``--seconds``, then draining their outboxes. Latency
is capture -> result stored (the ingest's ``result`` event, after the frame
and its analysis are committed), measured by a subscriber to the events.
``--rate 0`` sends flat out: the figure is then the ingest's capacity.
Columns: frames/s and MB/s stored in the steady window (after ``--warmup``),
latency percentiles, the cores the ingest's process tree used, its CPU time
per frame (the machine-independent cost), the load average (this machine is
shared: a load far above the core count means the figures are CPU-starved),
and frames never stored (must be 0).

The size of a real 5 MP frame (PNG, simulated T-REX frames at the three
wavelengths) is measured too, for the storage figures in docs/scaling.md.

Run: ``PYTHONPATH=. .venv/bin/python bench/bench_scale.py [--modules 2,8,32] [--rate 1] [--seconds 20]``.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

SMALL = (320, 256)


def free_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


# ---------------------------------------------------------------- frames
def render_pool(out: Path, per_camera: int = 8) -> dict[str, list[str]]:
    """PNG files of near-camera-like (A) and far-camera-like (B) frames on a 320 x 256 cut."""
    from camcal.core.images import encode_png
    from lrm.dive.simulation import scaled_camera
    from lrm.sim import CameraModel, FrameRenderer, Placement
    from lrm.sim.scene import water_preset

    full = CameraModel()
    cam = scaled_camera(full, SMALL[0] / full.width_px)
    cam = type(cam)(**{**cam.__dict__, "height_px": SMALL[1]})
    pool: dict[str, list[str]] = {}
    for camera, distance, far, exposure, gain in (
        ("A", 21.56, False, 0.05, 6.0),
        ("B", 41.62, True, 0.11, 8.0),
    ):
        r = FrameRenderer(
            cam, Placement(camera, distance, 0.02, faces_far_side=far), water_preset("trex"), seed=0
        )
        files = []
        for i in range(per_camera):
            frame, _ = r.render(460, exposure, gain, rng=np.random.default_rng([7, i, far]))
            path = out / f"{camera}-{i}.png"
            path.write_bytes(encode_png(frame))
            files.append(str(path))
        pool[camera] = files
    return pool


def png_size_5mp() -> dict[str, float]:
    """Mean PNG size of full 5 MP simulated T-REX frames (both cameras, three wavelengths)."""
    from analysis import analyze_frame
    from camcal.core.images import encode_png
    from lrm.sim import CameraModel, FrameRenderer, Placement
    from lrm.sim.scene import water_preset

    sizes, times, crops = [], [], []
    for camera, distance, far in (("A", 21.56, False), ("B", 41.62, True)):
        r = FrameRenderer(
            CameraModel(), Placement(camera, distance, 0.02, faces_far_side=far), water_preset("trex")
        )
        for wl, exposure, gain in ((405, 0.11, 8.0), (460, 0.05, 6.0), (525, 0.07, 6.0)):
            frame, _ = r.render(wl, exposure, gain, rng=np.random.default_rng(wl))
            t0 = time.perf_counter()
            data = encode_png(frame)
            times.append(time.perf_counter() - t0)
            sizes.append(len(data))
            res = analyze_frame(frame)
            if res.centroid_px is not None:  # the 300 x 300 crop the I_center method works on
                x, y = (round(v) for v in res.centroid_px)
                crops.append(len(encode_png(frame[max(0, y - 150) : y + 150, max(0, x - 150) : x + 150])))
    return {
        "crop_png_bytes_mean": statistics.mean(crops) if crops else None,
        "png_bytes_mean": statistics.mean(sizes),
        "png_bytes_max": max(sizes),
        "encode_s": statistics.median(times),
    }


# ---------------------------------------------------------------- modules
class PacedSource:
    """Frames at ``rate_hz`` (0: flat out) from `begin` for ``seconds``, each captured "now"."""

    def __init__(self, module: str, files: list[str], rate_hz: float, phase_s: float) -> None:
        self.module = module
        self.pngs = [Path(f).read_bytes() for f in files]
        self.rate_hz = rate_hz
        self.phase_s = phase_s
        self.started = threading.Event()
        self.next_t = self.t_end = 0.0
        self.i = 0
        self.bytes = 0

    def begin(self, t_start: float, seconds: float) -> None:
        self.next_t, self.t_end = t_start + self.phase_s, t_start + seconds
        self.started.set()

    def __call__(self, stop: threading.Event) -> Any:
        from camcal.core.schedule import Shot
        from lrm.replay import ReplayedFrame
        from lrm.runner import Capture

        while not self.started.wait(0.05):
            if stop.is_set():
                return None
        if self.rate_hz > 0:
            wait = self.next_t - time.time()
            if wait > 0 and stop.wait(wait):
                return None
            self.next_t += 1.0 / self.rate_hz
        if time.time() >= self.t_end or stop.is_set():
            return None
        png = self.pngs[self.i % len(self.pngs)]
        self.i += 1
        self.bytes += len(png)
        frame = ReplayedFrame(png, datetime.now(UTC), 0.05, 6.0, self.module, 460, 3400.0)
        return Capture(frame, Shot(460, 0.05, 6.0, 0), 460, 1)


class Sensors:
    """A module's housing and attitude sensors, read at 10 Hz (one ``sensors`` message a second)."""

    def read(self) -> Any:
        from types import SimpleNamespace

        t = time.time()
        heave = 0.2 * np.sin(2 * np.pi * t / 7.0)
        return SimpleNamespace(
            t=datetime.now(UTC),
            temperature_c=4.0,
            humidity_pct=30.0,
            acc_m_s2=(0.05, 0.0, 9.81 + heave),
            gyro_dps=(0.05, 0.0, 0.02),
            depth_m=3400.0,
        )


def run_modules(
    modules: list[str],
    files: dict[str, list[str]],
    endpoint: str,
    rate_hz: float,
    seconds: float,
    outbox: str,
    out: Any,
    go: Any,
    sensors: bool,
) -> None:
    """One process holding several modules (agents): connect, report ready, send when told, drain."""
    import logging

    from lrm.agent import Agent, AgentConfig
    from lrm.clock import SystemClock

    logging.basicConfig(level=logging.WARNING)
    rng = np.random.default_rng(abs(hash(modules[0])) % 2**32)
    clock = SystemClock()
    agents, sources = [], []
    for i, m in enumerate(modules):
        phase = float(rng.uniform(0, 1.0 / rate_hz)) if rate_hz > 0 else 0.0
        src = PacedSource(m, files["A" if i % 2 == 0 else "B"], rate_hz, phase)
        cfg = AgentConfig(
            module=m, connect=endpoint, outbox=Path(outbox) / m, fsync=False, initial_window=8, plaintext=True
        )
        agents.append(Agent(cfg, clock=clock, source=src, sensors=Sensors() if sensors else None))
        sources.append(src)
    for a in agents:
        a.start()
    end = time.time() + 60
    while time.time() < end and not all(a.linked.is_set() for a in agents):
        time.sleep(0.05)
    out.put({"ready": len(modules)})
    go.wait()
    t_start = time.time()
    for src in sources:
        src.begin(t_start, seconds)
    time.sleep(seconds)
    for a in agents:
        a.stop_producing()
    end = time.time() + 120
    while time.time() < end and not all(a.capture_done() and a.outbox.pending_count() == 0 for a in agents):
        time.sleep(0.1)
    pending = sum(a.outbox.pending_count() for a in agents)
    for a in agents:
        a.stop()
    frames = sum(a.counters["frames_captured"] for a in agents)
    out.put({"frames": frames, "bytes": sum(s.bytes for s in sources), "pending": pending})


# ---------------------------------------------------------------- one count
def start_ingest(
    data: Path, port: int, events_port: int, workers: int, fsync: bool, db_url: str | None
) -> Any:
    cmd = [
        sys.executable, "-c", "from camcal.cli import main; main()", "ingest",
        "--data", str(data), "--bind", f"tcp://127.0.0.1:{port}", "--events", f"tcp://127.0.0.1:{events_port}",
        "--workers", str(workers), "--dive", "bench", "--log-level", "warning", "--plaintext",
        "--fsync" if fsync else "--no-fsync",
    ]  # fmt: skip
    if db_url:
        cmd += ["--db-url", db_url]
    log = (data.parent / "ingest.log").open("wb")
    proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    end = time.time() + 60
    while time.time() < end:
        if b"modules connect to" in (data.parent / "ingest.log").read_bytes():
            return proc
        if proc.poll() is not None:
            break
        time.sleep(0.1)
    raise RuntimeError((data.parent / "ingest.log").read_text(errors="replace")[-2000:])


def measure(n: int, args: argparse.Namespace, files: dict[str, list[str]], tmp: Path) -> dict[str, Any]:
    import psutil
    import zmq

    root = tmp / f"n{n}"
    data = root / "data"
    data.mkdir(parents=True)
    port, events_port = free_port(), free_port()
    ingest = start_ingest(data, port, events_port, args.workers, args.fsync, args.db_url)
    ctx = zmq.Context.instance()
    sub = ctx.socket(zmq.SUB)
    sub.setsockopt(zmq.SUBSCRIBE, b"result")
    sub.setsockopt(zmq.RCVHWM, 0)
    sub.connect(f"tcp://127.0.0.1:{events_port}")
    time.sleep(0.5)  # the subscription reaches the publisher
    modules = [f"M{i:03d}" for i in range(n)]
    n_procs = max(1, min(args.module_procs, n))
    groups = [modules[i::n_procs] for i in range(n_procs)]
    mp = multiprocessing.get_context("spawn")
    out, go = mp.Queue(), mp.Event()
    endpoint = f"tcp://127.0.0.1:{port}"
    outbox = str(root / "outbox")
    procs = [
        mp.Process(
            target=run_modules,
            args=(g, files, endpoint, args.rate, args.seconds, outbox, out, go, args.sensors),
        )
        for g in groups
    ]
    ingest_ps = psutil.Process(ingest.pid)

    def cpu_s() -> float:
        total = 0.0
        for p in [ingest_ps, *ingest_ps.children(recursive=True)]:
            try:
                t = p.cpu_times()
                total += t.user + t.system
            except psutil.NoSuchProcess:
                pass
        return total

    for p in procs:
        p.start()
    for _ in procs:  # every module linked before the clock starts
        assert "ready" in out.get(timeout=120)
    go.set()
    t0 = time.time()
    results: list[tuple[float, float]] = []  # (captured, stored) per frame
    reports: list[dict[str, Any]] = []
    cpu0, wall0 = cpu_s(), time.time()
    poller = zmq.Poller()
    poller.register(sub, zmq.POLLIN)

    def drain(timeout_ms: int) -> None:
        if poller.poll(timeout_ms):
            while True:
                try:
                    _kind, body = sub.recv_multipart(zmq.NOBLOCK)
                except zmq.Again:
                    return
                results.append((json.loads(body)["payload"]["captured_unix_s"], time.time()))

    while len(reports) < len(procs):
        drain(100)
        while not out.empty():
            reports.append(out.get())
    sent = sum(r["frames"] for r in reports)
    end = time.time() + (60 if args.rate > 0 else 900)  # flat out leaves an analysis backlog to finish
    while len(results) < sent and time.time() < end:
        drain(200)
    cpu, wall = cpu_s() - cpu0, time.time() - wall0
    for p in procs:
        p.join(30)
    os.killpg(ingest.pid, signal.SIGTERM)
    ingest.wait(60)
    sub.close(0)
    lo, hi = t0 + args.warmup, t0 + args.seconds
    if args.rate > 0:  # paced: the steady window
        steady = [r for r in results if lo <= r[1] <= hi]
        latencies = [stored - cap for cap, stored in results if lo <= cap <= hi]
        fps = len(steady) / (hi - lo)
    else:  # flat out: everything sent, stored and analysed, over the time it took
        latencies = [stored - cap for cap, stored in results]
        fps = len(results) / (max(r[1] for r in results) - t0) if results else 0.0
    sent_bytes = sum(r["bytes"] for r in reports)
    return {
        "modules": n,
        "offered_fps": n * args.rate if args.rate > 0 else None,
        "frames_sent": sent,
        "pending": sum(r["pending"] for r in reports),
        "results": len(results),
        "frames_per_s": fps,
        "bytes_per_s": fps * sent_bytes / max(1, sent),
        "mean_png_bytes": sent_bytes / max(1, sent),
        "latency_p50_s": float(np.percentile(latencies, 50)) if latencies else None,
        "latency_p95_s": float(np.percentile(latencies, 95)) if latencies else None,
        "ingest_cores": cpu / wall if wall > 0 else None,
        "ingest_cpu_ms_per_frame": 1e3 * cpu / max(1, len(results)),
        "load_average": os.getloadavg()[0],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--modules", default="2,8,32", help="module counts, comma-separated")
    parser.add_argument("--rate", type=float, default=1.0, help="frames/s per module; 0 = flat out")
    parser.add_argument("--seconds", type=float, default=20.0, help="sending time per count")
    parser.add_argument("--warmup", type=float, default=3.0, help="seconds left out of the figures")
    parser.add_argument("--workers", type=int, default=2, help="analysis processes of the ingest")
    parser.add_argument("--module-procs", type=int, default=4, help="processes the modules are spread over")
    parser.add_argument(
        "--sensors", action=argparse.BooleanOptionalAction, default=True, help="modules send sensors at 10 Hz"
    )
    parser.add_argument(
        "--fsync", action=argparse.BooleanOptionalAction, default=True, help="ingest fsyncs frames"
    )
    parser.add_argument("--db-url", default=None, help="ingest database (default SQLite in its data folder)")
    parser.add_argument(
        "--png", action=argparse.BooleanOptionalAction, default=True, help="measure 5 MP PNG size"
    )
    parser.add_argument("--json", type=Path, default=None, help="write the figures here")
    args = parser.parse_args()
    counts = [int(x) for x in args.modules.split(",") if x.strip()]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        pool = render_pool(Path(tmp))
        mode = f"{args.rate:g} frames/s per module" if args.rate > 0 else "flat out"
        print(f"{os.cpu_count()} cores; ingest with {args.workers} analysis processes; {mode}; "
              f"{args.seconds:g} s per count; {SMALL[0]}x{SMALL[1]} PNG frames", flush=True)  # fmt: skip
        print(f"{'modules':>7} {'offered/s':>9} {'frames/s':>9} {'MB/s':>6} {'p50 s':>7} {'p95 s':>7} "
              f"{'cores':>5} {'ms/frame':>8} {'load':>5} {'lost':>4}", flush=True)  # fmt: skip
        for n in counts:
            r = measure(n, args, pool, Path(tmp))
            rows.append(r)
            lost = r["frames_sent"] - r["results"]
            offered = f"{r['offered_fps']:.0f}" if r["offered_fps"] else "max"
            lat = f"{r['latency_p50_s']:>7.3f} {r['latency_p95_s']:>7.3f}"
            print(
                f"{n:>7} {offered:>9} {r['frames_per_s']:>9.1f} {r['bytes_per_s'] / 1e6:>6.2f} "
                f"{lat} {r['ingest_cores']:>5.2f} {r['ingest_cpu_ms_per_frame']:>8.1f} "
                f"{r['load_average']:>5.1f} {lost:>4}",
                flush=True,
            )
    out: dict[str, Any] = {"rate_per_module": args.rate, "seconds": args.seconds, "rows": rows}
    if args.png:
        out["png_5mp"] = png_size_5mp()
        print(f"5 MP PNG (simulated T-REX frames): mean {out['png_5mp']['png_bytes_mean'] / 1e6:.2f} MB, "
              f"max {out['png_5mp']['png_bytes_max'] / 1e6:.2f} MB, "
              f"encode {out['png_5mp']['encode_s'] * 1e3:.0f} ms; 300x300 crop "
              f"{(out['png_5mp']['crop_png_bytes_mean'] or 0) / 1e3:.0f} kB")  # fmt: skip
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
