"""The whole camcal system as a real process (``camcal up``) on free ports, for browser tests and benches.

``camcal up`` starts the ingest and two simulated modules as its own children
(each in its own session); stopping it with SIGINT stops them in order.
If it does not stop in time, its children are found in /proc and killed by
pid, so a failed test never leaves a simulated dive running.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx

REPO = Path(__file__).resolve().parents[2]
CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--headless=new",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
    "--disable-quic",
]


def free_ports(n: int) -> list[int]:
    """``n`` distinct TCP ports that are free on 127.0.0.1 right now.

    The system picks them, unless ``CAMCAL_TEST_PORTS=LO-HI`` names a range to
    pick from (on a machine shared with colleagues who own other ports).
    """
    span = os.environ.get("CAMCAL_TEST_PORTS", "")
    candidates = [0] * n
    if span:
        lo, hi = (int(v) for v in span.split("-"))
        candidates = list(range(lo, hi + 1))
    socks: list[socket.socket] = []
    try:
        for port in candidates:
            if len(socks) == n:
                break
            s = socket.socket()
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                s.close()
                continue
            socks.append(s)
        if len(socks) < n:
            raise RuntimeError(f"no {n} free ports in {span}")
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


def wait_until(check: Callable[[], Any], timeout_s: float, what: str, every_s: float = 0.5) -> Any:
    """Poll ``check`` until it returns something truthy; raise naming ``what`` after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = check()
        if value:
            return value
        if time.monotonic() > deadline:
            raise TimeoutError(f"timed out after {timeout_s} s waiting for {what}")
        time.sleep(every_s)


@dataclass
class System:
    base_url: str
    data: Path
    token: str
    operator: str
    process: subprocess.Popen[bytes]
    log: Path
    ingest_port: int = 0

    def url(self, path: str) -> str:
        return f"{self.base_url}{path}"


def _children(pid: int) -> list[int]:
    out = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        # pid (comm) state ppid ...: comm may hold spaces, so split after the last ')'.
        fields = stat.rsplit(")", 1)[1].split()
        if int(fields[1]) == pid:
            out.append(int(entry.name))
    return out


def module_pid(system: System, module: str) -> int:
    """The pid of a simulated module that ``camcal up`` started (its ``lrm simulate --camera MODULE``)."""
    for pid in _children(system.process.pid):
        try:
            args = (Path("/proc") / str(pid) / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        if (
            b"simulate" in args
            and b"--camera" in args
            and args[args.index(b"--camera") + 1] == module.encode()
        ):
            return pid
    raise LookupError(f"no simulated module {module} among the children of camcal up ({system.process.pid})")


def stop_system(proc: subprocess.Popen[bytes], timeout_s: float = 40.0) -> None:
    children = _children(proc.pid)
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
    for pid in children:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)


@contextlib.contextmanager
def camcal_up(
    data: Path,
    *,
    speed: float = 20.0,
    frame_scale: float = 0.25,
    winch_m_per_s: float = 6.0,
    test_stop_s: float = 200.0,
    station_s: float = 600.0,
    extra: list[str] | None = None,
    ready_timeout_s: float = 60.0,
) -> Iterator[System]:
    """Run ``camcal up`` on free ports with a short simulated dive; yield once the API answers."""
    port, ingest_port, events_port = free_ports(3)
    token = "browser-test-token-0123456789"
    data.mkdir(parents=True, exist_ok=True)
    log = data.parent / f"{data.name}-up.log"
    # A clean configuration: no CAMCAL_* setting of the caller's shell leaks into the system under test.
    env = {k: v for k, v in os.environ.items() if not k.startswith("CAMCAL_")}
    env["PYTHONPATH"] = str(REPO)
    args = [
        sys.executable,
        "-c",
        "from camcal.cli import main; main()",
        "up",
        "--data",
        str(data),
        "--port",
        str(port),
        "--ingest-port",
        str(ingest_port),
        "--events-port",
        str(events_port),
        "--speed",
        str(speed),
        "--frame-scale",
        str(frame_scale),
        "--winch-m-per-s",
        str(winch_m_per_s),
        "--test-stop-s",
        str(test_stop_s),
        "--station-s",
        str(station_s),
        *(extra or []),
    ]
    env["CAMCAL_OPERATOR_TOKENS"] = json.dumps({"tester": token})  # never on a command line
    with log.open("wb") as fh:
        proc = subprocess.Popen(args, cwd=data.parent, env=env, stdout=fh, stderr=subprocess.STDOUT)
    system = System(f"http://127.0.0.1:{port}", data, token, "tester", proc, log, ingest_port)
    try:
        deadline = time.monotonic() + ready_timeout_s
        while True:
            if proc.poll() is not None:
                raise RuntimeError(f"camcal up exited with {proc.returncode}:\n{log.read_text()[-3000:]}")
            try:
                if httpx.get(system.url("/api/health"), timeout=2).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            if time.monotonic() > deadline:
                tail = log.read_text()[-3000:]
                raise RuntimeError(f"camcal up did not answer in {ready_timeout_s} s:\n{tail}")
            time.sleep(0.3)
        yield system
    finally:
        stop_system(proc)


@contextlib.contextmanager
def camcal_serve(
    data: Path, *extra: str, env: dict[str, str] | None = None, scheme: str = "http", verify: Any = False
) -> Iterator[tuple[str, subprocess.Popen[bytes]]]:
    """``camcal serve --events none`` of ``data`` on a free port; yields its base URL and process."""
    (port,) = free_ports(1)
    base = {k: v for k, v in os.environ.items() if not k.startswith("CAMCAL_")}
    full_env = {**base, "PYTHONPATH": str(REPO), **(env or {})}
    log = data.parent / f"serve-{port}.log"
    args = [sys.executable, "-c", "from camcal.cli import main; main()", "serve", "--data", str(data)]
    args += ["--port", str(port), "--events", "none", *extra]
    with log.open("wb") as fh:
        proc = subprocess.Popen(args, env=full_env, stdout=fh, stderr=subprocess.STDOUT)
    url = f"{scheme}://127.0.0.1:{port}"
    try:

        def up() -> bool:
            if proc.poll() is not None:
                raise RuntimeError(f"camcal serve exited with {proc.returncode}: {log.read_text()[-2000:]}")
            try:
                return httpx.get(f"{url}/api/health", timeout=2, verify=verify).status_code == 200
            except httpx.HTTPError:
                return False

        wait_until(up, 60, "camcal serve to answer", every_s=0.2)
        yield url, proc
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(5)
