"""A module whose runs of shots outlast the LEM's colour says so: its heartbeat's `deferred_shots`.

A real agent (simulated camera, the only stand-in) runs a schedule of twenty shots at 460 nm against
a LEM that shows each colour 0.4 s; its runner takes what a turn leaves at the next (`lrm.runner`),
and the count reaches the ship over a real socket in the heartbeat, the ingest's health, and the
control page (which reads it there).
"""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path

from camcal.core.schedule import Schedule
from ingest.service import IngestService
from lrm.dive.profile import LEMTimetable
from lrm.runner import LemTimetableClock
from tests.live.conftest import ingest_config
from tests.live.test_ingest import wait_for
from tests.utils.live import make_agent


def test_the_shots_a_turn_left_are_counted_in_the_heartbeat(tmp_path: Path) -> None:
    svc = IngestService(ingest_config(tmp_path / "data"))
    svc.start()
    lem = LemTimetableClock(LEMTimetable(dwell_s=0.4), datetime.now(UTC))
    long_runs = Schedule(
        name="long-runs", exposures_s=(0.001,), gains_db=(6.0,), repeats=20, wavelengths_nm=(460,)
    )
    agent, _ = make_agent("A", svc.endpoint, tmp_path / "outbox", schedule=long_runs, lem=lem)
    agent.start()
    try:

        def deferred() -> int:
            return int((svc.health()["modules"].get("A") or {}).get("deferred_shots") or 0)

        assert wait_for(lambda: deferred() > 0, 30), svc.health()["modules"]
        assert 0 < deferred() <= agent.runner.deferred_shots  # the heartbeat lags the runner by < 1 s
    finally:
        agent.stop()
        svc.stop()
