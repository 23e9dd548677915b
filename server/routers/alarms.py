"""Alarms and their acknowledgement; the audit log."""

from __future__ import annotations

import time
from typing import Annotated, Any

from fastapi import APIRouter, Query

from camcal.core.events import Event, EventKind
from server.deps import HubDep, IdPath, OperatorDep, StoreDep
from server.errors import NotFound
from server.schemas import AckRequest, AlarmPublic, AuditEntryPublic
from storage import queries

router = APIRouter(tags=["alarms"])


@router.get("/api/alarms", response_model=list[AlarmPublic])
def list_alarms(
    store: StoreDep, active: bool | None = None, limit: Annotated[int, Query(ge=1, le=2000)] = 200
) -> list[dict[str, Any]]:
    """Alarms, newest first: severity MINOR or MAJOR, raised, cleared, acknowledged by whom."""

    return store.call(queries.alarms, active=active, limit=limit)


@router.post("/api/alarms/{alarm_id}/ack", response_model=AlarmPublic)
def ack(
    alarm_id: IdPath, store: StoreDep, hub: HubDep, who: OperatorDep, body: AckRequest | None = None
) -> dict[str, Any]:
    """Acknowledge an alarm (operator token); recorded in the audit log with the operator's note.

    Every connected browser hears of it as a live ``alarm`` event with
    ``state: "acked"`` (not stored: the alarm row itself records the ack).
    """
    alarm = store.ack_alarm(alarm_id, who, body.note if body else "")
    if alarm is None:
        raise NotFound(f"no alarm {alarm_id}")
    out = queries.alarm_dict(alarm)
    payload = {"alarm_id": out["id"], "state": "acked", **out}
    hub.deliver_threadsafe(Event(EventKind.ALARM, payload, time.time(), out["module"]))
    return out


@router.get("/api/audit", response_model=list[AuditEntryPublic])
def audit(
    store: StoreDep,
    limit: Annotated[int, Query(ge=1, le=5000)] = 500,
    offset: Annotated[int, Query(ge=0, le=10_000_000)] = 0,
) -> list[dict[str, Any]]:
    """The append-only audit log: commands, acknowledgements, calibration changes."""

    return store.call(queries.audit, limit, offset)
