"""The ingest's events: one type for the ingest that makes them, the store that keeps them, the
server that relays them and ``camcal doctor`` that listens for them.

An event is ``{id, kind, t, module, dive_id, payload}``. Stored kinds get the
id of their row in the event log (a subscriber that sees ids jump reads the
missing ones from the store); transient kinds (``health``, ``sensors``,
``attitude``) carry ``id`` null and may be lost without harm. On the wire
(ZeroMQ PUB) an event is ``[kind, json]``; its JSON is strict (a value that
is not a finite number is ``null``). Each kind's payload is a `TypedDict`
below; docs/protocol.md lists them (a test keeps the two in step).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any, TypedDict


class EventKind(StrEnum):
    FRAME = "frame"
    RESULT = "result"
    ATTENUATION = "attenuation"
    ALARM = "alarm"
    LINK = "link"
    GAP = "gap"
    GAP_FILLED = "gap_filled"
    COMMAND = "command"
    RETENTION = "retention"
    HEALTH = "health"
    SENSORS = "sensors"
    ATTITUDE = "attitude"


#: Kinds that are never stored (``id`` null): the next one replaces them.
TRANSIENT_KINDS = frozenset({EventKind.HEALTH, EventKind.SENSORS, EventKind.ATTITUDE})


class FramePayload(TypedDict, total=False):
    """A frame stored (written with the frame, in its transaction)."""

    frame_id: int
    module: str
    boot: str
    seq: int
    captured_unix_s: float
    wavelength_nm: int
    exposure_s: float
    gain_db: float
    depth_m: float | None
    width_px: int
    height_px: int
    schedule_version: int
    stored_latency_s: float


class ResultPayload(TypedDict, total=False):
    """A frame analysed: its status and, when accepted, I_center."""

    frame_id: int
    seq: int
    wavelength_nm: int
    exposure_s: float
    gain_db: float
    depth_m: float | None
    captured_unix_s: float
    captured_ship_unix_s: float | None  # on the ship's clock (`camcal.core.clockmap`)
    status: str
    reason: str | None
    centroid_px: list[float] | None
    radius_px: float | None
    i_center_gray: float | None
    i_center_err_gray: float | None
    background_gray: float | None
    width_px: int | None
    height_px: int | None
    thumb: str
    analysis_s: float | None


class AttenuationPayload(TypedDict, total=False):
    """A λ_att point of a LEM visit, new or updated (``deleted`` when the visit is gone)."""

    point_id: int | None
    visit_key: str
    deleted: bool
    run_id: int
    wavelength_nm: int
    t_unix_s: float
    t_first_unix_s: float
    t_last_unix_s: float
    depth_m: float | None
    lambda_att_m: float | None
    stat_err_m: float | None
    sys_err_m: float | None
    n_pairs: int
    n_frames: int
    chi2_ndof: float | None
    window_s: float
    final: bool


class AlarmPayload(TypedDict, total=False):
    alarm_id: int
    state: str  # raised, cleared, acked
    kind: str
    severity: str
    message: str


class LinkPayload(TypedDict):
    state: str  # up, down
    reason: str | None


class GapPayload(TypedDict, total=False):
    boot: str
    first_seq: int
    last_seq: int
    reason: str  # link_lost, when the module's last_seq says what never came


class GapFilledPayload(TypedDict):
    gap_id: int
    boot: str


class CommandPayload(TypedDict, total=False):
    command_id: str
    state: str
    reason: str | None
    action: str
    target_version: int


class RetentionPayload(TypedDict):
    files: int
    bytes: int
    older_than_days: float


#: The payload of each kind (``health``, ``sensors`` and ``attitude`` are documented where they are made:
#: `ingest.service.IngestService.health`, `camcal.core.wire.sensors`, `ingest.housekeeping`).
PAYLOADS: dict[EventKind, type] = {
    EventKind.FRAME: FramePayload,
    EventKind.RESULT: ResultPayload,
    EventKind.ATTENUATION: AttenuationPayload,
    EventKind.ALARM: AlarmPayload,
    EventKind.LINK: LinkPayload,
    EventKind.GAP: GapPayload,
    EventKind.GAP_FILLED: GapFilledPayload,
    EventKind.COMMAND: CommandPayload,
    EventKind.RETENTION: RetentionPayload,
}

#: The payload of a stored event: one of the kinds' `TypedDict`s.
StoredPayload = (
    FramePayload
    | ResultPayload
    | AttenuationPayload
    | AlarmPayload
    | LinkPayload
    | GapPayload
    | GapFilledPayload
    | CommandPayload
    | RetentionPayload
)


class EventError(ValueError):
    """A message that is not an event (not JSON, not an object, an unknown kind)."""


@dataclass
class Event:
    """One event. ``id`` is set once it is stored (None for transient kinds)."""

    kind: EventKind
    payload: dict[str, Any]
    t: float
    module: str | None = None
    dive_id: int | None = None
    id: int | None = None
    _json: bytes | None = field(default=None, repr=False, compare=False)

    @property
    def stored(self) -> bool:
        return self.kind not in TRANSIENT_KINDS

    def as_dict(self) -> dict[str, Any]:
        """The event as the API and the wire give it (payload made strict JSON)."""
        return {
            "id": self.id,
            "kind": str(self.kind),
            "t": self.t,
            "module": self.module,
            "dive_id": self.dive_id,
            "payload": finite_json(self.payload),
        }

    def to_json(self) -> bytes:
        """The wire body: strict, compact JSON."""
        return json.dumps(self.as_dict(), separators=(",", ":"), default=str, allow_nan=False).encode()

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Event:
        try:
            kind = EventKind(str(d.get("kind")))
        except ValueError:
            raise EventError(f"unknown event kind {d.get('kind')!r}") from None
        payload = d.get("payload") or {}
        if not isinstance(payload, dict):
            raise EventError("an event's payload must be an object")
        eid, dive = d.get("id"), d.get("dive_id")
        return cls(
            kind=kind,
            payload=payload,
            t=float(d.get("t") or 0.0),
            module=d.get("module"),
            dive_id=int(dive) if isinstance(dive, int) else None,
            id=int(eid) if isinstance(eid, int) and not isinstance(eid, bool) else None,
        )

    @classmethod
    def from_json(cls, body: bytes | str) -> Event:
        """An event from its wire body; `EventError` if it is not one."""
        try:
            d = json.loads(body)
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise EventError(f"not JSON: {exc}") from None
        if not isinstance(d, dict):
            raise EventError("an event must be a JSON object")
        return cls.from_dict(d)


def finite_json(value: Any) -> Any:
    """``value`` with every float that is not finite replaced by None (strict JSON allows no NaN)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: finite_json(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [finite_json(v) for v in value]
    return value
