"""`camcal import` killed while it analyses: what it analysed is kept, the same import again finishes it.

A real `camcal import` process on a real SQLite store, killed with SIGKILL
(the OOM killer, a closed laptop) once its first results are stored. Before,
its results were stored all at once at the end, so a kill lost all of them,
and the next import found every frame "already present" and analysed none:
the frames stayed without a result, and the dive without a series, for good.
"""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

from tests.utils.indepset import START, Station
from tests.utils.live import camcal_cli, cli_env


def count(db: Path, table: str) -> int:
    try:
        with sqlite3.connect(db, timeout=5) as c:
            return int(c.execute(f"SELECT COUNT(*) FROM {table}").fetchone()[0])
    except sqlite3.OperationalError:  # not created yet
        return 0


def test_an_import_killed_while_it_analyses_is_finished_by_the_same_import_again(tmp_path: Path) -> None:
    folder, data = tmp_path / "set", tmp_path / "data"
    n = Station(seed=4, duration_s=400.0).write(folder, START)
    db = data / "camcal.db"
    args = ["import", str(folder), "--data", str(data), "--workers", "1"]
    proc = subprocess.Popen(
        [sys.executable, "-c", "from camcal.cli import main; main()", *args],
        env=cli_env(),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    try:
        deadline = time.monotonic() + 120
        while count(db, "frame_results") == 0 and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.02)
        assert proc.poll() is None, "the import ended before it could be killed"
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(10)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    kept = count(db, "frame_results")
    assert count(db, "frames") == n and 0 < kept < n, (kept, n)

    res = camcal_cli("import", str(folder), "--data", str(data), timeout=300)
    said = " ".join((res.stdout + res.stderr).split())
    assert res.returncode == 0, said
    assert f"0 frames imported, {n} already present" in said and f"{n - kept} analysed" in said, said
    assert count(db, "frame_results") == n
    assert count(db, "attenuation_points") >= 3, said
    again = camcal_cli("import", str(folder), "--data", str(data))
    assert "0 analysed" in " ".join(again.stdout.split()), again.stdout  # nothing left to do
