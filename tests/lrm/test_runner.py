"""The schedule runner: shot order, pause/resume/stop/start, schedule changes, waiting for the LEM.

Time is virtual: `sleep` moves the clock on at once, so the tests wait for
nothing and the times the runner chose can be checked exactly.
"""

from __future__ import annotations

import threading
from datetime import timedelta

import pytest

from camcal.core.schedule import Schedule
from lrm.runner import Capture, ScheduleRunner
from tests.lrm.virtual import EPOCH, CyclingLem, FakeCamera, Shot, VirtualClock


def schedule(version: int = 1, **over: object) -> Schedule:
    spec: dict[str, object] = dict(
        name="test",
        version=version,
        exposures_s=(0.05, 0.07),
        gains_db=(6.0,),
        repeats=3,
        wavelengths_nm=(460,),
    )
    spec.update(over)
    return Schedule(**spec)


def make(sched: Schedule | None = None, **kw: object) -> tuple[ScheduleRunner, FakeCamera, VirtualClock]:
    clock = VirtualClock()
    cam = FakeCamera(clock)
    return ScheduleRunner(cam, clock, sched or schedule(), **kw), cam, clock


def take(runner: ScheduleRunner, n: int) -> list[Capture]:
    stop = threading.Event()
    out = []
    for _ in range(n):
        cap = runner.next_capture(stop)
        assert cap is not None
        out.append(cap)
    return out


def settings(caps: list[Capture]) -> list[tuple[int, float, float, int, int]]:
    return [
        (c.wavelength_nm, c.shot.exposure_s, c.shot.gain_db, c.shot.repeat, c.schedule_version) for c in caps
    ]


def blocked(runner: ScheduleRunner, cam: FakeCamera, wait_s: float = 0.3) -> bool:
    """True if `next_capture` takes no frame while the runner is not running (then it is released)."""
    stop = threading.Event()
    before = len(cam.taken)
    timer = threading.Timer(wait_s, stop.set)
    timer.start()
    cap = runner.next_capture(stop)
    timer.cancel()
    return cap is None and len(cam.taken) == before


def test_shots_follow_the_schedule_and_the_pass_repeats() -> None:
    runner, _, _ = make()
    caps = take(runner, 7)
    assert settings(caps) == [
        (460, 0.05, 6.0, 0, 1),
        (460, 0.05, 6.0, 1, 1),
        (460, 0.05, 6.0, 2, 1),
        (460, 0.07, 6.0, 0, 1),
        (460, 0.07, 6.0, 1, 1),
        (460, 0.07, 6.0, 2, 1),
        (460, 0.05, 6.0, 0, 1),  # the next pass
    ]


def test_pause_holds_the_place_and_resume_continues_from_it() -> None:
    runner, cam, _ = make()
    take(runner, 2)
    runner.pause()
    assert runner.status() == {"name": "test", "version": 1, "state": "paused"}
    assert blocked(runner, cam)
    runner.resume()
    assert runner.state == "running"
    assert settings(take(runner, 2)) == [(460, 0.05, 6.0, 2, 1), (460, 0.07, 6.0, 0, 1)]


def test_stop_takes_nothing_and_start_begins_the_pass_again() -> None:
    runner, cam, _ = make()
    take(runner, 4)
    runner.stop()
    assert runner.state == "stopped"
    assert blocked(runner, cam)
    runner.start()
    assert settings(take(runner, 1)) == [(460, 0.05, 6.0, 0, 1)]


def test_a_runner_created_stopped_waits_for_start() -> None:
    runner, cam, _ = make(state="stopped")
    assert blocked(runner, cam)
    runner.start()
    assert len(take(runner, 1)) == 1


def test_on_change_reports_every_state_and_schedule_change() -> None:
    runner, _, _ = make()
    seen: list[tuple[int, str]] = []
    runner.on_change = lambda sched, state: seen.append((sched.version, state))
    runner.pause()
    runner.resume()
    runner.set_schedule(schedule(2), "now")
    runner.stop()
    assert seen == [(1, "paused"), (1, "running"), (2, "running"), (2, "stopped")]


def test_set_schedule_now_switches_at_once() -> None:
    runner, _, _ = make()
    take(runner, 1)
    runner.set_schedule(schedule(2, exposures_s=(0.11,), gains_db=(10.0,)), "now")
    assert runner.schedule.version == 2
    assert settings(take(runner, 2)) == [(460, 0.11, 10.0, 0, 2), (460, 0.11, 10.0, 1, 2)]


def test_set_schedule_at_end_of_setting_waits_for_the_last_repeat() -> None:
    runner, _, _ = make()
    seen: list[int] = []
    runner.on_change = lambda sched, state: seen.append(sched.version)
    take(runner, 1)  # the first of three repeats of 0.05 s at 6 dB
    runner.set_schedule(schedule(2, exposures_s=(0.11,), gains_db=(10.0,)), "end_of_setting")
    assert runner.schedule.version == 1 and seen == []
    caps = take(runner, 4)
    assert settings(caps) == [
        (460, 0.05, 6.0, 1, 1),
        (460, 0.05, 6.0, 2, 1),  # the last repeat of the setting, still under version 1
        (460, 0.11, 10.0, 0, 2),
        (460, 0.11, 10.0, 1, 2),
    ]
    assert seen == [2]


def test_end_of_setting_at_the_end_of_a_pass_switches_before_the_next_pass() -> None:
    runner, _, _ = make(schedule(exposures_s=(0.05,), repeats=2))
    take(runner, 1)
    runner.set_schedule(schedule(2, exposures_s=(0.2,), repeats=2), "end_of_setting")
    assert settings(take(runner, 2)) == [(460, 0.05, 6.0, 1, 1), (460, 0.2, 6.0, 0, 2)]


def test_a_newer_pending_schedule_replaces_an_older_pending_one() -> None:
    runner, _, _ = make()
    take(runner, 1)
    runner.set_schedule(schedule(2, exposures_s=(0.11,)), "end_of_setting")
    runner.set_schedule(schedule(3, exposures_s=(0.2,)), "end_of_setting")
    assert settings(take(runner, 3))[-1] == (460, 0.2, 6.0, 0, 3)


def test_each_shot_waits_until_the_lem_shows_its_wavelength() -> None:
    lem = CyclingLem(dwell_s=10.0)
    runner, cam, _ = make(schedule(wavelengths_nm=(460, 525), exposures_s=(0.05,), repeats=2), lem=lem)
    caps = take(runner, 5)
    assert [c.wavelength_nm for c in caps] == [460, 460, 525, 525, 460]
    times = [t for t, _, _ in cam.taken]
    # 405 nm shows during [0, 10) s: the first 460 nm shot waits for t = 10 s.
    assert 10.0 <= times[0] < times[1] < 20.0
    assert 20.0 <= times[2] < times[3] < 30.0
    assert 40.0 <= times[4] < 50.0  # the next pass waits through 525 and 405 nm again
    for c, (t, _, _) in zip(caps, cam.taken, strict=True):
        assert lem.wavelength_at(EPOCH + timedelta(seconds=t)) == c.wavelength_nm


def test_shots_the_lem_left_no_time_for_come_first_at_its_next_turn_not_a_whole_cycle_late() -> None:
    """A pass that does not fit the LEM's dwell (five 2.4 s shots in a 10 s block): the runner stays
    in step with the LEM, taking four shots in each block, and the one it had no time for comes first
    at that wavelength's next turn. Waiting for it, the runner would take every later wavelength a
    whole cycle late (a block after the other camera). The fifth is not started at 19.6 s either: its
    exposure would end after the LEM changed colour, a frame of two colours under one label."""
    lem = CyclingLem(dwell_s=10.0)
    runner, cam, _ = make(schedule(wavelengths_nm=(460, 525), exposures_s=(2.4,), repeats=5), lem=lem)
    caps = take(runner, 20)
    times = [t for t, _, _ in cam.taken]
    assert [c.wavelength_nm for c in caps] == ([460] * 4 + [525] * 4) * 2 + [460] * 4
    at = pytest.approx  # the runner wakes a millisecond after a block starts
    assert times[:4] == at([10.0, 12.4, 14.8, 17.2], abs=0.01)  # 460 nm shows during [10, 20) s
    assert times[4:8] == at([20.0, 22.4, 24.8, 27.2], abs=0.01)  # 525 nm at once, in its own block
    assert times[8] == at(40.0, abs=0.01) and times[12] == at(50.0, abs=0.01)  # the next turns
    # The repeat left over comes first; over the turns every repeat is taken as often as the others.
    assert [c.shot.repeat for c in caps[:12]] == [0, 1, 2, 3] * 2 + [4, 0, 1, 2]
    assert sorted(c.shot.repeat for c in caps[:20] if c.wavelength_nm == 460) == sorted(
        [0, 1, 2, 3, 4] * 2 + [0, 1]
    )
    assert runner.deferred_shots == 4  # one a turn: 460, 525, 460, 525 nm
    for c, (t, exposure_s, _) in zip(caps, cam.taken, strict=True):
        assert lem.wavelength_at(EPOCH + timedelta(seconds=t)) == c.wavelength_nm
        assert lem.wavelength_at(EPOCH + timedelta(seconds=t + exposure_s - 1e-6)) == c.wavelength_nm


def test_no_exposure_is_started_that_the_lem_would_change_colour_in() -> None:
    """One 0.5 s shot a setting, 1.2 s each with readout: in a 10 s block the ninth starts at 9.6 s,
    after which a 0.5 s exposure would end at 10.1 s, in the next colour. It waits for its colour's
    next turn instead (the start of a wavelength's shots: nothing to defer)."""
    lem = CyclingLem(dwell_s=10.0)
    clock = VirtualClock()
    cam = FakeCamera(clock, readout_s=0.7)
    runner = ScheduleRunner(cam, clock, schedule(exposures_s=(0.5,), repeats=1), lem=lem)
    clock.t = 18.0  # 460 nm shows until 20 s: 1.2 s left after the first shot's 0.8 s wait... none
    caps = take(runner, 3)
    times = [t for t, _, _ in cam.taken]
    assert all(c.wavelength_nm == 460 for c in caps)
    assert times[0] == pytest.approx(18.0) and times[1] == pytest.approx(19.2)
    assert times[2] == pytest.approx(40.0, abs=0.01)  # 19.2 + 1.2 = 20.4: past the change; next turn
    # An exposure longer than a whole dwell could never fit: taken as the timetable allows, not held.
    long = ScheduleRunner(FakeCamera(VirtualClock()), VirtualClock(), schedule(exposures_s=(12.0,)), lem=lem)
    assert long.next_capture(threading.Event()) is not None


def test_a_paused_runner_resumes_its_wavelength_in_its_next_block() -> None:
    """Paused amid 460 nm's shots and resumed while 525 nm shows: nothing is deferred, the runner
    waits for 460 nm (resume continues where it stopped)."""
    lem = CyclingLem(dwell_s=10.0)
    runner, cam, clock = make(schedule(wavelengths_nm=(460, 525), exposures_s=(2.5,), repeats=3), lem=lem)
    take(runner, 2)
    runner.pause()
    clock.sleep(22.5 - clock.monotonic())  # now 525 nm shows
    runner.resume()
    caps = take(runner, 2)
    assert [c.shot.repeat for c in caps] == [2, 0] and caps[0].wavelength_nm == 460
    assert cam.taken[2][0] == pytest.approx(40.0, abs=0.01) and runner.deferred_shots == 0


def test_the_wavelength_the_camera_reports_wins_over_the_timetable() -> None:
    runner, cam, _ = make(lem=CyclingLem(dwell_s=10.0))

    def capture(exposure_s: float, gain_db: float) -> Shot:
        cam.taken.append((cam.clock.monotonic(), exposure_s, gain_db))
        return Shot(cam.clock.now(), exposure_s, gain_db, wavelength_nm=405)

    cam.capture = capture  # type: ignore[method-assign]
    assert take(runner, 1)[0].wavelength_nm == 405


def test_the_gate_holds_captures_until_it_opens() -> None:
    clock_box: dict[str, VirtualClock] = {}
    runner, cam, clock = make(gate=lambda: clock_box["c"].monotonic() >= 30.0)
    clock_box["c"] = clock
    take(runner, 1)
    assert cam.taken[0][0] >= 30.0


def test_pause_after_the_pass_waits_before_the_next_pass() -> None:
    runner, cam, _ = make(schedule(exposures_s=(0.05,), repeats=1, pause_s=60.0))
    take(runner, 2)
    assert cam.taken[1][0] - cam.taken[0][0] == pytest.approx(0.05 + 60.0)


def test_next_capture_returns_none_when_stop_is_set() -> None:
    runner, _, _ = make()
    stop = threading.Event()
    stop.set()
    assert runner.next_capture(stop) is None
