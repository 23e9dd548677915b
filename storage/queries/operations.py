"""Reads of the ship's operations: modules, alarms, events, the audit log, commands, calibrations."""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from typing import Any

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from camcal.core.events import Event, EventKind
from storage.audit import describe
from storage.models import (
    Alarm,
    AuditEntry,
    Calibration,
    CommandRecord,
    Module,
)
from storage.models import Event as EventRow

KINDS = frozenset(k.value for k in EventKind)


def modules(s: Session) -> list[dict[str, Any]]:
    return [
        {
            "id": m.id,
            "distance_m": m.distance_m,
            "last_seen_unix_s": m.last_seen_unix_s,
            "boot": m.boot,
            "software": m.software,
            "schedule": {"name": m.schedule_name, "version": m.schedule_version, "state": m.schedule_state},
            "camera": _camera(m.camera_json),
        }
        for m in s.scalars(select(Module).order_by(Module.id))
    ]


def _camera(text: str | None) -> dict[str, Any] | None:
    """A module's camera as it said (`camcal.core.wire.CameraInfo` as a dict), or None."""
    if not text:
        return None
    try:
        cam = json.loads(text)
    except ValueError:
        return None
    return cam if isinstance(cam, dict) else None


def module_camera(s: Session, module_id: str) -> dict[str, Any] | None:
    """What a module said of its camera (model, ranges, pixel format), or None if it never said."""
    mod = s.get(Module, module_id)
    return _camera(mod.camera_json) if mod is not None else None


def module_exists(s: Session, module_id: str) -> bool:
    return s.get(Module, module_id) is not None


def schedule_version(s: Session, module_id: str) -> int:
    """The newest schedule version a module runs or has been sent (not rejected)."""
    mod = s.get(Module, module_id)
    running = mod.schedule_version if mod else 0
    sent = s.scalar(
        select(func.max(CommandRecord.target_version)).where(
            CommandRecord.module_id == module_id,
            CommandRecord.action == "set_schedule",
            CommandRecord.state != "rejected",
        )
    )
    return max(running or 0, sent or 0)


def alarms(s: Session, *, active: bool | None = None, limit: int = 200) -> list[dict[str, Any]]:
    q = select(Alarm)
    if active is not None:
        q = q.where(Alarm.active.is_(active))
    return [alarm_dict(a) for a in s.scalars(q.order_by(Alarm.id.desc()).limit(limit))]


def alarm_dict(a: Alarm) -> dict[str, Any]:
    return {
        "id": a.id,
        "key": a.key,
        "kind": a.kind,
        "module": a.module_id,
        "severity": a.severity,
        "message": a.message,
        "raised_unix_s": a.raised_unix_s,
        "cleared_unix_s": a.cleared_unix_s,
        "acked_unix_s": a.acked_unix_s,
        "acked_by": a.acked_by,
        "active": a.active,
    }


def active_alarms(s: Session) -> list[Alarm]:
    return list(s.scalars(select(Alarm).where(Alarm.active.is_(True)).order_by(Alarm.id)))


def events_after(s: Session, after_id: int, limit: int) -> list[Event]:
    """Stored events after an id, in id order (a kind this version does not know is left out)."""
    rows = s.scalars(select(EventRow).where(EventRow.id > after_id).order_by(EventRow.id).limit(limit))
    return [
        Event(EventKind(e.kind), e.payload or {}, e.t_unix_s, e.module_id, e.dive_id, e.id)
        for e in rows
        if e.kind in KINDS
    ]


def last_event_id(s: Session) -> int:
    return int(s.scalar(select(func.max(EventRow.id))) or 0)


def audit(s: Session, limit: int = 500, offset: int = 0) -> list[dict[str, Any]]:
    """Audit entries, newest first, each with ``what``: what happened, in words (`storage.audit`)."""
    out = []
    for a in s.scalars(select(AuditEntry).order_by(AuditEntry.id.desc()).limit(limit).offset(offset)):
        entry = {
            "id": a.id,
            "t_unix_s": a.t_unix_s,
            "actor": a.actor,
            "action": a.action,
            "target": a.target,
            "details": a.details,
        }
        out.append({**entry, "what": describe(entry)})
    return out


def command_dict(c: CommandRecord) -> dict[str, Any]:
    return {
        "id": c.id,
        "module": c.module_id,
        "action": c.action,
        "target_version": c.target_version,
        "payload": c.payload,
        "apply": c.apply,
        "issued_by": c.issued_by,
        "issued_unix_s": c.issued_unix_s,
        "state": c.state,
        "reason": c.reason,
        "attempts": c.attempts,
        "updated_unix_s": c.updated_unix_s,
    }


def command(s: Session, command_id: str) -> dict[str, Any] | None:
    cmd = s.get(CommandRecord, command_id)
    return command_dict(cmd) if cmd else None


def commands(
    s: Session, module_id: str | None = None, states: Sequence[str] | None = None, limit: int = 200
) -> list[dict[str, Any]]:
    q = select(CommandRecord)
    if module_id:
        q = q.where(CommandRecord.module_id == module_id)
    if states:
        q = q.where(CommandRecord.state.in_(list(states)))
    return [command_dict(c) for c in s.scalars(q.order_by(CommandRecord.issued_unix_s.desc()).limit(limit))]


#: The states of a command the module has not answered for good yet: the ship still delivers it.
UNANSWERED = ("pending", "sent", "accepted")


def commands_unanswered(s: Session, module_id: str) -> int:
    """How many commands of a module wait for its answer (not yet applied or refused)."""
    q = select(func.count()).where(CommandRecord.module_id == module_id, CommandRecord.state.in_(UNANSWERED))
    return int(s.scalar(q) or 0)


def commands_to_deliver(s: Session, per_module: int) -> list[dict[str, Any]]:
    """The commands the ship still has to deliver, oldest first, at most ``per_module`` of each module.

    Oldest first over all of them: taking the newest few and reversing them (as before) sent a
    module's later commands before its earlier ones once more than a few waited, and a queued
    ``pause`` then arrived after the operator's ``start``.
    """
    out: list[dict[str, Any]] = []
    taken: dict[str, int] = {}
    q = select(CommandRecord).where(CommandRecord.state.in_(UNANSWERED)).order_by(CommandRecord.issued_unix_s)
    for c in s.scalars(q):
        if taken.get(c.module_id, 0) < per_module:
            taken[c.module_id] = taken.get(c.module_id, 0) + 1
            out.append(command_dict(c))
    return out


def calibration_dict(c: Calibration) -> dict[str, Any]:
    return {
        "id": c.id,
        "name": c.name,
        "version": c.version,
        "source": c.source,
        "valid_from_unix_s": c.valid_from_unix_s,
        "valid_to_unix_s": c.valid_to_unix_s,
        "values": c.values,
        "created_unix_s": c.created_unix_s,
    }


def calibrations(s: Session, name: str | None = None) -> list[dict[str, Any]]:
    q = select(Calibration)
    if name:
        q = q.where(Calibration.name == name)
    return [calibration_dict(c) for c in s.scalars(q.order_by(Calibration.name, Calibration.version))]


def calibration(s: Session, ref: int | str) -> dict[str, Any] | None:
    """A calibration by id, by ``name@version``, or by name (its newest version valid now)."""
    if isinstance(ref, int) or (isinstance(ref, str) and ref.isdigit()):
        c = s.get(Calibration, int(ref))
        return calibration_dict(c) if c else None
    name, _, version = str(ref).partition("@")
    q = select(Calibration).where(Calibration.name == name)
    if version:
        if not version.isdigit():
            return None
        q = q.where(Calibration.version == int(version))
    else:
        t = time.time()
        q = q.where(
            (Calibration.valid_from_unix_s.is_(None)) | (Calibration.valid_from_unix_s <= t),
            (Calibration.valid_to_unix_s.is_(None)) | (Calibration.valid_to_unix_s >= t),
        )
    c = s.scalars(q.order_by(Calibration.version.desc()).limit(1)).first()
    return calibration_dict(c) if c else None
