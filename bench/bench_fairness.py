"""No module can starve another: module A's acknowledgement latency while module B floods the ship.

A real ``camcal ingest`` process (CURVE, fsync, one analysis process). Module A
sends a small frame, waits for its acknowledgement, pauses 0.1 s, and again:
first on a quiet ship (the floor), then while module B, in a process of its
own, floods the ship at its maximum with sensor batches just under the 32 MiB
part limit (70 000 rows of 64 columns each; as many in flight as the window
allows, each refused ``busy`` sent again after a second), then quiet again.
Prints A's latency p50 / p99 in each phase and the ratios flood / quiet of the
same run, and what B got through.

    python bench/bench_fairness.py [--frames 60]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests.utils, run as a script

from tests.utils.rogue import IngestProbe, Rogue
from tests.utils.wiremsgs import frame_parts, sensors_parts

COLUMNS = (
    "t_unix_s",
    "temperature_c",
    "humidity_pct",
    "acc_x_m_s2",
    "acc_y_m_s2",
    "acc_z_m_s2",
    "gyro_x_dps",
    "gyro_y_dps",
    "gyro_z_dps",
    "depth_m",
    *(f"extra_{i}" for i in range(54)),
)


def hello(module: str, boot: str) -> list[bytes]:
    return [json.dumps({"v": 1, "type": "hello", "module": module, "boot": boot}).encode()]


def big_batch(seq: int, boot: str) -> list[bytes]:
    row = b"[1800000000.25," + b",".join([b"0.1234"] * (len(COLUMNS) - 1)) + b"]"
    rows = (32 * 1024 * 1024 - 64) // (len(row) + 1)
    payload = b"[" + b",".join([row] * rows) + b"]"
    return sensors_parts(payload, COLUMNS, count=rows, module="B", boot=boot, seq=seq)


def flood(endpoint: str, keys: str, stop: Any, result: Any) -> None:
    """Module B: big sensor batches, the window full, each ``busy`` resent after a second."""
    import zmq

    b = Rogue(zmq.Context.instance(), endpoint, "B", keys_dir=Path(keys))
    boot = f"flood{int(time.time())}"
    replies = b.send(hello("B", boot), wait_s=30)
    window = replies[0].window if replies and replies[0].type == "welcome" else 8
    template = big_batch(1, boot)
    header = json.loads(template[0])
    in_flight: set[int] = set()
    retry: dict[int, float] = {}
    seq = acked = busy = 0
    while not stop.is_set():
        now = time.monotonic()
        due = [q for q, t in retry.items() if t <= now]
        while len(in_flight) < window:
            if due:
                q = due.pop()
                del retry[q]
            else:
                seq += 1
                q = seq
            b.sock.send_multipart([json.dumps({**header, "seq": q}).encode(), template[1]])
            in_flight.add(q)
        for m in b.collect(0.2, expect=100):
            if m.type == "ack":
                for _, a, z in m.ranges:
                    for q in range(a, z + 1):
                        if q in in_flight:
                            in_flight.discard(q)
                            acked += 1
            elif m.type == "nack" and m.seq is not None:
                in_flight.discard(m.seq)
                busy += m.reason == "busy"
                retry[m.seq] = time.monotonic() + 1.0
    result.put({"sent_batches": seq, "acked_batches": acked, "busy": busy})
    b.close()


def latencies(a: Rogue, boot: str, first_seq: int, n: int, timeout_s: float) -> list[float]:
    out = []
    for i in range(n):
        seq = first_seq + i
        img = np.full((48, 64), seq % 250, np.uint8)
        t0 = time.monotonic()
        replies = a.send(frame_parts(module="A", camera="A", boot=boot, seq=seq, image=img), wait_s=timeout_s)
        out.append(time.monotonic() - t0 if any(m.type == "ack" for m in replies) else timeout_s)
        time.sleep(0.1)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=60, help="frames of A per phase")
    ap.add_argument("--timeout-s", type=float, default=60.0, help="a later ack counts as this [s]")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        probe = IngestProbe(Path(tmp) / "data")
        probe.wait_ready(60)
        a = probe.rogue("A")
        probe.rogue("B").close()  # (makes B's key)
        boot = f"a{int(time.time())}"
        a.send(hello("A", boot), wait_s=30)
        phases: dict[str, list[float]] = {}
        try:
            latencies(a, boot, 1, 5, args.timeout_s)  # warm up
            phases["quiet"] = latencies(a, boot, 100, args.frames, args.timeout_s)
            ctx = multiprocessing.get_context("spawn")
            stop, result = ctx.Event(), ctx.Queue()
            b = ctx.Process(target=flood, args=(probe.endpoint, str(probe.keys), stop, result))
            b.start()
            time.sleep(3.0)  # B's first batches are on the ship
            phases["B flooding"] = latencies(a, boot, 1000, args.frames, args.timeout_s)
            stop.set()
            got = result.get(timeout=120)
            b.join(30)
            health = probe.health()
            phases["quiet after"] = latencies(a, boot, 5000, args.frames, args.timeout_s)
        finally:
            a.close()
            probe.stop()
    base = phases["quiet"]
    p50, p99 = np.percentile(base, 50), np.percentile(base, 99)
    print(f"module A: one frame at a time, {args.frames} per phase; ack latency (ms)")
    print(f"{'phase':<14} {'p50':>8} {'p99':>8} {'p50 / quiet':>12} {'p99 / quiet':>12}")
    for name, values in phases.items():
        q50, q99 = np.percentile(values, 50), np.percentile(values, 99)
        print(f"{name:<14} {1e3 * q50:8.1f} {1e3 * q99:8.1f} {q50 / p50:11.2f}x {q99 / p99:11.2f}x")
    print(
        f"module B: {got['sent_batches']} batches of 32 MiB sent, {got['acked_batches']} stored and "
        f"acknowledged, {got['busy']} refused busy (resent after 1 s); "
        f"A's link {health['modules']['A']['link']}"
    )


if __name__ == "__main__":
    main()
