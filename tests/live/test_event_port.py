"""The events port beyond loopback, with real processes: only the ship's key hears it.

A real ``camcal ingest`` publishes its events on ``tcp://0.0.0.0:PORT``: the
port then speaks CURVE, and a subscriber hears its heartbeats only with the
ship's key pair. A plaintext subscriber, one holding a module's key (every
module knows the ship's public key) and one with a key of its own connect
and receive nothing, and the ingest logs the refused ones with their
address. ``camcal serve`` relays the events with the ship's keys (through
127.0.0.1 with ``events_curve`` set, and through the machine's own network
address by itself), ``camcal doctor`` hears the heartbeat, and a ship
without keys refuses to publish beyond loopback in one line. (``camcal up``,
on loopback, is unchanged: ``tests/live/test_up.py``.)
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
import zmq

from camcal.core.eventport import subscriber
from camcal.core.wire.keys import module_keys, ship_public
from tests.utils.live import camcal_cli, cli_env, start_ingest, wait_for
from tests.utils.system import camcal_serve, free_ports


def lan_address() -> str | None:
    """An address of this machine beyond loopback (none sent: a UDP socket only picks its route)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.connect(("192.0.2.123", 9))
            address = s.getsockname()[0]
        except OSError:
            return None
    return None if address.startswith("127.") else address


def plain_sub(ctx: zmq.Context[Any], endpoint: str) -> Any:
    sub = ctx.socket(zmq.SUB)
    sub.setsockopt(zmq.SUBSCRIBE, b"")
    sub.setsockopt(zmq.LINGER, 0)
    sub.connect(endpoint)
    return sub


def curve_sub(ctx: zmq.Context[Any], endpoint: str, server: bytes, public: bytes, secret: bytes) -> Any:
    sub = ctx.socket(zmq.SUB)
    sub.setsockopt(zmq.CURVE_SERVERKEY, server)
    sub.setsockopt(zmq.CURVE_PUBLICKEY, public)
    sub.setsockopt(zmq.CURVE_SECRETKEY, secret)
    sub.setsockopt(zmq.SUBSCRIBE, b"")
    sub.setsockopt(zmq.LINGER, 0)
    sub.connect(endpoint)
    return sub


@pytest.fixture(scope="module")
def published(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Path, int]]:
    """An ingest with its events port on every address of the machine; (its data folder, the port)."""
    data = tmp_path_factory.mktemp("eventport") / "data"
    port, events_port = free_ports(2)
    proc = start_ingest(data, port, events_port, events_host="0.0.0.0")
    try:
        ctx = zmq.Context.instance()
        keyed = subscriber(ctx, f"tcp://127.0.0.1:{events_port}", keys_dir=data / "keys", curve=True)
        try:
            assert wait_for(lambda: proc.poll() is not None or keyed.poll(100), 60), "no heartbeat"
        finally:
            keyed.close(0)
        assert proc.poll() is None, (data.parent / "ingest.log").read_text()[-2000:]
        yield data, events_port
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(30)


def test_only_the_ships_key_hears_the_events_port(published) -> None:
    data, events_port = published
    endpoint = f"tcp://127.0.0.1:{events_port}"
    ctx = zmq.Context.instance()
    a = module_keys(data / "keys", "A")
    own_public, own_secret = zmq.curve_keypair()
    keyed = subscriber(ctx, endpoint, keys_dir=data / "keys", curve=True)
    others = {
        "plaintext": plain_sub(ctx, endpoint),
        "module A's key": curve_sub(ctx, endpoint, ship_public(data / "keys"), a.pair.public, a.pair.secret),
        "a key of its own": curve_sub(ctx, endpoint, ship_public(data / "keys"), own_public, own_secret),
    }
    heard = {name: 0 for name in others}
    heartbeats = 0
    end = time.monotonic() + 60
    try:
        while heartbeats < 4 and time.monotonic() < end:  # four heartbeats: seconds of every event
            if keyed.poll(100):
                kind, _ = keyed.recv_multipart()
                heartbeats += kind == b"health"
            for name, sub in others.items():
                while sub.poll(0):
                    sub.recv_multipart()
                    heard[name] += 1
    finally:
        for sub in (keyed, *others.values()):
            sub.close(0)
    print(f"events port beyond loopback: the ship's key heard {heartbeats} heartbeats; the others {heard}")
    assert heartbeats >= 4, "the ship's own key heard no heartbeat"
    assert heard == {name: 0 for name in others}, heard
    log = data.parent / "ingest.log"
    assert wait_for(lambda: "refused a subscriber of the events port" in log.read_text(), 10), (
        log.read_text()[-2000:]
    )


def test_the_dashboard_and_the_doctor_listen_with_the_ships_key(published) -> None:
    data, events_port = published
    reach = [(f"tcp://127.0.0.1:{events_port}", {"CAMCAL_EVENTS_CURVE": "true"})]
    lan = lan_address()
    if lan is not None:  # by the machine's own network address: CURVE without being told
        reach.append((f"tcp://{lan}:{events_port}", {}))
    for endpoint, extra in reach:
        env = {"CAMCAL_EVENTS_CONNECT": endpoint, **extra}
        with camcal_serve(data, "--events", endpoint, env=env) as (url, _):

            def relayed() -> bool:
                health = httpx.get(f"{url}/api/health", timeout=5).json()
                return bool(health["ingest"]["up"])

            assert wait_for(relayed, 30), f"the dashboard relays no heartbeat from {endpoint}"
        doctor = cli(env, "doctor", "--data", str(data), "--check", "ingest")
        assert "heartbeat received" in doctor.stdout + doctor.stderr, doctor.stdout + doctor.stderr
    # Without the ship's keys the dashboard does not start, and says what to do.
    empty = data.parent / "no-keys"
    empty.mkdir(exist_ok=True)
    r = cli(
        {"CAMCAL_KEYS_DIR": str(empty), "CAMCAL_EVENTS_CURVE": "true"},
        "serve", "--data", str(data), "--port", str(free_ports(1)[0]),
        "--events", f"tcp://127.0.0.1:{events_port}",
    )  # fmt: skip
    assert r.returncode == 3, r.stdout + r.stderr
    assert "needs the ship's key pair" in r.stdout + r.stderr and "camcal keys create" in r.stdout + r.stderr


def test_a_ship_without_keys_publishes_on_loopback_only(tmp_path: Path) -> None:
    port, events_port = free_ports(2)
    r = camcal_cli(
        "ingest", "--data", str(tmp_path / "data"), "--plaintext", "--workers", "1",
        "--bind", f"tcp://127.0.0.1:{port}", "--events", f"tcp://0.0.0.0:{events_port}",
    )  # fmt: skip
    out = r.stdout + r.stderr
    assert r.returncode == 3, out
    assert "beyond loopback" in out and "tcp://127.0.0.1:PORT" in out, out
    with socket.socket() as s:  # nothing was left bound
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind(("127.0.0.1", port))


def cli(env: dict[str, str], *args: str) -> subprocess.CompletedProcess[str]:
    """``camcal ARGS`` of this checkout with ``env`` added to the environment."""
    return subprocess.run(
        [sys.executable, "-c", "from camcal.cli import main; main()", *args],
        capture_output=True,
        text=True,
        timeout=120,
        env={**cli_env(), **env},
    )
