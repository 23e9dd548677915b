"""`camcal import` stopped or killed as it analyses: what it did is kept, the same import again finishes it.

A real `camcal import` process on a real SQLite store, stopped with SIGTERM
and killed with SIGKILL (the OOM killer) once results are stored. Before,
its results were stored all at once at the end, so a kill lost all of them,
and the next import found every frame "already present" and analysed none:
the frames stayed without a result, and the dive without a series, for good;
Ctrl-C waited for every frame still queued, then dropped their results.
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
from tests.utils.pace import Pace


def count(db: Path, table: str) -> int:
    try:
        with sqlite3.connect(db, timeout=5) as c:
            return int(c.execute(f"SELECT COUNT(*) FROM {table}").fetchone()[0])
    except sqlite3.OperationalError:  # not created yet
        return 0


def start_import(folder: Path, data: Path) -> subprocess.Popen[str]:
    args = ["import", str(folder), "--data", str(data), "--workers", "1"]
    return subprocess.Popen(
        [sys.executable, "-c", "from camcal.cli import main; main()", *args],
        env=cli_env(),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )


def stop_when_results_pass(proc: subprocess.Popen[str], db: Path, above: int, sig: int) -> tuple[str, float]:
    """Send ``sig`` to the import's process group once more than ``above`` results are stored."""
    try:
        deadline = time.monotonic() + 120
        while count(db, "frame_results") <= above and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.02)
        assert proc.poll() is None, "the import ended before it could be stopped"
        sent = time.monotonic()
        os.killpg(proc.pid, sig)
        _, err = proc.communicate(timeout=30)
        return " ".join(err.split()), time.monotonic() - sent
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)


def test_an_import_stopped_or_killed_while_it_analyses_is_finished_by_the_same_import_again(
    tmp_path: Path,
) -> None:
    folder, data = tmp_path / "set", tmp_path / "data"
    n = Station(seed=4, duration_s=400.0).write(folder, START)
    db = data / "camcal.db"

    # SIGTERM (`kill`, systemd) as Ctrl-C: it stops at once, keeps what it analysed, says what to do
    proc = start_import(folder, data)
    pace = Pace()  # "at once": seconds of an idle machine, stretched by how busy this one is
    said, took_s = stop_when_results_pass(proc, db, 0, signal.SIGTERM)
    first = count(db, "frame_results")
    assert proc.returncode == 130 and took_s < pace.bound(5), (proc.returncode, took_s, str(pace), said)
    assert "stopped:" in said and "the same import again takes the rest" in said, said
    assert count(db, "frames") == n and 0 < first < n, (first, n)

    # SIGKILL (the OOM killer): nothing to say, but what it stored stays
    said, _ = stop_when_results_pass(start_import(folder, data), db, first, signal.SIGKILL)
    kept = count(db, "frame_results")
    assert first < kept < n, (first, kept, n)

    res = camcal_cli("import", str(folder), "--data", str(data), timeout=300)
    said = " ".join((res.stdout + res.stderr).split())
    assert res.returncode == 0, said
    assert f"0 frames imported, {n} already present" in said and f"{n - kept} analysed" in said, said
    assert count(db, "frame_results") == n
    assert count(db, "attenuation_points") >= 3, said
    again = camcal_cli("import", str(folder), "--data", str(data))
    assert "0 analysed" in " ".join(again.stdout.split()), again.stdout  # nothing left to do
