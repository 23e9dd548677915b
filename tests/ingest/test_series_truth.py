"""The per-visit series against the simulator's truth on a drifting station, in memory.

Frames rendered by the dive simulation (T-REX geometry and emission ratios,
the small sensor, module motion) while λ_att of every wavelength falls by
30 % and comes back, analysed frame by frame and cut into visits as the
live ingest does. The pulls (λ - truth) / stat_err must have an RMS between
0.8 and 1.25: the errors mean what they say. Another seed, block length and
number of frames per setting than the floors were measured with
(``bench/repeatability.py``: seeds 101 and 102, 75 s blocks, 5 frames).

Fifteen visits per wavelength pin a pull RMS down to ~±18 %, too loosely
for the 0.8-1.25 band of each wavelength alone: here the band holds for all
points together and each wavelength must stay within 0.5-1.6;
``bench/repeatability.py`` checks each wavelength in the band with 30
visits on two more seeds (figures in the README).
"""

from __future__ import annotations

import math

import pytest

from camcal.core.frameset import Setup
from ingest.rolling import Sample, VisitSeries
from lrm.dive import DiveProfile, DiveSimulation, LEMTimetable, WaterColumn
from lrm.dive.station import station_results
from tests.utils.series_check import check_series


@pytest.mark.slow
def test_pulls_on_a_drifting_station_have_an_rms_near_one() -> None:
    profile = DiveProfile(
        deck_s=5.0, descent_m_per_s=100.0, test_stop_s=30.0, station_s=45 * 60.0, ascent_m_per_s=100.0
    )
    sim = DiveSimulation(
        profile,
        LEMTimetable(dwell_s=60.0),
        WaterColumn.with_station_bump(profile, 0.3),
        seed=13,
        frame_scale=0.25,
    )
    series = VisitSeries(Setup())
    t0, t1 = profile.window("station")
    settings = ((0.05, 8.0), (0.07, 8.0), (0.11, 8.0))
    for rows in station_results(sim, settings, 3, t_from_s=t0, t_to_s=t1):
        series.add(Sample.from_result(r) for r in rows)
    series.close_all()
    epoch = sim.start.timestamp()
    check = check_series(series.points(), lambda wl, t: sim.lambda_att_pair_truth_m(wl, t - epoch))
    print("\n" + check.table())
    assert set(check.per_wavelength) == {405, 460, 525}
    figures = check.per_wavelength.values()
    pooled = math.sqrt(sum(f.n * f.pull_rms**2 for f in figures) / sum(f.n for f in figures))
    assert 0.8 <= pooled <= 1.25, pooled
    for wl, f in check.per_wavelength.items():
        assert f.n >= 14, wl
        assert 0.5 <= f.pull_rms <= 1.6, (wl, f)
        assert f.rms_rel_dev <= 0.01, (wl, f)
