"""One clock per dive: simulated modules at 10x through the live path, their link cut for a while.

Seen on deck: the simulated modules' times ran 10x fast while alarms, commands and the audit log
kept the ship's clock, so the review timeline and the report drew module B's link loss (on the
ascent) during the first descent, and the export had frames `received` before `captured`. Now each
module's clock is mapped onto the ship's at the handshake and every heartbeat, frames, samples and
λ_att points carry the ship's time beside their own, and the timeline draws them all on it.
"""

from __future__ import annotations

import csv
import time
from datetime import UTC, datetime
from pathlib import Path

from sqlalchemy import select

from camcal.core.schedule import Schedule
from ingest.service import IngestService
from lrm.agent import AgentConfig
from lrm.clock import SimClock
from lrm.dive import DiveProfile, DiveSimulation, LEMTimetable, WaterColumn
from lrm.simmodule import simulated_module
from storage import queries
from storage.export import export_dive
from storage.models import Alarm, Frame
from tests.live.conftest import ingest_config
from tests.utils.live import TcpProxy, wait_for

SPEED = 10.0
CUT_S = 6.0  # seconds of the ship's clock the fibre to module B is cut


def test_a_simulated_dive_and_its_outage_lie_on_the_ships_clock(tmp_path: Path) -> None:
    profile = DiveProfile(deck_s=1.0, descent_m_per_s=400.0, test_stop_s=10.0, station_s=400.0)
    start_real = time.time() + 1.0
    start = datetime.fromtimestamp(start_real, UTC)
    sim = DiveSimulation(profile, LEMTimetable(dwell_s=20.0), WaterColumn.with_station_drift(profile, 0.0),
                         seed=2, frame_scale=0.25, start=start)  # fmt: skip
    svc = IngestService(ingest_config(tmp_path / "data", workers=1))
    svc.start()
    proxy = TcpProxy(int(svc.endpoint.rsplit(":", 1)[1]))
    schedule = Schedule(name="clock-test", exposures_s=(0.05, 0.07), gains_db=(6.0,), repeats=2)
    agents = {}
    for m, endpoint in (("A", svc.endpoint), ("B", proxy.endpoint)):
        config = AgentConfig(module=m, connect=endpoint, outbox=tmp_path / f"ob-{m}", fsync=False,
                             sensor_rate_hz=2.0, plaintext=True, link_timeout_s=2.0)  # fmt: skip
        agents[m] = simulated_module(sim, config, SimClock.synced(start, SPEED, start_real), schedule)
        agents[m].start()
    try:
        assert wait_for(lambda: _frames(svc, "B") >= 4, 60)
        proxy.cut()
        cut_at = time.time()
        time.sleep(CUT_S)
        proxy.restore()
        restored_at = time.time()
        n = _frames(svc, "B")
        assert wait_for(lambda: _frames(svc, "B") >= n + 6, 60), "B's frames from its card did not come"
        assert wait_for(lambda: _alarm(svc) is not None and _alarm(svc).cleared_unix_s is not None, 30)
        for a in agents.values():
            a.stop_producing()
        assert all(a.wait_drained(30) for a in agents.values())
    finally:
        for a in agents.values():
            a.stop()
        proxy.close()
        svc.stop()

    alarm = _alarm(svc)
    assert alarm is not None and cut_at <= alarm.raised_unix_s <= restored_at + 1.0
    with svc.store.read() as s:
        dive_id = queries.dives(s)[0]["id"]
        timeline = queries.timeline(s, dive_id, 5000)
        rows = s.execute(
            select(Frame.module_id, Frame.captured_unix_s, Frame.captured_ship_unix_s, Frame.received_unix_s)
        ).all()
        points = [
            p for pts in queries.attenuation_series(s, queries.live_run_id(s, dive_id)).values() for p in pts
        ]
    # The module's clock ran 10x: its own times lie far ahead of the ship's; mapped, each frame was
    # taken before it arrived, and not long before (B's waited on its card for the outage at most).
    assert max(c - r for _, c, _, r in rows) > 30, "the simulated clock did not run ahead"
    lags = [r - ship for _, _, ship, r in rows]
    assert min(lags) > -0.5 and max(lags) < CUT_S + 20, (min(lags), max(lags))
    # B's frames taken during the outage (sent from its card afterwards) are drawn during the outage,
    # between the alarm's raising (a link lost 2 s before it is said) and its clearing.
    during = [f for f in timeline["frames"] if f["module"] == "B" and cut_at < f["t_unix_s"] < restored_at]
    assert during, "no frame of B drawn while its link was cut: the outage is drawn elsewhere"
    late = {r[2] for r in rows if r[0] == "B" and cut_at < r[2] < restored_at}
    assert all(r[3] >= restored_at - 0.5 for r in rows if r[0] == "B" and r[2] in late)
    # Every time of the timeline is the ship's: the dive's frames span what the ship saw of it.
    ts = [f["t_unix_s"] for f in timeline["frames"]]
    assert min(ts) >= start_real - 1 and max(ts) <= max(r[3] for r in rows) + 0.5
    depth_t = [t for d in timeline["depth_by_module"].values() for t in d["t_unix_s"]]
    assert depth_t and max(depth_t) <= max(r[3] for r in rows) + 2.0
    assert all(min(r[3] for r in rows) - 60 <= p["t_ship_unix_s"] <= max(r[3] for r in rows) for p in points)
    clocks = {c["module"]: c for c in timeline["clocks"]}
    assert set(clocks) == {"A", "B"} and all(c["rate"] == SPEED for c in clocks.values())
    assert all(c["offset_s"] is not None and abs(c["offset_s"]) < 5 for c in clocks.values()), clocks
    # The export: captured (ship's clock) before received, in the order they were taken.
    (frames_csv,) = [
        f for f in export_dive(svc.store, dive_id, tmp_path / "out", ("csv",)) if f.stem == "frames"
    ]
    with frames_csv.open() as fh:
        exported = list(csv.DictReader(fh))
    ship = [float(r["captured_ship_unix_s"]) for r in exported]
    assert ship == sorted(ship) and all(float(r["received_unix_s"]) >= float(r["captured_ship_unix_s"]) - 0.5
                                        for r in exported)  # fmt: skip


def _frames(svc: IngestService, module: str) -> int:
    with svc.store.read() as s:
        return len(s.scalars(select(Frame.id).where(Frame.module_id == module)).all())


def _alarm(svc: IngestService) -> Alarm | None:
    with svc.store.read() as s:
        return s.scalars(select(Alarm).where(Alarm.kind == "link_lost", Alarm.module_id == "B")).first()
