"""A data folder filled by a real simulated dive: both modules through the live path, sped up."""

from __future__ import annotations

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


def run_simulated_dive(data: Path, *, station_s: float = 240.0, seed: int = 5) -> dict[str, object]:
    """Stream a short simulated dive into ``data`` and wait until everything is stored and analysed."""
    profile = DiveProfile(
        deck_s=5.0, descent_m_per_s=80.0, test_stop_s=40.0, station_s=station_s, ascent_m_per_s=80.0
    )
    start_real = time.time() + 1.0
    start = datetime.fromtimestamp(start_real, UTC)
    sim = DiveSimulation(
        profile,
        LEMTimetable(dwell_s=20.0),
        WaterColumn.with_station_drift(profile, 0.04),
        seed=seed,
        frame_scale=0.25,
        start=start,
    )
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
    return {"sim": sim, "frames": {a.config.module: a.counters["frames_captured"] for a in agents}}


def copy_data(src: Path, dst: Path) -> Path:
    """A copy of a data folder (database with its WAL, frame files) to change without touching ``src``."""
    shutil.copytree(src, dst)
    return dst
