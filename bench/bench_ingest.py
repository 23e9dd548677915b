"""Benchmark of the live path: two replaying modules of 5 MP frames into the ingest, against a floor.

1. **Throughput.** ``camcal lrm replay --speed 0`` for cameras A and B (two
   processes, as fast as the credit allows) into an `IngestService` with its
   production settings (fsync of every frame file, SQLite ``synchronous=FULL``,
   one analysis process per core, thumbnails): frames/s stored and analysed,
   latency from receipt to the stored row and to the stored result.
2. **The floor beside it**: the same PNG bytes, sent by two processes over the
   same kind of sockets (DEALER -> ROUTER on tcp://127.0.0.1), received and
   written to disk with fsync by one thread, and nothing else.
   A second reference: the analysis alone (decode, analyse, thumbnail) of
   the same files on one process per core.
3. **Latency at the T-REX rate**: both cameras replayed at recorded pace from
   a set whose frames are 1 s apart per camera (2 frames/s in all).

The 5 MP frame set (T-REX exposures 0.05/0.07/0.11 s x gains 2..20 dB x 3
repeats x 3 wavelengths, 108 frames per camera) is rendered once and kept in
``--cache`` (default: the temp folder) for later runs.

Run: ``.venv/bin/python bench/bench_ingest.py [--repeats N] [--trex-frames N]``.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any

import numpy as np
import zmq
from sqlalchemy import func, select

from analysis import FrameConfig
from camcal.core import wire
from camcal.core.frameset import read_manifest, read_setup
from camcal.core.parallel import process_pool
from camcal.core.schedule import Schedule
from camcal.core.wire.keys import create_module_key, create_ship_key
from ingest.service import IngestConfig, IngestService
from ingest.worker import analyse_stored_frame
from lrm.simset import SimulationSpec, simulate_frame_set
from storage.models import Event, Frame, FrameResult

ROOT = Path(__file__).resolve().parents[1]


def frame_set(cache: Path, repeats: int) -> Path:
    """The 5 MP frame set, rendered on first use (truth.json is written last: its presence means done)."""
    folder = cache / f"ingest-5mp-r{repeats}-s11"
    if (folder / "truth.json").exists():
        return folder
    shutil.rmtree(folder, ignore_errors=True)
    sched = Schedule(
        name="bench-ingest", exposures_s=(0.05, 0.07, 0.11), gains_db=(2.0, 8.0, 14.0, 20.0), repeats=repeats
    )
    print(f"rendering a 5 MP frame set of {2 * sched.n_frames} frames into {folder} ...", flush=True)
    simulate_frame_set(folder, SimulationSpec(schedule=sched, seed=11))
    return folder


def paced_set(source: Path, out: Path, per_camera: int, interval_s: float = 1.0) -> Path:
    """Frames of ``source`` (links, not copies) re-timed ``interval_s`` apart per camera."""
    rows = read_manifest(source)
    out.mkdir(parents=True)
    shutil.copy(source / "setup.json", out / "setup.json")
    t0 = datetime.fromisoformat((rows[0].timestamp or "").replace("Z", "+00:00"))
    lines = ["file,camera,wavelength_nm,exposure_s,gain_db,timestamp,seq"]
    for cam in ("A", "B"):
        mine = [r for r in rows if r.camera == cam]
        step = max(1, len(mine) // per_camera)
        for i, r in enumerate(mine[::step][:per_camera]):
            os.symlink(source / r.file, out / r.file)
            t = (t0 + timedelta(seconds=i * interval_s)).isoformat().replace("+00:00", "Z")
            lines.append(f"{r.file},{cam},{r.wavelength_nm},{r.exposure_s},{r.gain_db},{t},{i + 1}")
    (out / "manifest.csv").write_text("\n".join(lines) + "\n")
    return out


def pct(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else float("nan")


def cpu_s(who: int) -> float:
    r = resource.getrusage(who)
    return r.ru_utime + r.ru_stime


_TICK_S = 1.0 / os.sysconf("SC_CLK_TCK")


def proc_cpu_s(path: str) -> float:
    """User + system CPU seconds of a process or thread from its /proc ``stat`` (0 once it is gone)."""
    try:
        text = Path(path).read_text()
    except OSError:
        return 0.0
    fields = text[text.rindex(")") + 2 :].split()
    return (int(fields[11]) + int(fields[12])) * _TICK_S


def thread_cpu_s() -> dict[str, float]:
    """CPU seconds of each thread of this process by name (ZeroMQ's own threads: ``zmq I/O``)."""
    names = {t.native_id: t.name for t in threading.enumerate()}
    out: dict[str, float] = {}
    for tid in os.listdir("/proc/self/task"):
        name = names.get(int(tid), "zmq I/O and other native threads")
        name = name.rstrip("_0123456789") if name.startswith("frame-write") else name
        out[name] = out.get(name, 0.0) + proc_cpu_s(f"/proc/self/task/{tid}/stat")
    return out


# ------------------------------------------------------------------ the floor
WINDOW = 8  # the ingest's default credit: unacknowledged messages a module may have in flight


def _sender(endpoint: str, module: str, paths: list[str]) -> None:
    """One floor module: the PNG bytes from memory, a small JSON header each, ``WINDOW`` in flight."""
    payloads = [Path(p).read_bytes() for p in paths]
    ctx = zmq.Context()
    sock = wire.module_socket(ctx, endpoint, module)
    in_flight = 0
    for i, data in enumerate(payloads):
        while in_flight >= WINDOW:
            sock.recv()  # an acknowledgement
            in_flight -= 1
        sock.send_multipart([json.dumps({"seq": i + 1, "size": len(data)}).encode(), data])
        in_flight += 1
    for _ in range(in_flight):
        sock.recv()
    sock.close(0)
    ctx.term()


def floor(folder: Path, out: Path) -> dict[str, float]:
    """Receive both cameras' frames on one ROUTER, write each with fsync, then acknowledge it."""
    rows = read_manifest(folder)
    out.mkdir(parents=True)
    ctx = zmq.Context()
    router = wire.ship_socket(ctx, "tcp://127.0.0.1:*")
    endpoint = router.getsockopt(zmq.LAST_ENDPOINT).decode()
    mp = multiprocessing.get_context("spawn")
    senders = [
        mp.Process(
            target=_sender, args=(endpoint, cam, [str(folder / r.file) for r in rows if r.camera == cam])
        )
        for cam in ("A", "B")
    ]
    for p in senders:
        p.start()
    latencies, t_first, n, cpu0 = [], 0.0, 0, 0.0
    while n < len(rows):
        ident, header, payload = router.recv_multipart(copy=False)
        t = time.monotonic()
        if not n:
            t_first, cpu0 = t, cpu_s(resource.RUSAGE_SELF)  # with ZeroMQ's I/O thread
        h = json.loads(header.bytes)
        name = ident.bytes.decode().replace("/", "_")  # a module identity is "<module>/<connection>"
        with open(out / f"{name}-{h['seq']:06d}.png", "wb") as fh:
            fh.write(payload.buffer)
            fh.flush()
            os.fsync(fh.fileno())
        latencies.append(time.monotonic() - t)
        router.send_multipart([ident.bytes, b"ack"])
        n += 1
    elapsed, cpu = time.monotonic() - t_first, cpu_s(resource.RUSAGE_SELF) - cpu0
    for p in senders:
        p.join(30)
    router.close(0)
    ctx.term()
    return {"n": n, "fps": n / elapsed, "p50": pct(latencies, 50), "p95": pct(latencies, 95), "cpu": cpu / n}


def _timed_analysis(path: str, config: FrameConfig, thumb: str) -> float:
    t0 = time.process_time()
    analyse_stored_frame(path, config, thumb)
    return time.process_time() - t0


def analysis_floor(folder: Path, out: Path) -> dict[str, float]:
    """The analysis alone (decode, analyse, thumbnail) on one process per core: frames/s, CPU per frame."""
    rows = read_manifest(folder)
    out.mkdir(parents=True)
    config = FrameConfig()
    with process_pool(os.cpu_count() or 1) as pool:
        list(pool.map(str, range(4)))  # the workers are up
        t0 = time.perf_counter()
        futures = [
            pool.submit(_timed_analysis, str(folder / r.file), config, str(out / f"{i}.jpg"))
            for i, r in enumerate(rows)
        ]
        cpu = [f.result() for f in futures]
        return {"fps": len(rows) / (time.perf_counter() - t0), "cpu": statistics.median(cpu)}


# ------------------------------------------------------------------ the ingest
def link_keys(data: Path) -> Path:
    """The link's CURVE keys (the production setting) for the ship and modules A and B."""
    folder = data / "keys"
    create_ship_key(folder)
    for m in ("A", "B"):
        create_module_key(folder, m)
    return folder


def replay(
    folder: Path, cam: str, endpoint: str, outbox: Path, speed: float, keys: Path
) -> subprocess.Popen[bytes]:
    path = os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))
    env = {**os.environ, "PYTHONPATH": path}
    cmd = [sys.executable, "-c", "from camcal.cli import main; main()", "lrm", "replay", str(folder)]
    cmd += ["--camera", cam, "--connect", endpoint, "--speed", str(speed), "--outbox", str(outbox)]
    cmd += ["--keys", str(keys)]  # the production link: CURVE
    return subprocess.Popen([*cmd, "--log-level", "warning"], env=env, stdout=subprocess.DEVNULL)


def ingest_run(folder: Path, work: Path, speed: float) -> dict[str, Any]:
    """Both cameras of ``folder`` replayed into a fresh ingest; what it stored, how fast, how late."""
    cfg = IngestConfig(
        data_dir=work / "data",
        bind="tcp://127.0.0.1:*",
        events_bind="tcp://127.0.0.1:*",
        setup=read_setup(folder),
        dive_name="bench",
        keys_dir=link_keys(work / "data"),
    )
    svc = IngestService(cfg)
    svc.start()
    # On a ship the ingest is up long before the modules send: its analysis processes have started.
    if not svc.analysis_ready.wait(120):
        raise SystemExit("the ingest's analysis processes did not start within 120 s")
    n_rows = len(read_manifest(folder))
    self0, kids0 = cpu_s(resource.RUSAGE_SELF), cpu_s(resource.RUSAGE_CHILDREN)
    keys = cfg.keys_dir
    assert keys is not None
    procs = [replay(folder, cam, svc.endpoint, work / f"outbox-{cam}", speed, keys) for cam in ("A", "B")]
    # The modules' start (Python, imports, keys, outbox) is not part of streaming: their CPU is read
    # again once the first frame is stored, and the ingest's threads are counted from there too.
    while not svc.counters.snapshot()["counters"].get("frames_stored") and all(
        p.poll() is None for p in procs
    ):
        time.sleep(0.01)
    modules_start = sum(proc_cpu_s(f"/proc/{p.pid}/stat") for p in procs)
    threads0 = thread_cpu_s()
    for p in procs:
        if p.wait(1800) != 0:
            raise SystemExit(f"a replay failed with status {p.returncode}")
    modules_cpu = cpu_s(resource.RUSAGE_CHILDREN) - kids0

    def count(model: Any) -> int:
        with svc.store.read() as s:
            return int(s.scalar(select(func.count(model.id))) or 0)

    deadline = time.monotonic() + 600
    while count(FrameResult) < n_rows and time.monotonic() < deadline:
        time.sleep(0.25)
    ingest_cpu = cpu_s(resource.RUSAGE_SELF) - self0
    threads = {k: v - threads0.get(k, 0.0) for k, v in thread_cpu_s().items()}
    with svc.store.read() as s:
        received = list(s.scalars(select(Frame.received_unix_s)))
        analysed = list(s.scalars(select(FrameResult.analysed_unix_s)))
        ok = s.scalar(select(func.count(FrameResult.id)).where(FrameResult.status == "ok"))
        events = list(s.scalars(select(Event).where(Event.kind.in_(("frame", "result")))))
    stored_events = [(e.t_unix_s, e.payload) for e in events if e.kind == "frame"]
    analysis_s = [e.payload["analysis_s"] for e in events if e.kind == "result"]
    to_result = list(svc.latency_s)
    svc.stop()
    t0 = min(received)
    n = len(received)
    return {
        "n": n,
        "ok": ok,
        "stored_fps": n / (max(t for t, _ in stored_events) - t0),
        "analysed_fps": len(analysed) / (max(analysed) - t0),
        "stored_p50": pct([p["stored_latency_s"] for _, p in stored_events], 50),
        "stored_p95": pct([p["stored_latency_s"] for _, p in stored_events], 95),
        "result_p50": pct(to_result, 50),
        "result_p95": pct(to_result, 95),
        "cpu_ms_per_frame": {
            "modules": 1e3 * modules_cpu / n,
            "modules_streaming": 1e3 * (modules_cpu - modules_start) / n,
            "ingest": 1e3 * ingest_cpu / n,
            **{f"thread {k}": 1e3 * v / n for k, v in sorted(threads.items()) if v > 0.001 * n},
        },
        "modules_start_s": modules_start / 2,
        "analysis_wall_ms": 1e3 * statistics.median(a for a in analysis_s if a),
        # how busy the analysis processes were between the first frame and the last result
        "pool_busy": sum(a for a in analysis_s if a) / ((os.cpu_count() or 1) * (max(analysed) - t0)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3, help="frames per setting (x 36 settings x 2)")
    parser.add_argument("--trex-frames", type=int, default=30, help="frames per camera at the T-REX rate")
    parser.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "camcal-bench")
    parser.add_argument("--only", choices=("floor", "full", "trex"), help="run one part (for profiling)")
    args = parser.parse_args()
    folder = frame_set(args.cache, args.repeats)
    sizes = [(folder / r.file).stat().st_size for r in read_manifest(folder)]
    parts: dict[str, Any] = {}
    load0 = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        if args.only in (None, "floor"):
            print(f"floor: {len(sizes)} frames, DEALER -> ROUTER, write + fsync ...", flush=True)
            fl = parts["floor"] = floor(folder, work / "floor")
            shutil.rmtree(work / "floor")
            print("analysis alone: decode, analyse, thumbnail on every core ...", flush=True)
            an = parts["analysis"] = analysis_floor(folder, work / "analysis")
        if args.only in (None, "full"):
            print("ingest: two replays at full speed ...", flush=True)
            full = parts["full"] = ingest_run(folder, work / "full", speed=0)
            shutil.rmtree(work / "full")
        if args.only in (None, "trex"):
            print(f"ingest: two replays at the T-REX rate ({args.trex_frames} s) ...", flush=True)
            paced = paced_set(folder, work / "paced", args.trex_frames)
            trex = parts["trex"] = ingest_run(paced, work / "trex", speed=1)
    if args.only:
        print(json.dumps(parts[args.only], indent=1))
        return

    cores = os.cpu_count() or 1
    ship_cpu = full["cpu_ms_per_frame"]["ingest"] / 1e3 + an["cpu"]
    ms = 1e3
    print()
    print(
        f"{full['n']} frames of 2448 x 2048 px ({statistics.mean(sizes) / 1e6:.2f} MB PNG on average), "
        f"{full['ok']} analysed ok; {cores} cores; load average {load0:.1f} at the start, "
        f"{os.getloadavg()[0]:.1f} at the end"
    )
    print()
    print("| figure | ingest | floor | ratio | aim |")
    print("| --- | --- | --- | --- | --- |")
    rows = [
        (
            "frames/s stored and analysed, two modules at full speed",
            f"{full['analysed_fps']:.1f}",
            f"{fl['fps']:.1f}",
            f"{full['analysed_fps'] / fl['fps']:.2f}x",
            ">= 0.5x, >= 20/s",
        ),
        (
            "frames/s stored (committed and acknowledged), full speed",
            f"{full['stored_fps']:.1f}",
            f"{fl['fps']:.1f}",
            f"{full['stored_fps'] / fl['fps']:.2f}x",
            "",
        ),
        (
            f"frames/s stored and analysed vs the analysis alone ({cores} processes)",
            f"{full['analysed_fps']:.1f}",
            f"{an['fps']:.1f}",
            f"{full['analysed_fps'] / an['fps']:.2f}x",
            ">= 0.8x",
        ),
        (
            "the same by CPU, the modules elsewhere (as on a dive): analysis / (ingest threads + analysis)",
            f"{cores / ship_cpu:.0f}",
            f"{cores / an['cpu']:.0f}",
            f"{an['cpu'] / ship_cpu:.2f}x",
            ">= 0.8x",
        ),
        (
            "ship CPU per frame: ingest threads + analysis (decode, analyse, thumbnail)",
            f"{full['cpu_ms_per_frame']['ingest']:.0f} + {an['cpu'] * ms:.0f} ms",
            f"{fl['cpu'] * ms:.1f} ms",
            f"{ship_cpu / fl['cpu']:.0f}x",
            "",
        ),
        (
            f"frames/s that CPU allows on {cores} idle cores",
            f"{cores / ship_cpu:.0f}",
            f"{cores / fl['cpu']:.0f}",
            "",
            ">= 20/s",
        ),
        (
            "latency receipt -> stored, p50 / p95, full speed (floor: receipt -> written)",
            f"{full['stored_p50'] * ms:.0f} / {full['stored_p95'] * ms:.0f} ms",
            f"{fl['p50'] * ms:.1f} / {fl['p95'] * ms:.1f} ms",
            "",
            "",
        ),
        (
            "latency receipt -> result, p50 / p95, full speed",
            f"{full['result_p50'] * ms:.0f} / {full['result_p95'] * ms:.0f} ms",
            "",
            "",
            "",
        ),
        (
            "latency receipt -> stored, p50 / p95, T-REX rate (2 frames/s)",
            f"{trex['stored_p50'] * ms:.0f} / {trex['stored_p95'] * ms:.0f} ms",
            "",
            "",
            "",
        ),
        (
            "latency receipt -> result, p50 / p95, T-REX rate (2 frames/s)",
            f"{trex['result_p50'] * ms:.0f} / {trex['result_p95'] * ms:.0f} ms",
            "",
            "",
            "p95 < 500 ms",
        ),
    ]
    for row in rows:
        print("| " + " | ".join(row) + " |")
    print()
    cpu = full["cpu_ms_per_frame"]
    print(
        f"The two replaying modules took {cpu['modules']:.0f} ms of CPU per frame on the same cores "
        f"(on a dive they run on the modules): {cpu['modules_streaming']:.1f} ms a frame while streaming, "
        f"the rest their start ({full['modules_start_s']:.2f} s each); the analysis processes were busy "
        f"{full['pool_busy']:.0%} of the time at full speed. The ingest's threads, ms of CPU a frame "
        "from the first frame stored to the last result: "
        + ", ".join(f"{k[7:]} {v:.1f}" for k, v in cpu.items() if k.startswith("thread "))
        + "."
    )


if __name__ == "__main__":
    main()
