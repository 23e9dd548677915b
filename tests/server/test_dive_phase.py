"""The dive phase the live view shows: test stops and the station told apart."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from camcal.core.events import Event, EventKind
from ingest.derived import dive_phase
from server.relay import LiveHub
from storage.store import Store


def trex_depths(t_s: np.ndarray) -> np.ndarray:
    """A T-REX-like dive at 1 m/s: 15-minute test stops at 1200 and 2021 m, 30 min on station at 3420 m."""
    legs = [(0, 0), (1200, 1200), (2100, 1200), (2921, 2021), (3821, 2021), (5220, 3420), (7020, 3420)]
    legs += [(8419, 2021), (9319, 2021), (10140, 1200), (11040, 1200), (12240, 0)]
    return np.interp(t_s, [t for t, _ in legs], [d for _, d in legs])


def hub_phases(tmp_path: Path, station_depth_m: float | None, at_s: list[float]) -> list[str | None]:
    """The phases a live hub shows at the given times of the dive, fed one sensor event a second."""
    store = Store.open(tmp_path / "data")
    hub = LiveHub(store, None, station_depth_m=station_depth_m)
    out = []
    t0 = 1.7e9
    for t in np.arange(0.0, max(at_s) + 1, 1.0):
        hub.deliver(Event(EventKind.SENSORS, {"t_unix_s": t0 + t, "depth_m": trex_depths(t)}, t0 + t, "A"))
        if t in at_s:
            out.append(hub.phase("A"))
    store.close()
    return out


MOMENTS = {  # time (s) -> what a deck crew should see
    600.0: "descent",
    2000.0: "stop",  # 13 min into the 1200 m test stop
    3700.0: "stop",  # 2021 m test stop
    6500.0: "station",
    8000.0: "ascent",
    9200.0: "stop",  # 2021 m again, on the way up, 13 min in
    10900.0: "stop",
    12239.0: "deck",
}


def test_with_the_dive_plan_every_stop_and_the_station_are_named_right(tmp_path: Path) -> None:
    assert hub_phases(tmp_path, 3420.0, list(MOMENTS)) == list(MOMENTS.values())


def test_without_a_plan_only_stops_on_the_way_down_can_pass_for_the_station(tmp_path: Path) -> None:
    got = dict(zip(MOMENTS, hub_phases(tmp_path, None, list(MOMENTS)), strict=True))
    # the deepest stop so far: on the way down nobody can know it is not the station
    assert got.pop(2000.0) == got.pop(3700.0) == "station"
    # on the way up the hub remembers the station depth, though its recent samples no longer hold it
    assert got == {t: p for t, p in MOMENTS.items() if t in got}


@pytest.mark.parametrize(
    ("depths", "plan", "phase"),
    [
        ([3.0, 3.0, 3.0], None, "deck"),
        ([100.0, 110.0, 120.0], None, "descent"),
        ([3400.0, 3400.0, 3400.0], 3420.0, "station"),
        ([3370.0, 3370.0, 3370.0], 3420.0, "station"),
        ([3300.0, 3300.0, 3300.0], 3420.0, "stop"),
        ([3500.0, 3500.0, 3500.0], 3420.0, "stop"),
    ],
)
def test_phase_from_the_last_samples(depths: list[float], plan: float | None, phase: str) -> None:
    assert dive_phase([0.0, 10.0, 20.0], depths, None, plan) == phase
