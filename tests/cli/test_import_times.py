"""A frame set's capture times as other tools write them: read as UTC, wherever the ship's clock is set.

`camcal import` runs as a real process with the machine's zone set to Tokyo (a ship's laptop set
to its port's time) on a frame set whose manifest writes its times four ways, leaves one out and
garbles one.
"""

from __future__ import annotations

import csv
import sqlite3
import subprocess
import sys
import time
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from camcal.core.images import encode_png
from tests.utils.live import camcal_cli, cli_env
from tests.utils.sim import SMALL_CAMERA, renderer

TRUE = datetime(2021, 9, 5, 3, 12, 44, tzinfo=UTC).timestamp()
STAMPS = {
    1: "2021-09-05T03:12:44Z",
    2: "2021-09-05 03:12:46",  # no zone: UTC, as the frame-set format says
    3: "2021-09-05T12:12:48+09:00",
    4: "2021-09-05T03:12:50.250",
    5: "",  # no time at all
    6: "5/9/2021 03:12",  # not ISO 8601
}


def frame_set(root: Path) -> Path:
    folder = root / "set"
    folder.mkdir()
    render = renderer("trex", 41.62, far_side=True, camera=SMALL_CAMERA, camera_id="B")
    with open(folder / "manifest.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["file", "camera", "wavelength_nm", "exposure_s", "gain_db", "timestamp", "seq"])
        for seq, stamp in STAMPS.items():
            pixels, _ = render.render(460, 0.05, 8.0, rng=np.random.default_rng(seq))
            (folder / f"B_{seq}.png").write_bytes(encode_png(pixels))
            w.writerow([f"B_{seq}.png", "B", 460, 0.05, 8.0, stamp, seq])
    return folder


def test_times_without_a_zone_are_utc_a_missing_one_is_said_and_a_garbled_one_named(tmp_path: Path) -> None:
    folder, data = frame_set(tmp_path), tmp_path / "data"
    env = cli_env() | {"TZ": "Asia/Tokyo"}
    before = time.time()
    res = subprocess.run(
        [sys.executable, "-c", "from camcal.cli import main; main()", "import", str(folder), "--data", data],
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
    )
    out = " ".join((res.stdout + res.stderr).split())
    assert res.returncode == 0, out
    assert "5 frames imported" in out, out
    assert "1 frames had no capture time" in out and "stamped with this import's clock" in out, out
    assert "B_6.png" in out and "'5/9/2021 03:12' is not an ISO 8601 time" in out, out
    with sqlite3.connect(data / "camcal.db") as db:
        times = dict(db.execute("SELECT seq, captured_unix_s FROM frames"))
    assert set(times) == {1, 2, 3, 4, 5}
    assert [times[s] - TRUE for s in (1, 2, 3, 4)] == [0.0, 2.0, 4.0, 6.25]
    assert before <= times[5] <= time.time()


def test_a_set_without_any_time_makes_no_series_over_time(tmp_path: Path) -> None:
    folder = tmp_path / "untimed"
    folder.mkdir()
    with open(folder / "manifest.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["file", "camera", "wavelength_nm", "exposure_s", "gain_db"])
        for cam, distance in (("A", 21.56), ("B", 41.62)):
            render = renderer("trex", distance, far_side=cam == "B", camera=SMALL_CAMERA, camera_id=cam)
            for k in range(3):
                pixels, _ = render.render(460, 0.05, 8.0, rng=np.random.default_rng(k))
                (folder / f"{cam}_{k}.png").write_bytes(encode_png(pixels))
                w.writerow([f"{cam}_{k}.png", cam, 460, 0.05, 8.0])
    res = camcal_cli("import", str(folder), "--data", str(tmp_path))
    out = " ".join((res.stdout + res.stderr).split())
    assert res.returncode == 0 and "6 frames imported" in out and "6 analysed" in out, out
    assert "λ_att visits" not in out and "no series is made" in out, out
    with sqlite3.connect(tmp_path / "camcal.db") as db:
        assert db.execute("SELECT COUNT(*) FROM attenuation_points").fetchone() == (0,)
