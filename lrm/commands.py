"""How a module answers the ship's commands and keeps its schedule: the command half of `lrm.agent.Agent`.

A command is applied at most once (its id is remembered in the outbox's
``commands.jsonl``) and every state it goes through is answered with a
``command_status``; a schedule that waits for the end of a setting is
re-armed after a reboot. `CommandHandling` is mixed into the agent, whose
state it uses (``runner``, ``outbox``, ``_commands``, ``_status_out``).
"""

from __future__ import annotations

import queue
from collections import Counter
from collections.abc import Callable
from typing import Any

from pydantic import ValidationError

from camcal.core import wire
from camcal.core.schedule import CameraLimits, Schedule
from lrm.outbox import Outbox
from lrm.runner import ScheduleRunner


class CommandHandling:
    """Commands and the schedule of a module agent (mixed into `lrm.agent.Agent`)."""

    config: Any
    boot: str
    runner: ScheduleRunner | None
    outbox: Outbox
    camera_limits: CameraLimits | Callable[[], CameraLimits | None] | None
    counters: Counter[str]
    _commands: dict[str, dict[str, Any]]
    _status_out: queue.SimpleQueue[Any]
    _card_record: Callable[..., None]  # (`lrm.producing.Producing`: a full card cannot stop the module)

    def _restore_pending(self, runner: ScheduleRunner) -> None:
        """Re-arm a schedule change that was waiting for the end of a setting when the module stopped."""
        waiting = []
        for rec in self._commands.values():
            if rec.get("state") != "in_progress" or not rec.get("schedule"):
                continue
            try:
                waiting.append(Schedule.model_validate(rec["schedule"]))
            except ValidationError:
                continue
        for sched in sorted(waiting, key=lambda s: s.version):
            if sched.version > runner.schedule.version:
                runner.set_schedule(sched, "end_of_setting")

    def _schedule_state(self) -> wire.ScheduleState:
        if self.runner is None:
            return wire.ScheduleState(name="replay", version=0, state="running")
        return wire.ScheduleState(**self.runner.status())

    def _schedule_changed(self, schedule: Schedule, state: str) -> None:
        self.outbox.save_json("schedule.json", {"schedule": schedule.model_dump(mode="json"), "state": state})
        for cid, rec in list(self._commands.items()):
            if rec.get("state") == "in_progress" and rec.get("target_version") == schedule.version:
                self._status(cid, "done", target_version=schedule.version)

    def _status(self, command_id: str, state: str, reason: str | None = None, **extra: Any) -> None:
        rec = {
            **self._commands.get(command_id, {}),
            "command_id": command_id,
            "state": state,
            "reason": reason,
            **extra,
        }
        self._commands[command_id] = rec
        self._card_record("a command's state", self.outbox.append_jsonl, "commands.jsonl", rec)
        self._status_out.put(
            wire.CommandStatus(
                module=self.config.module,
                boot=self.boot,
                command_id=command_id,
                state=state,
                reason=reason,
                schedule=self._schedule_state(),
            )
        )

    def _on_command(self, cmd: wire.Command) -> None:
        """Validate and apply a command once; a repeated command only gets its status again."""
        self.counters["commands"] += 1
        known = self._commands.get(cmd.command_id)
        if known is not None:
            self.counters["commands_repeated"] += 1
            self._status_out.put(
                wire.CommandStatus(
                    module=self.config.module,
                    boot=self.boot,
                    command_id=cmd.command_id,
                    state=known["state"],
                    reason=known.get("reason"),
                    schedule=self._schedule_state(),
                )
            )
            return
        runner = self.runner
        if runner is None:
            self._status(cmd.command_id, "rejected", "this module replays a recorded frame set")
            return
        current = runner.schedule.version
        if cmd.action == "set_schedule":
            try:
                sched = Schedule.model_validate(cmd.schedule or {})
            except ValidationError as exc:
                e = exc.errors()[0]
                self._status(
                    cmd.command_id, "rejected", f"schedule.{'.'.join(str(p) for p in e['loc'])}: {e['msg']}"
                )
                return
            problem = self._check_limits(sched)
            if problem:
                self._status(cmd.command_id, "rejected", problem)
                return
            if sched.version != cmd.target_version:
                self._status(
                    cmd.command_id,
                    "rejected",
                    f"target_version {cmd.target_version} differs from the schedule's "
                    f"version {sched.version}",
                )
                return
            if sched.version <= current:
                self._status(
                    cmd.command_id,
                    "rejected",
                    f"version {sched.version} is not newer than the running version {current}",
                )
                return
            self._commands[cmd.command_id] = {"command_id": cmd.command_id, "target_version": sched.version}
            self._status(cmd.command_id, "accepted", target_version=sched.version)
            if cmd.apply == "end_of_setting":
                # The schedule is kept with the status, so that a reboot before the switch re-arms it.
                self._status(
                    cmd.command_id,
                    "in_progress",
                    target_version=sched.version,
                    schedule=sched.model_dump(mode="json"),
                )
                runner.set_schedule(sched, "end_of_setting")
            else:
                self._commands[cmd.command_id]["state"] = "in_progress"
                runner.set_schedule(sched, "now")
                if self._commands[cmd.command_id].get("state") != "done":
                    self._status(cmd.command_id, "done", target_version=sched.version)
            return
        if cmd.target_version and cmd.target_version != current:
            self._status(
                cmd.command_id,
                "rejected",
                f"{cmd.action} targets schedule version {cmd.target_version}, the module runs {current}",
            )
            return
        self._status(cmd.command_id, "accepted")
        {"start": runner.start, "pause": runner.pause, "resume": runner.resume, "stop": runner.stop}[
            cmd.action
        ]()
        self._status(cmd.command_id, "done")

    def _check_limits(self, sched: Schedule) -> str | None:
        limits = self.camera_limits() if callable(self.camera_limits) else self.camera_limits
        if limits is None:  # (a camera not opened yet: its own capture refuses what it cannot take)
            return None
        problems = limits.problems(sched)
        return problems[0][1] if problems else None
