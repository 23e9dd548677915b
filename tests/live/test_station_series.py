"""A drifting station streamed from two `camcal lrm simulate` modules into a real `camcal ingest`.

The water's λ_att falls by 30 % over the 90 minutes on station and comes
back; the LEM shows each wavelength for 60 s; module B shoots 0.45 s after
module A (interleaved frames); three exposures at 8 dB, twice each per
visit; test stops of 400 s at 1200 and 2021 m on the way down; 100x speed. The stored series,
exported with `camcal export`, is compared with the simulator's truth at
each point's time (`tests.utils.series_check`), and `camcal reanalyze`
must give the identical series from the same frames. Everything runs as
real processes over TCP into a real SQLite file; only the cameras are
simulated.
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq
import pytest
from sqlalchemy import func, select

from camcal.core.schedule import Schedule
from lrm.dive import DiveProfile, DiveSimulation, LEMTimetable, WaterColumn
from storage.models import AttenuationPoint, Frame, FrameResult
from storage.store import Store
from tests.utils.live import camcal_cli, cli_env, link_keys
from tests.utils.series_check import check_series
from tests.utils.system import free_ports

pytestmark = pytest.mark.solo  # a 90-minute station at 100x: after the rest, beside the browser tests

SPEED = 100.0
DIVE = dict(deck_s=5.0, winch_m_per_s=100.0, test_stop_s=400.0, station_s=5400.0)
DWELL_S = 60.0
DROP = 0.3
SEED = 21
#: The quick check's exposures at one gain, twice each: six frames per camera and visit.
SCHEDULE = Schedule(name="station-test", exposures_s=(0.05, 0.07, 0.11), gains_db=(8.0,), repeats=2)


def _cli(*args: str, log: Path) -> subprocess.Popen[bytes]:
    with log.open("ab") as out:
        return subprocess.Popen(
            [sys.executable, "-c", "from camcal.cli import main; main()", *args],
            stdout=out,
            stderr=out,
            env=cli_env(),
            start_new_session=True,
        )


def _simulation(epoch: float) -> DiveSimulation:
    profile = DiveProfile(
        deck_s=DIVE["deck_s"],
        descent_m_per_s=DIVE["winch_m_per_s"],
        ascent_m_per_s=DIVE["winch_m_per_s"],
        test_stop_s=DIVE["test_stop_s"],
        station_s=DIVE["station_s"],
    )
    return DiveSimulation(
        profile,
        LEMTimetable(dwell_s=DWELL_S),
        WaterColumn.with_station_bump(profile, DROP),
        start=datetime.fromtimestamp(epoch, UTC),
    )


def _count(store: Store, model: Any) -> int:
    with store.read() as s:
        return int(s.scalar(select(func.count(model.id))))


@pytest.fixture(scope="module")
def station(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    root = tmp_path_factory.mktemp("station")
    data = root / "data"
    port, events = free_ports(2)
    keys = link_keys(data)  # the link is CURVE, as on a ship: the ship's key pair and A's and B's
    t_wall = time.monotonic()
    ingest = _cli(
        "ingest",
        "--data",
        str(data),
        "--dive",
        "drift",
        "--bind",
        f"tcp://127.0.0.1:{port}",
        "--events",
        f"tcp://127.0.0.1:{events}",
        "--workers",
        "2",
        "--no-fsync",
        log=root / "ingest.log",
    )
    schedule = root / "schedule.json"
    schedule.write_text(SCHEDULE.model_dump_json())
    epoch = time.time() + 10.0  # time for the processes to start before the dive does
    modules = {
        cam: _cli(
            "lrm",
            "simulate",
            "--camera",
            cam,
            "--connect",
            f"tcp://127.0.0.1:{port}",
            "--outbox",
            str(root / f"outbox-{cam}"),
            "--speed",
            str(SPEED),
            "--frame-scale",
            "0.25",
            "--schedule",
            str(schedule),
            "--seed",
            str(SEED),
            "--epoch",
            repr(epoch),
            "--deck-s",
            str(DIVE["deck_s"]),
            "--winch-m-per-s",
            str(DIVE["winch_m_per_s"]),
            "--test-stop-s",
            str(DIVE["test_stop_s"]),
            "--station-s",
            str(DIVE["station_s"]),
            "--drift",
            str(DROP),
            "--drift-shape",
            "bump",
            "--lem-dwell-s",
            str(DWELL_S),
            "--lem-settle-s",
            settle,
            "--sensor-rate-hz",
            "0.5",
            "--no-fsync",
            "--keys",
            str(keys),
            "--log-level",
            "warning",
            log=root / f"module-{cam}.log",
        )
        for cam, settle in (("A", "0"), ("B", "0.45"))
    }
    try:
        for cam, proc in modules.items():
            rc = proc.wait(timeout=300)
            assert rc == 0, (root / f"module-{cam}.log").read_text()[-3000:]
        store = Store.open(data, run_migrations=False)
        try:
            end = time.monotonic() + 60
            while time.monotonic() < end and _count(store, FrameResult) < _count(store, Frame):
                time.sleep(0.3)
            assert _count(store, FrameResult) == _count(store, Frame) > 0
        finally:
            store.close()
        time.sleep(1.5)  # the store thread's last batch
    finally:
        for proc in modules.values():
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
        ingest.send_signal(signal.SIGTERM)
        ingest.wait(timeout=30)
    streamed_s = time.monotonic() - t_wall
    out = root / "export"
    done = camcal_cli("export", "--data", str(data), "--out", str(out), "--dive", "drift")
    assert done.returncode == 0, done.stderr
    return {"data": data, "export": out, "epoch": epoch, "streamed_s": streamed_s, "root": root}


def test_the_streamed_series_follows_the_drifting_water_with_honest_errors(station: dict[str, Any]) -> None:
    table = pq.read_table(station["export"] / "attenuation.parquet").to_pylist()
    for column in (
        "t_unix_s",
        "t_first_unix_s",
        "t_last_unix_s",
        "depth_m",
        "n_frames",
        "stat_err_m",
        "sys_err_m",
        "final",
        "lambda_att_m",
    ):
        assert column in table[0], column
    sim = _simulation(station["epoch"])

    def truth(wl: int, t: float) -> float:
        return sim.lambda_att_pair_truth_m(wl, t - station["epoch"])

    check = check_series(table, truth)
    print(f"\nstreamed in {station['streamed_s']:.0f} s\n{check.table()}")
    assert check.passed, check.problems
    assert {405, 460, 525} <= set(check.per_wavelength)
    # The series follows the water: it spans most of the 30 % fall at each wavelength.
    for wl in (405, 460, 525):
        values = [p["lambda_att_m"] for p in table if p["wavelength_nm"] == wl and p["depth_m"] > 3400]
        assert min(values) < 0.8 * max(values), wl
    # Depth: points at both test stops and on station, stamped with the LEM's depth.
    depths = sorted({round(p["depth_m"]) for p in table})
    for stop in (1200, 2021, 3420):
        assert any(abs(d - stop) < 3 for d in depths), (stop, depths)
    # One point per visit: a point's frames all lie in one block of the LEM's timetable.
    epoch = station["epoch"]
    for p in table:
        first, last = ((p[k] - epoch) // DWELL_S for k in ("t_first_unix_s", "t_last_unix_s"))
        assert first == last, p
    on_station = [p for p in table if p["depth_m"] > 3400]
    blocks = {(p["wavelength_nm"], (p["t_unix_s"] - epoch) // DWELL_S) for p in on_station}
    assert len(blocks) >= 0.9 * len(on_station)  # a module lagging a loaded machine may split a few
    # Every visit but the last of each wavelength is final.
    assert sum(not p["final"] for p in table) <= 3
    assert min(p["n_frames"] for p in table) >= 2


def test_the_check_fails_a_constant_series_and_errors_halved_or_doubled(station: dict[str, Any]) -> None:
    table = pq.read_table(station["export"] / "attenuation.parquet").to_pylist()
    sim = _simulation(station["epoch"])
    epoch = station["epoch"]

    def truth(wl: int, t: float) -> float:
        return sim.lambda_att_pair_truth_m(wl, t - epoch)

    means = {
        wl: sum(p["lambda_att_m"] for p in table if p["wavelength_nm"] == wl)
        / sum(p["wavelength_nm"] == wl for p in table)
        for wl in {p["wavelength_nm"] for p in table}
    }
    constant = [{**p, "lambda_att_m": means[p["wavelength_nm"]]} for p in table]
    halved = [{**p, "stat_err_m": p["stat_err_m"] / 2} for p in table]
    assert not check_series(constant, truth).passed
    doubled = [{**p, "stat_err_m": p["stat_err_m"] * 2} for p in table]
    assert not check_series(halved, truth).passed
    assert not check_series(doubled, truth).passed


def test_reanalyze_gives_the_identical_series_from_the_same_frames(station: dict[str, Any]) -> None:
    data = station["data"]
    done = camcal_cli("reanalyze", "--dive", "drift", "--data", str(data), "--workers", "1", timeout=180)
    assert done.returncode == 0, done.stderr
    store = Store.open(data, run_migrations=False)
    try:
        with store.read() as s:
            runs = sorted({r for (r,) in s.execute(select(AttenuationPoint.run_id))})
            assert len(runs) == 2
            series = [
                {
                    p.visit_key: (
                        p.wavelength_nm,
                        p.t_unix_s,
                        p.depth_m,
                        p.lambda_att_m,
                        p.stat_err_m,
                        p.sys_err_m,
                    )
                    for p in s.scalars(select(AttenuationPoint).where(AttenuationPoint.run_id == r))
                }
                for r in runs
            ]
    finally:
        store.close()
    live, again = series
    assert set(live) == set(again) and len(live) > 30
    for key, values in live.items():
        for a, b in zip(values, again[key], strict=True):
            assert a == b or (isinstance(a, float) and math.isclose(a, b, rel_tol=1e-12)), (
                key,
                values,
                again[key],
            )
