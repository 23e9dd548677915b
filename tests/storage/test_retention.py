"""At sea the disk fills: a disk alarm, and retention of old frame files."""

from __future__ import annotations

import time
from pathlib import Path

from fastapi.testclient import TestClient

from ingest.alarms import AlarmEvaluator, AlarmLimits
from server.app import create_app
from server.settings import ServerSettings
from storage.store import FrameRow, Store


def test_low_disk_raises_a_major_alarm_that_says_what_to_do() -> None:
    ev = AlarmEvaluator(AlarmLimits(disk_min_free_gb=5.0))
    ev.observe_disk(12.0)
    assert "disk:ship" not in ev.evaluate(time.time())
    ev.observe_disk(1.2)
    c = ev.evaluate(time.time())["disk:ship"]
    assert c.severity == "MAJOR" and "1.2 GB" in c.message and "retention" in c.message


def test_retention_deletes_old_frame_files_but_keeps_rows(tmp_path: Path) -> None:
    store = Store.open(tmp_path / "data", sqlite_synchronous="NORMAL")
    dive = store.current_dive()
    now = time.time()
    rows = []
    for seq, age_days in ((1, 100.0), (2, 1.0)):
        rel = store.files.relative_path(dive.id, "A", "b", seq)
        store.files.write(rel, b"\x89PNG fake", fsync=False)
        rows.append(
            FrameRow(
                module_id="A",
                boot="b",
                seq=seq,
                captured_unix_s=now - age_days * 86400,
                received_unix_s=now,
                wavelength_nm=460,
                exposure_s=0.05,
                gain_db=8.0,
                depth_m=None,
                width_px=1,
                height_px=1,
                path=rel,
                size_bytes=9,
                sha256="0" * 64,
            )
        )
    ids = store.commit_batch(dive.id, rows).new_frames
    n, freed = store.purge_frame_files(now - 30 * 86400)
    assert (n, freed) == (1, 9)
    assert not store.files.resolve(rows[0].path).exists() and store.files.resolve(rows[1].path).exists()
    app = create_app(ServerSettings(data_dir=tmp_path / "data", events=None), store=store)
    with TestClient(app) as client:
        old = ids[("A", "b", 1)]
        r = client.get(f"/api/frames/{old}/image")
        assert r.status_code == 410 and "retention" in r.json()["error"]["message"]
        assert client.get(f"/api/frames/{old}").status_code == 200
    store.close()
