"""A re-analysis whose process stops never reads as running forever.

Before, a re-analysis under way when its server stopped (Ctrl-C, `docker stop`, a kill) or when
`camcal reanalyze` was killed stayed ``running`` (and those waiting ``queued``) for ever: the
review page polled it without end. Now a stopping server asks the running one to stop after its
batch (``interrupted``) and cancels those waiting; a run whose process was killed stops beating
and reads as ``interrupted`` (with what to do) within `RUN_STALE_S`, or at once when it ran on
this host, and the next server marks it so. Real ``camcal serve`` and ``camcal reanalyze``
processes, real signals, real SQLite files; the in-process test slows the batches (the one
stand-in) to stop a run surely in its middle.
"""

from __future__ import annotations

import signal
import socket
import sqlite3
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from camcal.core.frameset import Setup
from ingest.reanalysis import ReanalysisOptions, reanalyse, start_run
from ingest.runners import LocalRunner
from server.jobs import ReanalysisQueue
from storage import queries
from storage.queries.runs import RUN_STALE_S
from storage.store import Store
from tests.utils.dive_store import copy_data
from tests.utils.pace import Pace
from tests.utils.runs import OPERATOR_ENV as ENV
from tests.utils.runs import runs_in_file, start_three
from tests.utils.system import REPO, camcal_serve, wait_until


@pytest.fixture
def data(dive_data, tmp_path: Path) -> Iterator[Path]:
    yield copy_data(dive_data[0], tmp_path / "data")


def test_a_killed_server_leaves_runs_that_the_next_one_marks_interrupted(data: Path) -> None:
    with camcal_serve(data, env=ENV) as (url, proc):
        dive, ids = start_three(url)
        proc.send_signal(signal.SIGKILL)  # nothing of it can end a run now
        proc.wait(10)
    left = {i: s for i, (_, s) in runs_in_file(data).items() if i in ids}
    assert "queued" in left.values(), left  # the last one surely waited: each takes ~1 s or more
    with camcal_serve(data, env=ENV) as (url, _):
        runs = {r["id"]: r for r in httpx.get(f"{url}/api/dives/{dive}/runs").json()}
    statuses = {i: runs[i]["status"] for i in ids}
    assert set(statuses.values()) <= {"done", "interrupted"}, statuses
    stopped = [runs[i] for i in ids if runs[i]["status"] == "interrupted"]
    assert stopped and all("start it again" in r["note"] for r in stopped)
    assert all(runs_in_file(data)[r["id"]][1] == "interrupted" for r in stopped)  # kept, not only shown
    log = "".join(p.read_text() for p in data.parent.glob("serve-*.log"))
    assert "marked interrupted; start it again" in log


def test_a_stopped_server_ends_every_run_it_held(data: Path) -> None:
    with camcal_serve(data, env=ENV) as (url, proc):
        _, ids = start_three(url)
        pace = Pace()
        t0 = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(pace.bound(30)) == 0
        stop_s = time.monotonic() - t0
    statuses = {i: s for i, (_, s) in runs_in_file(data).items() if i in ids}
    # Read from the file before any other server could mend it: the stopping server ended them all.
    assert set(statuses.values()) <= {"done", "interrupted", "cancelled"}, statuses
    assert statuses[ids[-1]] == "cancelled"
    assert stop_s < ReanalysisQueue.STOP_WAIT_S + pace.bound(5), (stop_s, str(pace))


class SlowRunner(LocalRunner):
    """Batches analysed in this process as the server's runner does, each made to take 0.2 s."""

    def map(self, fn: Any, batches: Any, **kwargs: Any) -> Iterator[Any]:
        for out in super().map(fn, batches, **kwargs):
            time.sleep(0.2)
            yield out


def test_a_stopping_queue_interrupts_its_run_after_the_batch_it_stores(data: Path) -> None:
    store = Store.open(data)
    try:
        dive_id = store.call(queries.dives)[0]["id"]
        setup = Setup.model_validate({**Setup().model_dump(), "linear_range": (15.0, 229.0)})
        run_id = start_run(store, dive_id, setup, "slow")
        queue = ReanalysisQueue(store, 4)
        # small batches: the stop comes with most of the dive still to do, however few frames a
        # dive streamed on a busy machine holds (19 beside two CPU-bound jobs)
        options = ReanalysisOptions(batch_size=2)
        queue.submit(
            run_id,
            lambda cancel: reanalyse(
                store, dive_id, run_id, setup, options, runner=SlowRunner(1), cancel=cancel
            ),
        )

        def under_way() -> bool:
            return next(r for r in store.call(queries.runs, dive_id) if r["id"] == run_id)["n_frames"] >= 4

        wait_until(under_way, 60, "the run to store two batches", every_s=0.02)
        queue.stop()
        run = next(r for r in store.call(queries.runs, dive_id) if r["id"] == run_id)
        total = store.call(queries.dives)[0]["n_frames"]
        assert run["status"] == "interrupted" and "start it again" in run["note"]
        assert 4 <= run["n_frames"] < total  # what it stored is kept, and it stopped well before the end
    finally:
        store.close()


def test_a_run_nobody_beats_reads_as_interrupted_and_one_that_beats_does_not(data: Path) -> None:
    store = Store.open(data)
    try:
        dive_id = store.call(queries.dives)[0]["id"]
        run_id = start_run(store, dive_id, Setup(), "held elsewhere")

        def status() -> dict[str, Any]:
            return next(r for r in store.call(queries.runs, dive_id) if r["id"] == run_id)

        assert status()["status"] == "running" and status()["note"] is None
        with sqlite3.connect(data / "camcal.db") as db:  # its process went silent RUN_STALE_S + 1 s ago
            db.execute(
                "UPDATE analysis_runs SET heartbeat_unix_s = ? WHERE id = ?",
                (time.time() - RUN_STALE_S - 1, run_id),
            )
        assert status()["status"] == "interrupted" and "start it again" in status()["note"]
        store.beat_runs([run_id])  # it speaks again (a machine that was only slow)
        assert status()["status"] == "running"
        assert store.interrupt_stale_runs() == []  # a starting server leaves a beating run alone
        ended = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True)
        with sqlite3.connect(
            data / "camcal.db"
        ) as db:  # beaten a moment ago by a process of this host now gone
            db.execute(
                "UPDATE analysis_runs SET owner = ? WHERE id = ?",
                (f"{socket.gethostname()}:{int(ended.stdout)}:12345", run_id),
            )
        assert status()["status"] == "interrupted"
        assert [r["id"] for r in store.interrupt_stale_runs()] == [run_id]
        assert runs_in_file(data)[run_id][1] == "interrupted"
    finally:
        store.close()


def test_camcal_reanalyze_stopped_by_sigterm_says_so_and_marks_its_run(data: Path) -> None:
    with sqlite3.connect(data / "camcal.db") as db:
        name = db.execute("SELECT name FROM dives").fetchone()[0]
    before = set(runs_in_file(data))
    args = [sys.executable, "-c", "from camcal.cli import main; main()", "reanalyze", "--dive", name]
    args += ["--data", str(data), "--linear-range", "15,229", "--workers", "1"]
    env = {"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin", "COLUMNS": "200"}
    proc = subprocess.Popen(args, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        wait_until(lambda: set(runs_in_file(data)) - before, 60, "the re-analysis run to start", every_s=0.02)
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    (run_id,) = set(runs_in_file(data)) - before
    assert proc.returncode == 130, (out, err)
    assert f"interrupted (run {run_id}, marked interrupted)" in " ".join(err.split())
    assert runs_in_file(data)[run_id][1] == "interrupted"
