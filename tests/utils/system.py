"""The whole camcal system as a real process (``camcal up``) on free ports, for browser tests and benches.

``camcal up`` starts the ingest and two simulated modules as its own children
(each in its own session); stopping it with SIGINT stops them in order.
Every process of its tree carries a mark in its environment (``TREE_MARK``),
which /proc shows whoever its parent is now: tests count what is left of a
tree by it (`tree`), never by the command's own bookkeeping, and whatever is
left after a test is killed, so a failed test never leaves a dive running.
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
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx

from tests.utils.pace import Pace

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


#: Environment variable marking every process a test started, with its children and theirs.
TREE_MARK = "CAMCAL_TEST_TREE"


def marked_env(mark: str) -> dict[str, str]:
    """A clean environment (no CAMCAL_* setting of the caller's shell) with this checkout first on the
    import path, marking the processes started with it (and their descendants) with ``mark``."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("CAMCAL_")}
    env["PYTHONPATH"] = str(REPO)
    env[TREE_MARK] = mark
    return env


def tree(mark: str) -> list[int]:
    """Live processes (zombies left out) whose environment carries ``mark``, read from /proc."""
    needle = f"{TREE_MARK}={mark}".encode()
    out = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            if needle not in (entry / "environ").read_bytes().split(b"\0"):
                continue
            state = (entry / "stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if state != "Z":
            out.append(int(entry.name))
    return out


def kill_tree(mark: str) -> None:
    for pid in tree(mark):
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)


def gone_within(mark: str, timeout_s: float) -> float:
    """Seconds until no process of the tree ``mark`` is left; fails naming the survivors."""
    t0 = time.monotonic()
    while tree(mark):
        if time.monotonic() - t0 >= timeout_s:
            left = {pid: Path(f"/proc/{pid}/cmdline").read_bytes()[:120] for pid in tree(mark)}
            raise AssertionError(f"still running {timeout_s} s later: {left}")
        time.sleep(0.05)
    return time.monotonic() - t0


def assert_ports_free(*ports: int) -> None:
    """Each port can be bound again at once, as the services bind them (SO_REUSEADDR)."""
    for port in ports:
        with socket.socket() as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            s.bind(("127.0.0.1", port))


def holding(port: int) -> socket.socket:
    """A plain listening socket on ``port``: somebody else's service."""
    s = socket.socket()
    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    s.bind(("127.0.0.1", port))
    s.listen()
    return s


def run_camcal(args: list[str], mark: str, cwd: Path, timeout_s: float = 60) -> tuple[int, str, float]:
    """Run ``camcal ARGS`` to its end: exit status, output, seconds it took."""
    t0 = time.monotonic()
    proc = subprocess.run(
        [sys.executable, "-c", "from camcal.cli import main; main()", *args],
        cwd=cwd,
        env={**marked_env(mark), "COLUMNS": "400"},
        capture_output=True,
        text=True,
        timeout=Pace().bound(timeout_s),  # an idle machine's, stretched by how busy this one is
    )
    return proc.returncode, proc.stdout + proc.stderr, time.monotonic() - t0


def wait_until(check: Callable[[], Any], timeout_s: float, what: str, every_s: float = 0.5) -> Any:
    """Poll ``check`` until it returns something truthy; raise naming ``what`` after ``timeout_s``
    (of an idle machine: stretched by how busy this one was meanwhile, `tests.utils.pace.Pace`)."""
    pace = Pace()
    t0 = time.monotonic()
    while True:
        value = check()
        if value:
            return value
        waited = time.monotonic() - t0
        if waited > timeout_s and waited > pace.bound(timeout_s):
            raise TimeoutError(f"timed out after {waited:.0f} s ({timeout_s} s, {pace}) waiting for {what}")
        time.sleep(every_s)


@dataclass
class System:
    base_url: str
    data: Path
    token: str
    operator: str
    process: subprocess.Popen[bytes]
    log: Path
    mark: str = ""
    ports: tuple[int, int, int] = (0, 0, 0)  # dashboard, ingest, events
    #: pid → (environ, cmdline) of each child of ``camcal up`` as read from /proc once it said it is up
    #: (a simulated module ends with its dive; a test run late in a long session still sees them).
    children_when_up: dict[int, tuple[bytes, bytes]] = field(default_factory=dict)

    def url(self, path: str) -> str:
        return f"{self.base_url}{path}"

    @property
    def ingest_port(self) -> int:
        return self.ports[1]


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


#: A short simulated dive from the deck (the browser tests' timeline).
SHORT_DIVE = {
    "--speed": "20",
    "--frame-scale": "0.25",
    "--winch-m-per-s": "6",
    "--test-stop-s": "200",
    "--station-s": "600",
    "--begin": "deck",
}


@contextlib.contextmanager
def camcal_up(
    data: Path,
    *,
    dive: dict[str, str] | None = None,
    extra: list[str] | None = None,
    ports: tuple[int, int, int] | None = None,
    ready_timeout_s: float = 90.0,
) -> Iterator[System]:
    """Run ``camcal up`` on free ports (or ``ports``: dashboard, ingest, events) with a simulated dive
    (``dive``: its options; default `SHORT_DIVE`, ``{}`` for `make run`'s); yield once it says it is up.

    Afterwards (however the test ended) no process of its tree is left.
    """
    port, ingest_port, events_port = ports or free_ports(3)
    token = "browser-test-token-0123456789"
    data.mkdir(parents=True, exist_ok=True)
    log = data.parent / f"{data.name}-up.log"
    mark = uuid.uuid4().hex
    dive_options = SHORT_DIVE if dive is None else dive
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
        *(w for kv in dive_options.items() for w in kv),
        *(extra or []),
    ]
    env = marked_env(mark)
    env["CAMCAL_OPERATOR_TOKENS"] = json.dumps({"tester": token})  # never on a command line
    with log.open("wb") as fh:
        proc = subprocess.Popen(args, cwd=data.parent, env=env, stdout=fh, stderr=subprocess.STDOUT)
    system = System(
        f"http://127.0.0.1:{port}", data, token, "tester", proc, log, mark, (port, ingest_port, events_port)
    )
    try:
        pace, t0 = Pace(), time.monotonic()  # the timeout is an idle machine's, stretched by a busy one's
        while True:
            if proc.poll() is not None:
                raise RuntimeError(f"camcal up exited with {proc.returncode}:\n{log.read_text()[-3000:]}")
            if "camcal is up" in log.read_text():  # every part healthy, both modules linked
                break
            waited = time.monotonic() - t0
            if waited > ready_timeout_s and waited > pace.bound(ready_timeout_s):
                tail = log.read_text()[-3000:]
                raise RuntimeError(f"camcal up was not up in {ready_timeout_s} s:\n{tail}")
            time.sleep(0.1)
        for pid in _children(proc.pid):
            with contextlib.suppress(OSError):
                proc_dir = Path(f"/proc/{pid}")
                system.children_when_up[pid] = (
                    (proc_dir / "environ").read_bytes(),
                    (proc_dir / "cmdline").read_bytes(),
                )
        yield system
    finally:
        stop_system(proc)
        kill_tree(mark)


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
