"""The agent's answers to the ship's commands, over a real ROUTER on 127.0.0.1 (the test is the ship)."""

from __future__ import annotations

import time
from collections.abc import Iterator
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zmq

from camcal.core.schedule import CameraLimits, Schedule
from lrm.agent import Agent, AgentConfig
from lrm.runner import ScheduleRunner
from tests.utils.live import FakeShip, Frame, RealClock


class TinyCamera:
    """A 32 x 24 camera with T-REX-like ranges (exposure 0.1 ms .. 2 s, gain 0 .. 24 dB in 0.1 dB)."""

    exposure_range_s = (1e-4, 2.0)
    gain_range_db = (0.0, 24.0)
    gain_step_db = 0.1

    def __init__(self) -> None:
        self.settings: list[tuple[float, float]] = []

    def capture(self, exposure_s: float, gain_db: float) -> Frame:
        self.settings.append((exposure_s, gain_db))
        time.sleep(0.01)
        pixels = np.full((24, 32), len(self.settings) % 200, dtype=np.uint8)
        return Frame(pixels, datetime.now(UTC), exposure_s, gain_db, "A", 460, 3420.0)


def schedule(version: int, exposures_s: tuple[float, ...] = (0.05,), **over: Any) -> Schedule:
    return Schedule(
        name="cmd-test",
        version=version,
        exposures_s=exposures_s,
        gains_db=over.pop("gains_db", (6.0,)),
        repeats=over.pop("repeats", 2),
        wavelengths_nm=(460,),
        **over,
    )


def spec(s: Schedule) -> dict[str, Any]:
    return s.model_dump(mode="json")


class Module:
    """An agent with its runner and camera, on an outbox folder."""

    def __init__(self, outbox: Path, endpoint: str, initial: Schedule, state: str = "running") -> None:
        self.camera = TinyCamera()
        clock = RealClock()
        self.runner = ScheduleRunner(self.camera, clock, initial, state=state)
        limits = CameraLimits(
            self.camera.exposure_range_s, self.camera.gain_range_db, self.camera.gain_step_db
        )
        self.agent = Agent(
            AgentConfig(
                module="A", connect=endpoint, outbox=outbox, fsync=False, heartbeat_s=0.2, plaintext=True
            ),
            clock=clock,
            runner=self.runner,
            camera_limits=limits,
            ctx=zmq.Context.instance(),
        )
        self.agent.start()

    def stop(self) -> None:
        self.agent.stop()


@pytest.fixture
def ship() -> Iterator[FakeShip]:
    s = FakeShip(zmq.Context.instance())
    yield s
    s.close()


@pytest.fixture
def module(tmp_path: Path, ship: FakeShip) -> Iterator[Module]:
    m = Module(tmp_path / "outbox", ship.endpoint, schedule(1))
    assert ship.pump(lambda: ship.hellos, 10), "the module never said hello"
    yield m
    m.stop()


def answered(ship: FakeShip, command_id: str, *states: str) -> bool:
    """Wait until the module's answers to ``command_id`` so far are exactly ``states``."""
    return ship.pump(lambda: ship.states_of(command_id) == list(states), 10)


def test_set_schedule_is_accepted_then_done_and_runs(ship: FakeShip, module: Module) -> None:
    new = schedule(2, exposures_s=(0.11,), gains_db=(10.0,))
    ship.command("c1", "set_schedule", target_version=2, schedule=spec(new))
    assert answered(ship, "c1", "accepted", "done")
    assert ship.states_of("c1") == ["accepted", "done"]
    done = [s for s in ship.statuses if s.command_id == "c1"][-1]
    assert (done.schedule.name, done.schedule.version, done.schedule.state) == ("cmd-test", 2, "running")
    assert module.runner.schedule == new
    # The module reports the new version in its heartbeats and takes the new setting.
    assert ship.pump(lambda: ship.heartbeats and ship.heartbeats[-1].schedule.version == 2)
    n = len(module.camera.settings)
    assert ship.pump(lambda: len(module.camera.settings) >= n + 3)
    assert module.camera.settings[-1] == (0.11, 10.0)
    saved = module.agent.outbox.load_json("schedule.json")
    assert saved["schedule"]["version"] == 2 and saved["state"] == "running"


def test_a_repeated_command_id_gets_its_status_again_and_is_applied_once(
    ship: FakeShip, module: Module
) -> None:
    ship.command("c1", "set_schedule", target_version=2, schedule=spec(schedule(2)))
    assert answered(ship, "c1", "accepted", "done")
    changes: list[int] = []
    on_change = module.runner.on_change
    module.runner.on_change = lambda s, st: (changes.append(s.version), on_change(s, st))
    # The ship did not hear the answer and sends the command again (here even with another body).
    ship.command("c1", "set_schedule", target_version=3, schedule=spec(schedule(3)))
    assert answered(ship, "c1", "accepted", "done", "done")
    assert module.agent.counters["commands_repeated"] == 1
    assert module.runner.schedule.version == 2 and changes == []


@pytest.mark.parametrize("version", [1, 2])
def test_a_schedule_version_not_newer_is_rejected_with_a_reason(
    ship: FakeShip, module: Module, version: int
) -> None:
    ship.command("c1", "set_schedule", target_version=2, schedule=spec(schedule(2)))
    assert answered(ship, "c1", "accepted", "done")
    ship.command("c2", "set_schedule", target_version=version, schedule=spec(schedule(version)))
    assert answered(ship, "c2", "rejected")
    reason = ship.statuses[-1].reason
    assert f"version {version} is not newer than the running version 2" in reason
    assert module.runner.schedule.version == 2


@pytest.mark.parametrize(
    ("over", "expected"),
    [
        ({"exposures_s": (0.05, 5.0)}, "exposure 5.0 s outside the camera's range [0.0001, 2.0] s"),
        ({"gains_db": (30.0,)}, "gain 30.0 dB outside the camera's range [0.0, 24.0] dB"),
        ({"gains_db": (6.05,)}, "gain 6.05 dB is not a multiple of the 0.1 dB step"),
    ],
)
def test_a_schedule_the_camera_cannot_take_is_rejected(
    ship: FakeShip, module: Module, over: dict[str, Any], expected: str
) -> None:
    ship.command("c1", "set_schedule", target_version=2, schedule=spec(schedule(2, **over)))
    assert answered(ship, "c1", "rejected")
    assert ship.statuses[-1].reason == expected
    assert module.runner.schedule.version == 1


def test_invalid_schedules_and_mismatched_versions_are_rejected(ship: FakeShip, module: Module) -> None:
    bad = {**spec(schedule(2)), "exposures_s": [-0.1]}
    ship.command("c1", "set_schedule", target_version=2, schedule=bad)
    assert answered(ship, "c1", "rejected")
    assert ship.statuses[-1].reason.startswith("schedule.exposures_s")
    ship.command("c2", "set_schedule", target_version=3, schedule=spec(schedule(2)))
    assert answered(ship, "c2", "rejected")
    assert "target_version 3 differs from the schedule's version 2" in ship.statuses[-1].reason
    ship.command("c3", "pause", target_version=7)
    assert answered(ship, "c3", "rejected")
    assert "targets schedule version 7, the module runs 1" in ship.statuses[-1].reason
    assert module.runner.state == "running" and module.runner.schedule.version == 1


def test_pause_resume_stop_start(ship: FakeShip, module: Module) -> None:
    for i, (action, state) in enumerate(
        [("pause", "paused"), ("resume", "running"), ("stop", "stopped"), ("start", "running")]
    ):
        target = 1 if i % 2 else 0  # 0 means "whatever version runs"
        ship.command(f"c{i}", action, target_version=target)
        assert answered(ship, f"c{i}", "accepted", "done"), action
        assert module.runner.state == state
        assert ship.statuses[-1].schedule.state == state
        assert ship.pump(lambda s=state: ship.heartbeats[-1].schedule.state == s)
        if state != "running":
            n = len(module.camera.settings)
            ship.pump(timeout=0.3)
            assert len(module.camera.settings) <= n + 1  # at most the frame being taken
    n = len(module.camera.settings)
    assert ship.pump(lambda: len(module.camera.settings) >= n + 2)


def test_end_of_setting_is_in_progress_until_the_setting_is_finished(ship: FakeShip, module: Module) -> None:
    ship.command(
        "c1",
        "set_schedule",
        target_version=2,
        schedule=spec(schedule(2, exposures_s=(0.2,))),
        apply="end_of_setting",
    )
    assert answered(ship, "c1", "accepted", "in_progress", "done")
    assert module.runner.schedule.version == 2
    assert ship.pump(lambda: module.camera.settings[-1] == (0.2, 6.0))
    i = module.camera.settings.index((0.2, 6.0))
    assert all(s == (0.05, 6.0) for s in module.camera.settings[:i])


def test_the_schedule_and_the_answers_survive_a_restart(tmp_path: Path, ship: FakeShip) -> None:
    outbox = tmp_path / "outbox"
    m = Module(outbox, ship.endpoint, schedule(1))
    assert ship.pump(lambda: ship.hellos)
    ship.command("c1", "set_schedule", target_version=2, schedule=spec(schedule(2, exposures_s=(0.11,))))
    assert answered(ship, "c1", "accepted", "done")
    ship.command("c2", "pause")
    assert answered(ship, "c2", "accepted", "done")
    m.stop()

    # The module reboots with its built-in schedule (version 1) and reads its SD card.
    ship.hellos.clear()
    again = Module(outbox, ship.endpoint, schedule(1))
    try:
        assert again.runner.schedule == schedule(2, exposures_s=(0.11,))
        assert again.runner.state == "paused"
        assert ship.pump(lambda: ship.hellos)
        hello = ship.hellos[-1]
        assert (hello.schedule.version, hello.schedule.state) == (2, "paused")
        assert hello.boot != m.agent.boot
        # A command answered before the reboot is answered again, not applied again.
        ship.command("c2", "resume")
        assert answered(ship, "c2", "accepted", "done", "done")
        assert again.runner.state == "paused" and again.agent.counters["commands_repeated"] == 1
        ship.command("c3", "resume", target_version=2)
        assert answered(ship, "c3", "accepted", "done")
        assert again.runner.state == "running"
        n = len(again.camera.settings)
        assert ship.pump(lambda: len(again.camera.settings) >= n + 2)
        assert again.camera.settings[-1] == (0.11, 6.0)
    finally:
        again.stop()


def test_an_older_saved_schedule_does_not_override_a_newer_built_in_one(
    tmp_path: Path, ship: FakeShip
) -> None:
    outbox = tmp_path / "outbox"
    m = Module(outbox, ship.endpoint, schedule(1))
    m.stop()
    updated = Module(outbox, ship.endpoint, schedule(5, exposures_s=(0.07,)))
    try:
        assert updated.runner.schedule.version == 5
        assert updated.agent.outbox.load_json("schedule.json")["schedule"]["version"] == 5
    finally:
        updated.stop()


def test_a_change_waiting_for_the_end_of_the_setting_survives_a_restart(
    tmp_path: Path, ship: FakeShip
) -> None:
    outbox = tmp_path / "outbox"
    # Paused from the start: no shot is being taken, so the change cannot apply before the reboot.
    m = Module(outbox, ship.endpoint, schedule(1), state="paused")
    assert ship.pump(lambda: ship.hellos)
    new = schedule(2, exposures_s=(0.2,))
    ship.command("c2", "set_schedule", target_version=2, schedule=spec(new), apply="end_of_setting")
    assert answered(ship, "c2", "accepted", "in_progress")
    m.stop()

    again = Module(outbox, ship.endpoint, schedule(1))
    try:
        assert again.runner.schedule.version == 1 and again.runner.state == "paused"
        assert ship.pump(lambda: len(ship.hellos) >= 2)
        ship.command("c2", "set_schedule", target_version=2, schedule=spec(new), apply="end_of_setting")
        assert answered(ship, "c2", "accepted", "in_progress", "in_progress")
        ship.command("c3", "resume")
        assert answered(ship, "c3", "accepted", "done")
        assert answered(ship, "c2", "accepted", "in_progress", "in_progress", "done")
        assert again.runner.schedule == new
        assert ship.pump(lambda: again.camera.settings and again.camera.settings[-1] == (0.2, 6.0))
    finally:
        again.stop()


def test_an_outbox_entry_whose_file_is_gone_is_skipped_and_the_rest_is_sent(
    tmp_path: Path, ship: FakeShip
) -> None:
    outbox = tmp_path / "outbox"
    m = Module(outbox, "tcp://127.0.0.1:1", schedule(1))  # no ship: everything stays in the outbox
    while m.agent.counters["frames_captured"] < 4:
        time.sleep(0.01)
    m.stop()
    pending = m.agent.outbox.pending()
    frames = [e for e in pending if e.kind == "frame"]
    (outbox / "frames" / frames[1].ref.file).unlink()  # the SD card lost one image

    again = Module(outbox, ship.endpoint, schedule(1), state="stopped")
    try:
        expected = {("frame", e.boot, e.seq) for e in frames} - {("frame", frames[1].boot, frames[1].seq)}
        assert ship.pump(lambda: expected <= set(ship.data), 10), "the rest of the outbox was not sent"
        assert again.agent.counters["unsendable"] == 1
        assert not again.agent.stopped
    finally:
        again.stop()


@pytest.mark.parametrize(
    ("file", "damaged"),
    [
        ("commands.jsonl", b'[1, 2]\n{"state": "done"}\n\xff\n'),  # JSON that is no answer, bytes
        ("schedule.json", b"[1, 2]\n"),  # JSON that is no saved schedule
        ("schedule.json", b'{"schedule": "\xff"}\n'),
    ],
)
def test_a_damaged_state_file_on_the_card_does_not_keep_the_module_from_starting(
    tmp_path: Path, ship: FakeShip, file: str, damaged: bytes
) -> None:
    """The card's answers and saved schedule, damaged (a failing card): the module starts on its
    built-in schedule and answers commands."""
    outbox = tmp_path / "outbox"
    first = Module(outbox, ship.endpoint, schedule(1))
    assert ship.pump(lambda: ship.hellos, 10)
    first.stop()
    ship.hellos.clear()
    (outbox / file).write_bytes(damaged)
    m = Module(outbox, ship.endpoint, schedule(2))
    try:
        assert m.runner.schedule.version == 2
        assert ship.pump(lambda: ship.hellos, 10), "the module never said hello"
        ship.command("c-after", "set_schedule", target_version=3, schedule=spec(schedule(3)))
        assert answered(ship, "c-after", "accepted", "done")
    finally:
        m.stop()
