"""The store's writes of operations: alarms, the audit log, commands, calibrations, retention."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from sqlalchemy import func, select, update

from storage.base import StoreBase, now_unix_s
from storage.models import Alarm, AnalysisRun, AuditEntry, Calibration, CommandRecord, Dive, Frame
from storage.queries.operations import calibration_dict, command_dict

#: Order of a command's states: a late, older status never moves it back.
COMMAND_STATES = {"pending": 0, "sent": 1, "accepted": 2, "in_progress": 3, "done": 4, "rejected": 4}


class OperationsWrites(StoreBase):
    """What the operators and the ingest's housekeeping write."""

    def raise_alarm(
        self,
        key: str,
        kind: str,
        severity: str,
        message: str,
        module_id: str | None = None,
        details: dict[str, Any] | None = None,
    ) -> tuple[Alarm, bool]:
        """Raise (or update) the active alarm with ``key``; returns it and whether it is new or changed."""
        t = now_unix_s()
        with self.session() as s:
            alarm = s.scalars(select(Alarm).where(Alarm.key == key, Alarm.active.is_(True))).first()
            if alarm is None:
                alarm = Alarm(
                    key=key,
                    kind=kind,
                    module_id=module_id,
                    severity=severity,
                    message=message,
                    raised_unix_s=t,
                    active=True,
                    details=details or {},
                )
                s.add(alarm)
                s.flush()
                return alarm, True
            changed = alarm.severity != severity or alarm.message != message
            alarm.severity, alarm.message, alarm.details = severity, message, details or {}
            return alarm, changed

    def clear_alarm(self, key: str) -> Alarm | None:
        with self.session() as s:
            alarm = s.scalars(select(Alarm).where(Alarm.key == key, Alarm.active.is_(True))).first()
            if alarm is not None:
                alarm.active = False
                alarm.cleared_unix_s = now_unix_s()
            return alarm

    def ack_alarm(self, alarm_id: int, user: str, note: str = "") -> Alarm | None:
        """Acknowledge an alarm once; the audit log keeps who, when, and the operator's ``note``."""
        with self.session() as s:
            alarm = s.get(Alarm, alarm_id)
            if alarm is None:
                return None
            if alarm.acked_unix_s is None:
                alarm.acked_unix_s, alarm.acked_by = now_unix_s(), user
                s.add(
                    AuditEntry(
                        t_unix_s=now_unix_s(),
                        actor=user,
                        action="alarm.ack",
                        target=f"alarm:{alarm_id}",
                        details={"kind": alarm.kind, "key": alarm.key, "note": note},
                    )
                )
            return alarm

    def audit(self, actor: str, action: str, target: str = "", details: dict[str, Any] | None = None) -> int:
        with self.session() as s:
            entry = AuditEntry(
                t_unix_s=now_unix_s(), actor=actor, action=action, target=target, details=details or {}
            )
            s.add(entry)
            s.flush()
            return entry.id

    def create_command(
        self,
        command_id: str,
        module_id: str,
        action: str,
        issued_by: str,
        *,
        payload: dict[str, Any] | None = None,
        target_version: int = 0,
        apply: str = "now",
    ) -> dict[str, Any]:
        """Queue a command (state ``pending``) and record it in the audit log, in one transaction."""
        t = now_unix_s()
        with self.session() as s:
            cmd = CommandRecord(
                id=command_id,
                module_id=module_id,
                action=action,
                target_version=target_version,
                payload=payload or {},
                apply=apply,
                issued_by=issued_by,
                issued_unix_s=t,
                state="pending",
                attempts=0,
                updated_unix_s=t,
            )
            s.add(cmd)
            s.add(
                AuditEntry(
                    t_unix_s=t,
                    actor=issued_by,
                    action=f"command.{action}",
                    target=f"module:{module_id}",
                    details={
                        "command_id": command_id,
                        "target_version": target_version,
                        "apply": apply,
                        "schedule": (payload or {}).get("schedule"),
                    },
                )
            )
            s.flush()
            return command_dict(cmd)

    def mark_command_sent(self, command_id: str) -> None:
        with self.session() as s:
            cmd = s.get(CommandRecord, command_id)
            if cmd is not None:
                cmd.attempts += 1
                cmd.updated_unix_s = now_unix_s()
                if cmd.state == "pending":
                    cmd.state = "sent"

    def update_command(
        self, command_id: str, state: str, reason: str | None, actor: str
    ) -> dict[str, Any] | None:
        """Record a module's answer (audited); returns the command if its state changed."""
        with self.session() as s:
            cmd = s.get(CommandRecord, command_id)
            if cmd is None or COMMAND_STATES.get(state, 0) <= COMMAND_STATES.get(cmd.state, 0):
                return None
            cmd.state, cmd.reason, cmd.updated_unix_s = state, reason, now_unix_s()
            s.add(
                AuditEntry(
                    t_unix_s=now_unix_s(),
                    actor=actor,
                    action=f"command.{state}",
                    target=f"module:{cmd.module_id}",
                    details={"command_id": command_id, "reason": reason, "action": cmd.action},
                )
            )
            return command_dict(cmd)

    def add_calibration(
        self,
        name: str,
        values: dict[str, Any],
        *,
        actor: str,
        source: str = "",
        valid_from_unix_s: float | None = None,
        valid_to_unix_s: float | None = None,
    ) -> dict[str, Any]:
        """Store a new version of a named calibration (the next integer); audited. Old versions stay."""
        with self.session() as s:
            latest = s.scalar(select(func.max(Calibration.version)).where(Calibration.name == name)) or 0
            cal = Calibration(
                name=name,
                version=latest + 1,
                source=source,
                valid_from_unix_s=valid_from_unix_s,
                valid_to_unix_s=valid_to_unix_s,
                values=values,
                created_unix_s=now_unix_s(),
            )
            s.add(cal)
            s.flush()
            s.add(
                AuditEntry(
                    t_unix_s=now_unix_s(),
                    actor=actor,
                    action="calibration.add",
                    target=f"calibration:{name}@{cal.version}",
                    details={"id": cal.id, "source": source, "values": values},
                )
            )
            return calibration_dict(cal)

    def use_calibration(self, dive_id: int, run_id: int, calibration_id: int, actor: str) -> None:
        """Record that a dive (and its run) uses a calibration; audited."""
        with self.session() as s:
            s.execute(update(Dive).where(Dive.id == dive_id).values(calibration_id=calibration_id))
            s.execute(
                update(AnalysisRun).where(AnalysisRun.id == run_id).values(calibration_id=calibration_id)
            )
            s.add(
                AuditEntry(
                    t_unix_s=now_unix_s(),
                    actor=actor,
                    action="calibration.use",
                    target=f"dive:{dive_id}",
                    details={"calibration_id": calibration_id, "run_id": run_id},
                )
            )

    def purge_frame_files(self, older_than_unix_s: float, modules: Sequence[str] = ()) -> tuple[int, int]:
        """Delete frame files captured before a time (of ``modules`` if given: an ingest that shares
        the data folder purges its own); rows, results and thumbnails stay.

        Returns (files deleted, bytes freed). The image route then says the
        file went to retention.
        """
        n = freed = 0
        with self.read() as s:
            q = select(Frame.path, Frame.size_bytes).where(Frame.captured_unix_s < older_than_unix_s)
            if modules:
                q = q.where(Frame.module_id.in_(list(modules)))
            rows = s.execute(q)
            for path, size in rows:
                try:
                    p = self.files.resolve(path)
                except ValueError:
                    continue
                if p.exists():
                    p.unlink()
                    n += 1
                    freed += int(size or 0)
        return n, freed
