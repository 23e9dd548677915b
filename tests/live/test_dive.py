"""A whole simulated dive of both modules through the live path, sped up."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
from sqlalchemy import func, select

from camcal.core.schedule import Schedule
from ingest.service import IngestService
from lrm.agent import AgentConfig
from lrm.clock import SimClock
from lrm.dive import DiveProfile, DiveSimulation, LEMTimetable, WaterColumn
from lrm.simmodule import simulated_module
from storage.models import AttenuationPoint, AttitudeSample, Frame, FrameResult
from tests.live.conftest import ingest_config
from tests.live.test_ingest import wait_for

pytestmark = pytest.mark.solo  # a whole dive in real time: after the rest, beside the browser tests

SPEED = 15.0


@pytest.mark.slow
def test_simulated_dive_everything_stored_once_and_lambda_att_tracks_the_water(tmp_path: Path) -> None:
    profile = DiveProfile(
        deck_s=5.0, descent_m_per_s=60.0, test_stop_s=60.0, station_s=420.0, ascent_m_per_s=60.0
    )
    start_real = time.time() + 1.0
    from datetime import UTC, datetime

    start = datetime.fromtimestamp(start_real, UTC)
    sim = DiveSimulation(
        profile,
        LEMTimetable(dwell_s=20.0),
        WaterColumn.with_station_drift(profile, 0.04),
        seed=3,
        frame_scale=0.25,
        start=start,
    )
    svc = IngestService(ingest_config(tmp_path / "data", workers=2))
    svc.start()
    schedule = Schedule(name="dive-test", exposures_s=(0.05, 0.07, 0.11), gains_db=(6.0,), repeats=3)
    agents = []
    for m in ("A", "B"):
        clock = SimClock.synced(start, SPEED, start_real)
        agent = simulated_module(
            sim,
            AgentConfig(
                module=m,
                connect=svc.endpoint,
                outbox=tmp_path / f"ob-{m}",
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
        real_duration = profile.duration_s / SPEED + 2.0
        time.sleep(real_duration)
        for a in agents:
            a.stop_producing()  # the sensors too: they send a batch every simulated second
        assert all(a.wait_drained(30) for a in agents)
        with svc.store.read() as s:
            n = s.scalar(select(func.count(Frame.id)))
        assert wait_for(lambda: _count(svc, FrameResult) == n, 60)
    finally:
        for a in agents:
            a.stop()
        svc.stop()
    from storage.store import Store

    store = Store.open(tmp_path / "data", run_migrations=False)
    with store.read() as s:
        for a in agents:
            keys = s.execute(select(Frame.boot, Frame.seq).where(Frame.module_id == a.config.module)).all()
            assert len(keys) == len(set(keys)) == a.counters["frames_captured"] > 20
        phases = {
            sim.profile.phase_at(sim.dive_time_s(datetime.fromtimestamp(t, UTC)))
            for (t,) in s.execute(select(Frame.captured_unix_s))
        }
        assert {"test-1200", "test-2021", "station"} <= phases
        points = list(s.scalars(select(AttenuationPoint).order_by(AttenuationPoint.t_unix_s)))
        tilts = s.scalar(select(func.count(AttitudeSample.id)))
    assert tilts > 10
    on_station = [p for p in points if p.depth_m and p.depth_m > 3300]
    assert {p.wavelength_nm for p in on_station} == {405, 460, 525}
    for p in on_station:
        t_s = sim.dive_time_s(datetime.fromtimestamp(p.t_unix_s, UTC))
        truth = sim.lambda_att_pair_truth_m(p.wavelength_nm, t_s)
        assert p.lambda_att_m == pytest.approx(truth, rel=0.04), (p.wavelength_nm, p.lambda_att_m, truth)
    store.close()


def _count(svc: IngestService, model) -> int:
    with svc.store.read() as s:
        return int(s.scalar(select(func.count(model.id))))
