"""A module streams only into the dive it was started for, and only to something that speaks the protocol.

Real processes: ``camcal ingest --dive`` and ``camcal lrm simulate --dive``
over CURVE, a plain TCP listener that answers garbage, and an ingest with
another ship key. The module refuses each wrong peer with a clear error and
exit status 3; the ingest refuses every message of another dive
(``wrong_dive``), so nothing of such a module is ever stored.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from camcal.core.wire.keys import create_module_key, create_ship_key
from ingest.service import IngestService
from tests.live.conftest import ingest_config
from tests.live.test_ingest import wait_for
from tests.utils.live import cli_env, make_agent
from tests.utils.peers import HTTP_ERROR, tcp_peer
from tests.utils.rogue import IngestProbe
from tests.utils.wiremsgs import frame_parts

REFUSED_EXIT = 3


def simulate(connect: str, keys: Path, outbox: Path, dive: str, timeout_s: float = 60.0) -> tuple[int, str]:
    """``camcal lrm simulate --dive DIVE`` until it exits by itself; its status and output."""
    args = ["lrm", "simulate", "--camera", "A", "--connect", connect, "--outbox", str(outbox)]
    args += ["--dive", dive, "--keys", str(keys), "--speed", "50", "--frame-scale", "0.1", "--deck-s", "0"]
    t0 = time.monotonic()
    res = subprocess.run(
        [sys.executable, "-c", "from camcal.cli import main; main()", *args],
        capture_output=True,
        text=True,
        timeout=timeout_s,
        env=cli_env(),
    )
    out = " ".join((res.stdout + res.stderr).split())
    return res.returncode, f"{out} [{time.monotonic() - t0:.1f} s]"


@pytest.fixture(scope="module")
def ship(tmp_path_factory: pytest.TempPathFactory) -> Iterator[IngestProbe]:
    probe = IngestProbe(tmp_path_factory.mktemp("dive") / "data", "--dive", "trex-7")
    probe.wait_ready()
    yield probe
    probe.stop()


def test_a_module_started_for_another_dive_refuses_the_ingest_and_nothing_of_it_is_stored(
    ship: IngestProbe, tmp_path: Path
) -> None:
    code, out = simulate(ship.endpoint, ship.keys, tmp_path / "outbox", "trex-8")
    assert code == REFUSED_EXIT, out
    assert "records dive 'trex-7'" in out and "started for dive 'trex-8'" in out, out
    assert ship.rows("SELECT COUNT(*) FROM frames WHERE module_id='A'") == [(0,)]
    assert ship.rows("SELECT COUNT(*) FROM sensor_batches WHERE module_id='A'") == [(0,)]
    assert ship.rows("SELECT id FROM modules WHERE id='A'") == [], "a refused module is not a module here"
    health = ship.health()
    assert health["nacked"]["wrong_dive"] >= 1 and "A" not in health["modules"]
    assert ship.alive()


def test_a_message_of_another_dive_is_refused_and_one_of_this_dive_is_stored(ship: IngestProbe) -> None:
    rogue = ship.rogue("R")
    try:
        (reply,) = rogue.send(frame_parts(boot="k", seq=1, module="R", camera="R", dive="trex-8"))
        assert (reply.type, reply.reason, reply.retry, reply.seq) == ("nack", "wrong_dive", True, 1)
        assert "trex-7" in reply.detail and "trex-8" in reply.detail
        assert ship.rows("SELECT COUNT(*) FROM frames WHERE module_id='R'") == [(0,)]
        # this dive's: its hello welcomed (data before a hello is refused since 1.9), its frame stored
        hello = {"v": 1, "type": "hello", "module": "R", "boot": "k", "dive": "trex-7"}
        (welcome,) = rogue.send([json.dumps(hello).encode()])
        assert (welcome.type, welcome.dive) == ("welcome", "trex-7") and welcome.ingest
        (reply,) = rogue.send(frame_parts(boot="k", seq=1, module="R", camera="R", dive="trex-7"))
        assert reply.type == "ack", reply
        assert ship.rows("SELECT COUNT(*) FROM frames WHERE module_id='R'") == [(1,)]
    finally:
        rogue.close()


def test_a_module_refuses_a_port_that_does_not_speak_the_protocol(ship: IngestProbe, tmp_path: Path) -> None:
    with tcp_peer(lambda n: HTTP_ERROR) as endpoint:  # not ZeroMQ: an HTTP error to everyone
        code, out = simulate(endpoint, ship.keys, tmp_path / "outbox", "trex-7")
    assert code == REFUSED_EXIT, out
    assert "does not complete the camcal link's handshake" in out and endpoint in out, out


def test_a_module_refuses_an_ingest_with_another_ship_key(ship: IngestProbe, tmp_path: Path) -> None:
    keys = tmp_path / "keys"  # A's own key pair, but a ship key that is not this ship's
    create_ship_key(keys)
    create_module_key(keys, "A")
    code, out = simulate(ship.endpoint, keys, tmp_path / "outbox", "trex-7")
    assert code == REFUSED_EXIT, out
    assert "handshake" in out, out
    assert ship.rows("SELECT COUNT(*) FROM frames WHERE module_id='A'") == [(0,)]


def test_the_welcome_names_the_ingest_and_its_dive_and_the_module_streams_into_it(tmp_path: Path) -> None:
    svc = IngestService(ingest_config(tmp_path / "data", dive_name="trex-9"))
    svc.start()
    agent, _ = make_agent("A", svc.endpoint, tmp_path / "outbox", dive="trex-9")
    try:
        agent.start()
        assert wait_for(lambda: agent.counters["acked"] >= 2, 30)
        assert agent.check.ship == {"ingest": svc.instance, "dive": "trex-9"}
        assert agent.refusal is None
    finally:
        agent.stop()
        svc.stop()
