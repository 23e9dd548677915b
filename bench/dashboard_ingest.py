"""Part 4 of bench_dashboard.py: the ingest's rate with WebSocket clients connected against none.

Two modules push pre-encoded frames as fast as the ship's window allows; the clients (run in a
niced process of their own: ``python bench/dashboard_ingest.py --run-clients BASE N SECONDS``) do
what static/js/live.js does. See bench_dashboard.py for the whole benchmark.
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import cv2
import httpx
import numpy as np
import zmq
from dashboard_procs import REPO, cli, spawn, wait_http

from camcal.core import wire
from tests.utils.system import free_ports, stop_system, wait_until


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


if __name__ == "__main__":
    if len(sys.argv) == 5 and sys.argv[1] == "--run-clients":
        run_clients(sys.argv[2], int(sys.argv[3]), float(sys.argv[4]))
    else:
        raise SystemExit("usage: dashboard_ingest.py --run-clients BASE N SECONDS (bench_dashboard runs it)")
