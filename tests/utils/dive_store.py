"""A data folder filled by a real simulated dive: both modules through the live path, sped up."""

from __future__ import annotations

import fcntl
import os
import pickle
import shutil
import time
from datetime import UTC, datetime
from pathlib import Path

from camcal.core.schedule import Schedule
from ingest.alarms import AlarmLimits
from ingest.service import IngestConfig, IngestService
from lrm.agent import AgentConfig
from lrm.clock import SimClock
from lrm.dive import DiveProfile, DiveSimulation, LEMTimetable, WaterColumn
from lrm.simmodule import simulated_module

SPEED = 10.0


def dive_simulation(start: datetime, *, station_s: float = 240.0, seed: int = 5) -> DiveSimulation:
    """The short dive `run_simulated_dive` streams: the same for the same arguments."""
    profile = DiveProfile(
        deck_s=5.0, descent_m_per_s=80.0, test_stop_s=40.0, station_s=station_s, ascent_m_per_s=80.0
    )
    return DiveSimulation(
        profile,
        LEMTimetable(dwell_s=20.0),
        WaterColumn.with_station_drift(profile, 0.04),
        seed=seed,
        frame_scale=0.25,
        start=start,
    )


def run_simulated_dive(data: Path, *, station_s: float = 240.0, seed: int = 5) -> dict[str, object]:
    """Stream a short simulated dive into ``data`` and wait until everything is stored and analysed."""
    start_real = time.time() + 1.0
    start = datetime.fromtimestamp(start_real, UTC)
    sim = dive_simulation(start, station_s=station_s, seed=seed)
    profile = sim.profile
    svc = IngestService(
        IngestConfig(
            data_dir=data,
            bind="tcp://127.0.0.1:*",
            events_bind=None,
            workers=2,
            sqlite_synchronous="NORMAL",
            alarm_limits=AlarmLimits(link_timeout_s=3.0),
            plaintext=True,
        )
    )
    svc.start()
    schedule = Schedule(
        name="review-test", exposures_s=(0.02, 0.05, 0.07, 0.11, 0.2), gains_db=(6.0,), repeats=2
    )
    agents = []
    for m in ("A", "B"):
        clock = SimClock.synced(start, SPEED, start_real)
        agent = simulated_module(
            sim,
            AgentConfig(
                module=m,
                connect=svc.endpoint,
                outbox=data.parent / f"outbox-{m}",
                fsync=False,
                # 2 Hz of simulated time is 40 Hz real at this speed: enough for attitude and the
                # heave period, and it leaves the CPU (and the GIL of this one process) to the frames.
                sensor_rate_hz=2.0,
                plaintext=True,
            ),
            clock,
            schedule,
        )
        agent.start()
        agents.append(agent)
    try:
        time.sleep(profile.duration_s / SPEED + 1.5)
        for a in agents:
            a.stop_producing()
        for a in agents:
            a.wait_drained(30)
        end = time.monotonic() + 60
        while time.monotonic() < end and (
            svc.health()["queues"]["analysis_backlog"] or svc.health()["queues"]["analysis_in_flight"]
        ):
            time.sleep(0.2)
        time.sleep(1.5)  # one more tick: linearity, attitude, alarms
    finally:
        for a in agents:
            a.stop()
        svc.stop()
    frames = {a.config.module: a.counters["frames_captured"] for a in agents}
    return {"sim": sim, "frames": frames, "start": start, "station_s": station_s, "seed": seed}


def shared_simulated_dive(session_tmp: Path) -> tuple[Path, dict[str, object]]:
    """The dive of `run_simulated_dive`, streamed once and shared read-only by everyone who asks.

    Shared by the pytest-xdist workers of one run (their temp folders' parent) and, when
    ``CAMCAL_TEST_CACHE`` names a folder (``make test`` sets a fresh one), by every pytest run
    that sees the same folder. A file lock makes the others wait while the first one streams it;
    ``info.pickle`` is written last, so a dive cut short by a crash is streamed again.
    """
    cache = os.environ.get("CAMCAL_TEST_CACHE")
    if cache:
        root = Path(cache)
    elif os.environ.get("PYTEST_XDIST_WORKER"):
        root = session_tmp.parent  # the run's folder, above each worker's own
    else:
        root = session_tmp
    folder = root / "shared-dive"
    root.mkdir(parents=True, exist_ok=True)
    with (root / "shared-dive.lock").open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        done = folder / "info.pickle"
        if not done.exists():
            shutil.rmtree(folder, ignore_errors=True)
            info = run_simulated_dive(folder / "data")
            done.write_bytes(pickle.dumps({k: v for k, v in info.items() if k != "sim"}))
        info = pickle.loads(done.read_bytes())
    info["sim"] = dive_simulation(info["start"], station_s=info["station_s"], seed=info["seed"])
    return folder / "data", info


def copy_data(src: Path, dst: Path) -> Path:
    """A copy of a data folder (database with its WAL, frame files) to change without touching ``src``."""
    shutil.copytree(src, dst)
    return dst
