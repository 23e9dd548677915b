"""The conformance kits another lab can run (issue 38, item 11), on camcal's own ingest and module.

`camcal lrm conformance` checks a real ``camcal ingest`` process as a module
would; ``camcal ingest --conformance`` checks camcal's own module agent (and
a module that breaks rules, which it must catch). Both print pass or fail per
numbered rule of docs/protocol.md.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import zmq

from camcal.core.wire.keys import create_module_key
from camcal.core.wire.rules import RULES
from tests.utils.live import link_keys, make_agent
from tests.utils.rogue import IngestProbe, Rogue
from tests.utils.system import free_ports
from tests.utils.wiremsgs import frame_parts

CAMCAL = [sys.executable, "-c", "from camcal.cli import main; main()"]


def verdicts(out: str) -> dict[int, str]:
    """Rule number -> pass, fail or not checked, from a kit's report."""
    return {int(n): v for n, v in re.findall(r"^R(\d+)\s+(pass|fail|not checked)", out, re.MULTILINE)}


def test_camcal_ingest_keeps_every_rule_that_binds_a_ship(tmp_path: Path) -> None:
    probe = IngestProbe(tmp_path / "data")
    try:
        probe.wait_ready()
        create_module_key(probe.keys, "K")
        module_keys = tmp_path / "module-keys"  # what a module holds: ship.key, modules/K.key_secret
        (module_keys / "modules").mkdir(parents=True)
        shutil.copy(probe.keys / "ship.key", module_keys / "ship.key")
        shutil.copy(probe.keys / "modules" / "K.key_secret", module_keys / "modules" / "K.key_secret")
        run = subprocess.run(
            [*CAMCAL, "lrm", "conformance", probe.endpoint, "--keys", str(module_keys)],
            capture_output=True,
            text=True,
            timeout=240,
        )
        out = run.stdout + run.stderr
        found = verdicts(out)
        ship_rules = {r.number for r in RULES if r.binds in ("ship", "both")}
        assert set(found) == ship_rules, out
        assert [n for n, v in found.items() if v == "fail"] == [], out
        assert [n for n, v in found.items() if v == "not checked"] == [22], out  # (a flood: test_fairness)
        assert run.returncode == 0, out
        assert probe.alive()
    finally:
        probe.stop()


def _conformance_ship(data: Path, port: int, seconds: float) -> subprocess.Popen[str]:
    link_keys(data)
    return subprocess.Popen(
        [
            *CAMCAL,
            "ingest",
            "--conformance",
            "--conformance-s",
            str(seconds),
            "--data",
            str(data),
            "--bind",
            f"tcp://127.0.0.1:{port}",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )


def _started(proc: subprocess.Popen[str]) -> None:
    assert proc.stdout is not None
    end = time.monotonic() + 60
    while time.monotonic() < end:
        line = proc.stdout.readline()
        if "listens on" in line or not line:
            return
    raise AssertionError("the conformance ship did not start")


def test_camcal_module_keeps_every_rule_that_binds_a_module(tmp_path: Path) -> None:
    (port,) = free_ports(1)
    ship = _conformance_ship(tmp_path / "data", port, 90)
    agent = None
    try:
        _started(ship)
        agent, _ = make_agent(
            "A", f"tcp://127.0.0.1:{port}", tmp_path / "outbox", keys_dir=tmp_path / "data" / "keys"
        )
        agent.start()
        out, _ = ship.communicate(timeout=120)
    finally:
        if agent is not None:
            agent.stop()
        if ship.poll() is None:
            ship.kill()
    found = verdicts(out)
    module_rules = {r.number for r in RULES if r.binds in ("module", "both")}
    assert set(found) == module_rules, out
    assert all(v == "pass" for v in found.values()), out
    assert ship.returncode == 0, out


def test_the_ship_side_kit_catches_a_module_that_breaks_rules(tmp_path: Path) -> None:
    """A module with a guessable routing id that sends a frame before its hello."""
    (port,) = free_ports(1)
    data = tmp_path / "data"
    ship = _conformance_ship(data, port, 6)
    rogue = None
    try:
        _started(ship)
        rogue = Rogue(
            zmq.Context.instance(), f"tcp://127.0.0.1:{port}", "A", keys_dir=data / "keys", route=b"A"
        )
        rogue.send(frame_parts(module="A", camera="A", boot="k", seq=1))
        rogue.send([json.dumps({"v": 1, "type": "hello", "module": "A", "boot": "k"}).encode()])
        out, _ = ship.communicate(timeout=60)
    finally:
        if rogue is not None:
            rogue.close()
        if ship.poll() is None:
            ship.kill()
    found = verdicts(out)
    assert found[2] == "fail" and found[12] == "fail", out
    assert ship.returncode == 1, out
