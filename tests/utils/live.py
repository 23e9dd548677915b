"""Test doubles for the hardware a module has (camera, sensors, clock) and a cuttable TCP link.

The camera renders small simulated frames of the LEM (the camera hardware is
what cannot run here); everything else in the live tests is real: ZeroMQ
over TCP on 127.0.0.1, SQLite files, PNG codecs, processes.
"""

from __future__ import annotations

import contextlib
import os
import selectors
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import zmq

from camcal.core import wire
from camcal.core.schedule import CameraLimits, Schedule
from lrm.agent import Agent, AgentConfig
from lrm.runner import ScheduleRunner
from tests.utils.pace import Pace
from tests.utils.sim import SMALL_CAMERA, renderer

TREX_DISTANCES = {"A": (21.56, False), "B": (41.62, True)}


class RealClock:
    def now(self) -> datetime:
        return datetime.now(UTC)

    def monotonic(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        time.sleep(seconds)


@dataclass
class Frame:
    pixels: np.ndarray
    captured_at: datetime
    exposure_s: float
    gain_db: float
    camera: str
    wavelength_nm: int | None
    depth_m: float | None
    extra: dict[str, Any] = field(default_factory=dict)


class SmallSimCamera:
    """Renders the LEM on a 640 x 512 sensor at the T-REX plate scale (stands in for the hardware)."""

    exposure_range_s = (1e-4, 2.0)
    gain_range_db = (0.0, 24.0)
    gain_step_db = 0.1

    def __init__(self, camera_id: str, frame_interval_s: float = 0.05, water: str = "trex") -> None:
        dist, far = TREX_DISTANCES[camera_id]
        self.camera_id = camera_id
        self.renderer = renderer(water, dist, far_side=far, camera=SMALL_CAMERA, camera_id=camera_id)
        self.interval = frame_interval_s
        self.count = 0
        self.settings: list[tuple[float, float]] = []

    def capture(self, exposure_s: float, gain_db: float) -> Frame:
        self.count += 1
        self.settings.append((exposure_s, gain_db))
        pixels, _ = self.renderer.render(460, exposure_s, gain_db, rng=np.random.default_rng(self.count))
        time.sleep(self.interval)
        return Frame(pixels, datetime.now(UTC), exposure_s, gain_db, self.camera_id, 460, 3400.0)

    def close(self) -> None:
        pass


@dataclass
class Sample:
    t: datetime
    temperature_c: float
    humidity_pct: float
    acc_m_s2: tuple[float, float, float]
    gyro_dps: tuple[float, float, float]
    depth_m: float


class SteadySensors:
    def __init__(self, humidity_pct: float = 30.0, tilt_deg: float = 0.5) -> None:
        self.humidity_pct = humidity_pct
        self.tilt = np.radians(tilt_deg)

    def read(self) -> Sample:
        t = time.time()
        g = 9.81
        return Sample(
            datetime.now(UTC),
            4.0,
            self.humidity_pct,
            (g * np.sin(self.tilt), 0.0, g * np.cos(self.tilt) + 0.2 * np.sin(2 * np.pi * t / 7.0)),
            (0.05, 0.0, 0.02),
            3400.0,
        )


def quick_schedule(version: int = 1, name: str = "quick") -> Schedule:
    return Schedule(
        name=name, version=version, exposures_s=(0.05,), gains_db=(6.0, 8.0), repeats=2, wavelengths_nm=(460,)
    )


def make_agent(
    module: str,
    endpoint: str,
    outbox: Path,
    *,
    schedule: Schedule | None = None,
    sensors: bool = True,
    keys_dir: Path | None = None,
    lem: Any = None,
    **config: Any,
) -> tuple[Agent, SmallSimCamera]:
    """A module agent on a simulated camera: CURVE with the keys of ``keys_dir`` (see `link_keys`),
    else a plaintext link (for an in-process ingest started with ``plaintext=True``). ``lem``: the
    LEM's colour clock the runner follows (`lrm.runner.LemClock`; none: every shot at once)."""
    camera = SmallSimCamera(module)
    clock = RealClock()
    runner = ScheduleRunner(camera, clock, schedule or quick_schedule(), lem=lem)
    if keys_dir is not None:
        config["keys"] = wire.module_keys(keys_dir, module)
    else:
        config.setdefault("plaintext", True)
    cfg = AgentConfig(module=module, connect=endpoint, outbox=outbox, fsync=False, **config)
    agent = Agent(
        cfg,
        clock=clock,
        runner=runner,
        sensors=SteadySensors() if sensors else None,
        camera_limits=CameraLimits(camera.exposure_range_s, camera.gain_range_db, camera.gain_step_db),
    )
    return agent, camera


class TcpProxy:
    """A TCP relay between modules and the ship whose link can be cut and restored."""

    def __init__(self, upstream_port: int) -> None:
        self.upstream = ("127.0.0.1", upstream_port)
        probe = socket.socket()
        probe.bind(("127.0.0.1", 0))
        self.port = probe.getsockname()[1]
        probe.close()
        self._stop = threading.Event()
        self._cut = threading.Event()
        self._stall = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    @property
    def endpoint(self) -> str:
        return f"tcp://127.0.0.1:{self.port}"

    def cut(self) -> None:
        """Break every connection and refuse new ones (a cut fibre)."""
        self._cut.set()

    def restore(self) -> None:
        self._cut.clear()
        self._stall.clear()

    def stall(self) -> None:
        """Hold everything the ship sends (acks, welcomes) while the modules' bytes still get through."""
        self._stall.set()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)

    def _run(self) -> None:
        sel = selectors.DefaultSelector()
        listener: socket.socket | None = None
        peers: dict[socket.socket, socket.socket] = {}
        upstream: set[socket.socket] = set()

        def drop_all() -> None:
            for s in list(peers):
                with contextlib.suppress(KeyError, ValueError):
                    sel.unregister(s)
                s.close()
            peers.clear()
            upstream.clear()

        while not self._stop.is_set():
            if self._cut.is_set():
                if listener is not None:
                    sel.unregister(listener)
                    listener.close()
                    listener = None
                drop_all()
                time.sleep(0.05)
                continue
            if listener is None:
                listener = socket.socket()
                listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                listener.bind(("127.0.0.1", self.port))
                listener.listen()
                listener.setblocking(False)
                sel.register(listener, selectors.EVENT_READ)
            for key, _ in sel.select(0.05):
                s = key.fileobj
                if s is listener:
                    client, _ = listener.accept()
                    try:
                        up = socket.create_connection(self.upstream, timeout=2)
                    except OSError:
                        client.close()
                        continue
                    for a, b in ((client, up), (up, client)):
                        a.setblocking(False)
                        peers[a] = b
                        sel.register(a, selectors.EVENT_READ)
                    upstream.add(up)
                    continue
                other = peers.get(s)
                if other is None:
                    continue
                if self._stall.is_set() and s in upstream:
                    time.sleep(0.005)  # leave the ship's bytes unread
                    continue
                try:
                    data = s.recv(1 << 16)
                except (BlockingIOError, InterruptedError):
                    continue
                except OSError:
                    data = b""
                if not data:
                    for x in (s, other):
                        peers.pop(x, None)
                        upstream.discard(x)
                        with contextlib.suppress(KeyError, ValueError):
                            sel.unregister(x)
                        x.close()
                    continue
                try:
                    other.setblocking(True)
                    other.sendall(data)
                    other.setblocking(False)
                except OSError:
                    pass
        drop_all()
        if listener is not None:
            listener.close()


class FakeShip:
    """The ship's side of the protocol, driven by the test: a real ROUTER on 127.0.0.1.

    It greets modules, acknowledges every data message and records what the
    module says; `pump` runs it until a condition holds.
    """

    def __init__(self, ctx: Any, window: int = 8) -> None:
        self.sock = wire.ship_socket(ctx, "tcp://127.0.0.1:*")
        self.endpoint = self.sock.getsockopt(zmq.LAST_ENDPOINT).decode()
        self.window = window
        self.identity: bytes | None = None
        self.statuses: list[wire.CommandStatus] = []
        self.heartbeats: list[wire.ModuleHeartbeat] = []
        self.hellos: list[wire.Hello] = []
        self.data: list[tuple[str, str, int]] = []
        #: How to answer a data message (default: acknowledge it); None from it: say nothing.
        self.answer: Any = None

    def pump(self, until: Any = lambda: False, timeout: float = 10.0) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if until():
                return True
            if not self.sock.poll(20):
                continue
            parts = self.sock.recv_multipart()
            self.identity = parts[0]
            msg, _ = wire.decode(parts[1:], allowed=wire.MODULE_TYPES)
            if msg.type == "hello":
                self.hellos.append(msg)
                self.send(wire.Welcome(module="ship", window=self.window))
            elif msg.type in ("frame", "sensors"):
                self.data.append((msg.type, msg.boot, msg.seq))
                reply = (
                    self.answer(msg)
                    if self.answer
                    else wire.Ack(module="ship", ranges=((msg.boot, msg.seq, msg.seq),), window=self.window)
                )
                if reply is not None:
                    self.send(reply)
            elif msg.type == "command_status":
                self.statuses.append(msg)
            elif msg.type == "heartbeat":
                self.heartbeats.append(msg)
        return until()

    def send(self, msg: Any) -> None:
        assert self.identity is not None, "no module has connected yet"
        self.sock.send_multipart([self.identity, *wire.encode(msg)])

    def command(self, command_id: str, action: str, **fields: Any) -> None:
        self.send(wire.Command(module="ship", command_id=command_id, action=action, **fields))

    def states_of(self, command_id: str) -> list[str]:
        return [s.state for s in self.statuses if s.command_id == command_id]

    def close(self) -> None:
        self.sock.close(0)


def camcal_cli(*args: str, timeout: float = 120.0) -> subprocess.CompletedProcess[str]:
    """Run the real ``camcal`` command of this checkout in a subprocess (exit status and output)."""
    return subprocess.run(
        [sys.executable, "-c", "from camcal.cli import main; main()", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=cli_env(),
    )


def cli_env() -> dict[str, str]:
    """The environment for a ``camcal`` subprocess: this checkout first on the import path."""
    root = str(Path(__file__).resolve().parents[2])
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([root, *filter(None, [env.get("PYTHONPATH")])])
    return env


def link_keys(data: Path, *modules: str) -> Path:
    """The link's keys in ``data/keys`` (the ingest's default): the ship's and ``modules``' (A, B if none)."""
    from camcal.core.wire.keys import create_module_key, create_ship_key

    folder = data / "keys"
    create_ship_key(folder)
    for m in modules or ("A", "B"):
        create_module_key(folder, m)
    return folder


def start_ingest(
    data: Path,
    port: int,
    events_port: int,
    *extra: str,
    log: str = "ingest.log",
    events_host: str = "127.0.0.1",
) -> subprocess.Popen[bytes]:
    """``camcal ingest`` as its own process (one analysis worker) on 127.0.0.1 (its events port on
    ``events_host``); output to ``data/../log``.

    The link is CURVE with the keys of ``data/keys`` (made for A and B if missing, see `link_keys`),
    unless ``extra`` says ``--plaintext``.
    """
    if "--plaintext" not in extra:
        data.mkdir(parents=True, exist_ok=True)
        link_keys(data)
    with (data.parent / log).open("ab") as out:
        return subprocess.Popen(
            [
                sys.executable,
                "-c",
                "from camcal.cli import main; main()",
                "ingest",
                "--data",
                str(data),
                *extra,
                "--bind",
                f"tcp://127.0.0.1:{port}",
                "--events",
                f"tcp://{events_host}:{events_port}",
                "--workers",
                "1",
            ],
            stdout=out,
            stderr=out,
            start_new_session=True,
        )


def wait_for(predicate: Callable[[], Any], timeout: float, interval: float = 0.05) -> bool:
    """Poll ``predicate`` until it is true or ``timeout`` seconds pass (of an idle machine: stretched by
    how busy this one was meanwhile, `tests.utils.pace.Pace`); whether it became true."""
    pace = Pace()
    t0 = time.monotonic()
    while (waited := time.monotonic() - t0) < timeout or waited < pace.bound(timeout):
        if predicate():
            return True
        time.sleep(interval)
    return bool(predicate())


def stop_and_drain(agents: list[Agent], timeout: float = 60.0, quiet_s: float = 1.5) -> bool:
    """Stop the agents' schedules, let a shot already being taken reach the outbox, then wait until
    the ship has acknowledged everything.

    A shot the runner began before ``stop`` still ends in the outbox (capture, PNG encoding) a moment
    later; an outbox that is empty before it arrives is not drained. So the capture counts must stay
    put for ``quiet_s`` first. True when all outboxes drained within ``timeout``.
    """
    for a in agents:
        a.runner.stop()
    end = time.monotonic() + timeout
    last = [a.counters["frames_captured"] for a in agents]
    still_since = time.monotonic()
    while time.monotonic() - still_since < quiet_s and time.monotonic() < end:
        time.sleep(0.1)
        now = [a.counters["frames_captured"] for a in agents]
        if now != last:
            last, still_since = now, time.monotonic()
    return all(a.wait_drained(max(end - time.monotonic(), 0.0)) for a in agents)
