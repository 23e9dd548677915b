"""When a dive ends, and when the next start begins a new one: a real `camcal ingest` process, a module
streaming to it, and `camcal dive list`.

Seen on deck: after the simulated dive ended (both modules back on deck and signed off) a second
`camcal up` poured its descent into the same dive. Now a dive whose modules came back on deck and
signed off has ended (`dive list` says so and why), the next start records that and begins a new
dive, saying so; a restart in the middle of a dive (the module still deep) continues it.
"""

from __future__ import annotations

import json
import signal
import subprocess
from dataclasses import replace
from pathlib import Path

from storage import queries
from storage.store import Store
from tests.live.test_faults import free_port
from tests.utils.live import Sample, SteadySensors, camcal_cli, make_agent, start_ingest, wait_for


class Winch(SteadySensors):
    """The module's pressure sensor at whatever depth the test winches it to."""

    def __init__(self, depth_m: float) -> None:
        super().__init__()
        self.depth_m = depth_m

    def read(self) -> Sample:
        return replace(super().read(), depth_m=self.depth_m)


def _dives(data: Path) -> list[dict[str, object]]:
    """The dives as `camcal dive list --json` gives them, read in this process (polled)."""
    store = Store.open(data, run_migrations=False)
    try:
        return store.call(queries.dives)
    finally:
        store.close()


def _listed(data: Path) -> list[dict[str, object]]:
    done = camcal_cli("dive", "list", "--json", "--data", str(data))
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


def _stop(proc: subprocess.Popen[bytes]) -> None:
    proc.send_signal(signal.SIGINT)
    proc.wait(30)


def _deployment(tmp_path: Path, data: Path, log: str, end_depth_m: float) -> tuple[str, dict[str, object]]:
    """An ingest and module A: deep, then at ``end_depth_m``, then the module signs off and the ingest
    stops. The ingest's log and the dive as `dive list` has it after the module signed off."""
    port, events = free_port(), free_port()
    ingest = start_ingest(data, port, events, log=log)
    agent, _ = make_agent("A", f"tcp://127.0.0.1:{port}", tmp_path / f"outbox-{log}", keys_dir=data / "keys")
    winch = Winch(3400.0)
    agent.sensors = winch
    try:
        agent.start()
        assert wait_for(lambda: agent.counters["acked"] >= 6, 60), (tmp_path / log).read_text()
        winch.depth_m = end_depth_m  # the winch brings it up (or not)
        n = agent.counters["sensor_batches"]
        assert wait_for(lambda: agent.counters["sensor_batches"] >= n + 2, 30)
        assert agent.wait_drained(30)
    finally:
        agent.stop()  # says bye
    try:
        assert wait_for(lambda: _dives(data)[0]["state"] != "open" or end_depth_m > 10, 20)
        dive = _dives(data)[0]
    finally:
        _stop(ingest)
    return (tmp_path / log).read_text(), dive


def test_a_dive_back_on_deck_and_signed_off_has_ended_and_the_next_start_begins_a_new_one(
    tmp_path: Path,
) -> None:
    data = tmp_path / "data"
    said, first = _deployment(tmp_path, data, "ingest-1.log", end_depth_m=0.5)
    assert f"dive {first['name']}: new" in said
    assert first["state"] == "ended", first
    assert "back on deck and signed off (A;" in str(first["state_reason"]), first
    assert first["end_reason"] is None  # what the modules did: recorded by the next start
    listed = " ".join(camcal_cli("dive", "list", "--data", str(data)).stdout.split())
    assert "ended" in listed and "back on deck and signed off" in listed

    said, second = _deployment(tmp_path, data, "ingest-2.log", end_depth_m=3400.0)
    assert second["name"] != first["name"], "the next deployment went into the ended dive"
    line = " ".join(said.split())
    assert f"dive {first['name']} has ended (back on deck and signed off" in line, line
    assert f"dive {second['name']}: new" in line, line
    old = next(d for d in _listed(data) if d["name"] == first["name"])
    assert old["state"] == "ended" and old["end_reason"] == first["state_reason"]
    assert old["n_frames"] == first["n_frames"], "frames of the next deployment joined the ended dive"

    # Stopped with the module still at 3400 m: a restart in the middle of the dive continues it.
    assert second["state"] == "open" and "in the water (A at 3400 m)" in str(second["state_reason"])
    port, events = free_port(), free_port()
    ingest = start_ingest(data, port, events, log="ingest-3.log")
    try:
        assert wait_for(lambda: "dive " in (tmp_path / "ingest-3.log").read_text(), 60)
        assert wait_for(lambda: "continued" in (tmp_path / "ingest-3.log").read_text(), 30)
    finally:
        _stop(ingest)
    line = " ".join((tmp_path / "ingest-3.log").read_text().split())
    assert f"dive {second['name']}: continued (its last frame arrived" in line, line
    assert [d["name"] for d in _dives(data)] == [second["name"], first["name"]]
