"""`camcal dive list` and `camcal dive end` against a real ingest process and a module streaming to it.

Without an end, an ingest (and `camcal up`) started for the next deployment recorded into the
last dive still open: two deployments' frames in one dive. `camcal dive end` ends it, refusing
while an ingest on this machine serves the store, and the next ingest starts a new dive.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

from camcal.cli.dive import dive_for_start
from camcal.core.settings import Settings
from storage import queries
from storage.store import FrameRow, Store
from tests.live.test_faults import free_port
from tests.utils.live import camcal_cli, make_agent, start_ingest, wait_for


def _stop(proc: subprocess.Popen[bytes]) -> None:
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(20)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(5)


def _dives(data: Path) -> list[dict[str, object]]:
    done = camcal_cli("dive", "list", "--json", "--data", str(data))
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


def test_a_dive_ends_once_its_ingest_stopped_and_the_next_ingest_starts_a_new_one(tmp_path: Path) -> None:
    data = tmp_path / "data"
    port, events = free_port(), free_port()
    ingest = start_ingest(data, port, events)
    agent, _ = make_agent("A", f"tcp://127.0.0.1:{port}", tmp_path / "outbox", keys_dir=data / "keys")
    try:
        agent.start()
        assert wait_for(lambda: agent.counters["acked"] >= 4, 60), (tmp_path / "ingest.log").read_text()
        (first,) = _dives(data)
        assert first["ended_unix_s"] is None and first["n_frames"] >= 4

        refused = camcal_cli("dive", "end", "--data", str(data))
        assert refused.returncode == 1
        said = " ".join(refused.stderr.split())
        assert f"pid {ingest.pid}" in said and "stop it first" in said, said
        assert _dives(data)[0]["ended_unix_s"] is None
    finally:
        agent.stop()
        _stop(ingest)

    ended = camcal_cli("dive", "end", "--data", str(data))
    assert ended.returncode == 0, ended.stderr
    assert f"dive {first['name']} ended" in " ".join(ended.stdout.split())
    (d,) = _dives(data)
    assert d["ended_unix_s"] is not None
    again = camcal_cli("dive", "end", str(first["name"]), "--data", str(data))
    assert again.returncode == 0 and "already" in again.stdout
    store = Store.open(data)
    try:
        (entry,) = [a for a in store.call(queries.audit) if a["action"] == "dive.end"]
        assert entry["target"] == first["name"] and entry["details"]["n_frames"] == d["n_frames"]
    finally:
        store.close()

    ingest = start_ingest(data, port, events, log="ingest-2.log")
    try:
        assert wait_for(lambda: len(_dives(data)) == 2, 60), (tmp_path / "ingest-2.log").read_text()
    finally:
        _stop(ingest)
    new, old = _dives(data)
    assert old["name"] == first["name"] and old["n_frames"] == d["n_frames"] >= first["n_frames"]
    assert new["name"] != first["name"] and new["ended_unix_s"] is None
    listed = camcal_cli("dive", "list", "--data", str(data)).stdout.splitlines()
    assert listed[0].split() == ["id", "name", "frames", "received", "(UTC)", "deepest", "state"]
    assert listed[1].split()[1:3] == [str(new["name"]), "0"]
    assert listed[1].endswith("open: no module has recorded into it yet")
    assert listed[2].split()[1:3] == [str(old["name"]), str(old["n_frames"])] and " ended " in listed[2]
    assert listed[2].endswith("ended by cli (camcal dive end)")


def test_ending_names_what_it_cannot_end(tmp_path: Path) -> None:
    data = tmp_path / "data"
    Store.open(data).close()  # a store without a dive
    none = camcal_cli("dive", "end", "--data", str(data))
    assert none.returncode == 2 and "no open dive" in none.stderr
    unknown = camcal_cli("dive", "end", "leg-9", "--data", str(data))
    assert unknown.returncode == 2 and "no dive named 'leg-9'" in unknown.stderr
    assert "camcal dive list" in unknown.stderr


def test_camcal_up_says_whether_it_continues_a_dive_and_how_to_start_a_new_one(tmp_path: Path) -> None:
    settings = Settings(data_dir=tmp_path / "data")
    first, line = dive_for_start(settings)
    assert line == f"dive {first}: new"
    store = Store.open(settings.data_dir)
    try:
        dive = store.current_dive(create=False)
        assert dive is not None and dive.name == first
        # received 2 h ago, stamped by a module clock running ahead (a simulation at 10x): the age is
        # the ship's, never negative ("the last -0.9 h ago" was the module's clock against the ship's)
        t = time.time() - 2 * 3600
        row = FrameRow("A", "b1", 1, t + 5 * 3600, t, 460, 0.05, 6.0, 3420.0, 64, 64, "f.png", 10, "0" * 64)
        store.commit_batch(dive.id, [row])
    finally:
        store.close()
    again, line = dive_for_start(settings)
    assert again == first
    assert line == f"dive {first}: continued (its last frame arrived 2.0 h ago); it is still in the water " \
        "by its modules' depths. A new deployment? stop, run `camcal dive end`, start again"  # fmt: skip
    done = camcal_cli("dive", "end", "--data", str(settings.data_dir))
    assert done.returncode == 0, done.stderr
    new, line = dive_for_start(settings)
    assert new != first and line == f"dive {new}: new"
