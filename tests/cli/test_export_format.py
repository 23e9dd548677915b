"""A dive's export reads without a converter: ISO 8601 UTC beside every UNIX time, and the audit log
says what happened in the words the review page uses.

`camcal export` (the real CLI, in a subprocess) of a copy of the shared simulated dive, with a
schedule command and the module's answer in its audit log, as the server and the ingest write them.
"""

from __future__ import annotations

import csv
import json
import uuid
from datetime import UTC, datetime
from pathlib import Path

import pyarrow.parquet as pq

from storage import queries
from storage.store import Store
from tests.utils.dive_store import copy_data
from tests.utils.system import run_camcal


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as fh:
        return list(csv.DictReader(fh))


def _iso(unix_s: str) -> str:
    return (
        datetime.fromtimestamp(float(unix_s), UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")
    )


def test_export_has_iso_utc_times_and_the_audit_logs_words(dive_data, tmp_path: Path) -> None:
    data = copy_data(dive_data[0], tmp_path / "data")
    cid = uuid.uuid4().hex
    schedule = {
        "name": "quick-check",
        "version": 2,
        "exposures_s": [0.05, 0.07, 0.11],
        "gains_db": [6.0],
        "repeats": 10,
        "wavelengths_nm": [405, 460, 525],
        "blocks": [],
    }
    store = Store.open(data, None)
    try:
        store.audit(
            "ops",
            "command.set_schedule",
            "module:A",
            {"command_id": cid, "schedule": schedule, "apply": "now"},
        )
        store.audit("module:A", "command.done", "module:A", {"command_id": cid, "action": "set_schedule"})
        dive = store.call(queries.dives)[0]
    finally:
        store.close()

    code, out, _ = run_camcal(
        ["export", "--data", str(data), "--dive", dive["name"], "--out", str(tmp_path / "out")],
        uuid.uuid4().hex,
        tmp_path,
    )
    assert code == 0, out
    frames = _rows(tmp_path / "out" / "frames.csv")
    assert frames
    names = list(frames[0])
    for col in [c for c in names if c.endswith("_unix_s")]:
        utc = col.removesuffix("_unix_s") + "_utc"
        assert names[names.index(col) + 1] == utc, f"{utc} is not beside {col}: {names}"
    for f in frames[:50]:
        assert f["captured_utc"] == _iso(f["captured_unix_s"]), f
    sensors = _rows(tmp_path / "out" / "sensor_samples.csv")
    assert sensors and all(s["t_utc"] == _iso(s["t_unix_s"]) for s in sensors[:50])
    table = pq.read_table(tmp_path / "out" / "frames.parquet")
    assert table.column("captured_utc").to_pylist()[:5] == [f["captured_utc"] for f in frames[:5]]

    audit = {a["action"]: a for a in _rows(tmp_path / "out" / "audit_log.csv")}
    sent, done = audit["command.set_schedule"], audit["command.done"]
    assert sent["what"] == (
        f"sent quick-check v2 (3 exposures × 1 gain × 10 at 405/460/525 nm) to LRM-A, to apply now #{cid[:8]}"
    )
    assert done["what"] == f"LRM-A applied the schedule change #{cid[:8]}"
    assert json.loads(sent["details"])["schedule"]["name"] == "quick-check"
    assert sent["t_utc"] == _iso(sent["t_unix_s"])
    about = json.loads((tmp_path / "out" / "run.json").read_text())
    assert about["exported_utc"] == _iso(str(about["exported_unix_s"]))
