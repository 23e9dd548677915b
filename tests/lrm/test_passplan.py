"""The ship's estimate of a pass (`camcal.core.passplan`) against the real schedule runner.

The runner (`lrm.runner.ScheduleRunner`) runs on a virtual clock with a camera
that takes exposure + readout and a LEM cycling its colours; the estimate walks
the same rules on its own. Both must agree on how long a pass takes and over
how many of the LEM's turns each colour's shots are spread.
"""

from __future__ import annotations

import threading

import pytest

from camcal.core.passplan import _PASSES, _PHASES, _Walk, plan_pass
from camcal.core.schedule import Block, Schedule, presets
from lrm.runner import ScheduleRunner
from tests.lrm.virtual import CyclingLem, FakeCamera, VirtualClock

READOUT_S = 0.8


def runner_shots(schedule: Schedule, dwell_s: float, t0: float, n: int) -> list[tuple[float, int, float]]:
    """The real runner's first ``n`` shots from t0, as (start, wavelength, exposure + readout)."""
    clock = VirtualClock()
    clock.t = t0
    cam = FakeCamera(clock, readout_s=READOUT_S)
    runner = ScheduleRunner(cam, clock, schedule, lem=CyclingLem(dwell_s))
    stop = threading.Event()
    caps = [runner.next_capture(stop) for _ in range(n)]
    return [(t, c.wavelength_nm, e + READOUT_S) for c, (t, e, _) in zip(caps, cam.taken, strict=True) if c]


SCHEDULES = {
    "fits the dwell": Schedule(exposures_s=(0.05, 0.2), gains_db=(6.0,), repeats=3),
    "twice the dwell": Schedule(exposures_s=(0.05, 0.2, 1.0), gains_db=(2.0, 8.0), repeats=4),
    "one colour": Schedule(exposures_s=(0.1, 0.5), gains_db=(6.0,), repeats=8, wavelengths_nm=(460,)),
    "setting order": Schedule(exposures_s=(0.05, 0.5), gains_db=(6.0,), repeats=3, order="setting"),
    "blocks and pause": Schedule(
        exposures_s=(0.05, 0.11),
        gains_db=(4.0,),
        repeats=5,
        blocks=(Block(exposures_s=(0.2,), gains_db=(2.0, 12.0)),),
        pause_s=7.0,
    ),
    "trex-subsampled": presets()["trex-subsampled"],
}


@pytest.mark.parametrize("name", list(SCHEDULES))
def test_the_estimate_takes_the_shots_the_runner_takes(name: str) -> None:
    """Shot by shot, at every phase the estimate starts the LEM at: same wavelength, same start."""
    schedule, dwell_s = SCHEDULES[name], 10.0
    shots = list(schedule.shots())
    for k in range(_PHASES):
        t0 = 3 * dwell_s * (k + 0.5) / _PHASES
        walk = _Walk(shots, READOUT_S, dwell_s, (405, 460, 525), schedule.pause_s)
        walk.t = t0
        mine = walk.take(_PASSES * len(shots))
        real = runner_shots(schedule, dwell_s, t0, _PASSES * len(shots))
        assert [wl for _, wl, _ in mine] == [wl for _, wl, _ in real], (name, k)
        assert [d for _, _, d in mine] == pytest.approx([d for _, _, d in real]), (name, k)
        assert [t for t, _, _ in mine] == pytest.approx([t for t, _, _ in real], abs=1e-6), (name, k)
    plan = plan_pass(schedule, READOUT_S, dwell_s)
    shooting = sum(
        e + READOUT_S for _ in schedule.wavelengths_nm for e, _, r in schedule.settings() for _ in range(r)
    )
    assert plan.shooting_s == pytest.approx(shooting) and plan.duration_s >= plan.shooting_s


def test_a_run_longer_than_the_dwell_is_named_and_one_that_fits_is_not() -> None:
    fits = plan_pass(SCHEDULES["fits the dwell"], READOUT_S, 10.0)
    assert fits.longest_run_s == pytest.approx({wl: 3 * (0.85 + 1.0) for wl in (405, 460, 525)})
    assert fits.warnings() == [] and fits.turns == pytest.approx({405: 1.0, 460: 1.0, 525: 1.0})
    # 2 gains x (0.85 + 1.0 + 1.8 s) x 4 repeats = 29.2 s a colour against 10 s on one: ~3 turns each
    long = plan_pass(SCHEDULES["twice the dwell"], READOUT_S, 10.0)
    (warning,) = long.warnings()
    assert "29.2 s, longer than the LEM shows a colour (10 s)" in warning, warning
    assert all(2.8 <= n <= 3.5 for n in long.turns.values()), long.turns
    # a run just over the dwell leaves a few shots to the next turn: said so, no "several turns"
    (tail,) = plan_pass(SCHEDULES["trex-subsampled"], READOUT_S, 60.0).warnings()
    assert "a little longer" in tail and "several" not in tail, tail
    assert long.busy_share > 0.9  # the camera shoots through every turn instead of waiting a cycle


def test_one_colour_waits_through_the_others_and_no_lem_means_no_waiting() -> None:
    one = SCHEDULES["one colour"]
    with_lem = plan_pass(one, READOUT_S, 10.0)
    assert with_lem.duration_s > 2.5 * with_lem.shooting_s  # the LEM shows 460 nm a third of the time
    bare = plan_pass(one, READOUT_S, None)
    assert bare.duration_s == pytest.approx(bare.shooting_s) and bare.warnings() == []
