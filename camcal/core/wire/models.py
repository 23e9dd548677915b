"""Every message of the module protocol as a strict model: types, units, ranges, lengths.

The models are the protocol: ``docs/protocol-v1.schema.json`` is generated
from them (`camcal.core.wire.schema`) and ``docs/protocol.md`` explains them. A
header field that is missing, of another JSON type, out of its range or too
long makes the message ``invalid_field``. Unknown fields are ignored, so a
later minor version can add fields without breaking older ships.
"""

from __future__ import annotations

import re
from datetime import UTC, datetime
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, BaseModel, BeforeValidator, ConfigDict, Field, Strict, model_validator

from camcal.core.wire.limits import (
    INT_MAX,
    MAX_SENSOR_ROWS,
    SENT_AT_MIN,
    TIME_MAX,
    TIME_MIN,
)
from camcal.core.wire.sensors import SENSOR_COLUMNS

PROTOCOL_VERSION: Literal[1] = 1
ID_PATTERN = r"^[A-Za-z0-9_.-]*[A-Za-z0-9_-][A-Za-z0-9_.-]*$"  # at least one character not a dot
_ID_RE = re.compile(ID_PATTERN)
_SEGMENT = r"[^/\\\x00]*[^/\\\x00.][^/\\\x00]*"  # a path segment that is not only dots
#: A frame's file inside the module's frame set: relative, ``/``-separated, no ``.``/``..`` segments.
FILE_PATTERN = rf"^{_SEGMENT}(?:/{_SEGMENT})*$"


def is_id(v: object) -> bool:
    """Whether ``v`` is a valid identifier (module, boot, camera, command)."""
    # fullmatch: ``$`` alone would let a final newline through ("B\n"), which the models refuse.
    return isinstance(v, str) and 1 <= len(v) <= 64 and _ID_RE.fullmatch(v) is not None


def utc_now() -> datetime:
    return datetime.now(UTC)


def _number(v: Any) -> Any:
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise ValueError("must be a JSON number")
    return v


def _timestamp(v: Any) -> Any:
    if isinstance(v, datetime):
        return v
    if not isinstance(v, str) or len(v) > 40:
        raise ValueError("must be an ISO-8601 date and time string, e.g. 2026-11-25T02:16:37.5Z")
    return v


def _in_window(v: datetime, low: datetime = TIME_MIN) -> datetime:
    if v.tzinfo is None:  # no offset: UTC, as the protocol says
        v = v.replace(tzinfo=UTC)
    if not low <= v < TIME_MAX:
        unset = " (the module's clock is not set: set it from the ship, NTP)" if v < TIME_MIN else ""
        raise ValueError(f"must be between {low:%Y-%m-%d} and {TIME_MAX:%Y-%m-%d} (UTC){unset}")
    return v.astimezone(UTC)


def _sent_at_window(v: datetime) -> datetime:
    return _in_window(v, SENT_AT_MIN)


#: An identifier: 1-64 letters, digits, ``_``, ``.``, ``-``, and not only dots.
Id = Annotated[str, Strict(), Field(min_length=1, max_length=64, pattern=ID_PATTERN)]
#: A sequence number of a boot: 1 .. 2^63-1.
Seq = Annotated[int, Strict(), Field(ge=1, le=INT_MAX)]
#: A count: 0 .. 2^63-1.
Count = Annotated[int, Strict(), Field(ge=0, le=INT_MAX)]
#: A schedule version: 0 .. 2^31-1 (operators number them 1, 2, 3, ...).
Version = Annotated[int, Strict(), Field(ge=0, le=2**31 - 1)]
#: Time as ISO-8601 text (UTC; an offset is converted, none means UTC), 2000-01-01 .. 2100-01-01.
Timestamp = Annotated[
    datetime,
    Field(
        description="ISO-8601 date and time, UTC (Z or an offset; none means UTC), 2000-01-01 to 2100-01-01"
    ),
    BeforeValidator(_timestamp),
    AfterValidator(_in_window),
]
#: When a message was sent, by its sender's clock: as `Timestamp`, but from 1970-01-01 (revision
#: 1.5): a module whose clock was never set links all the same, and the ship raises its clock alarm.
SentAt = Annotated[
    datetime,
    Field(
        description="ISO-8601 date and time, UTC (Z or an offset; none means UTC), 1970-01-01 to 2100-01-01"
    ),
    BeforeValidator(_timestamp),
    AfterValidator(_sent_at_window),
]
#: A finite JSON number (integer or fraction); each field adds its bounds.
_NUMBER = BeforeValidator(_number)
#: A dive's name as the ship records it (``camcal ingest --dive NAME``): text, no control characters.
DiveName = Annotated[str, Strict(), Field(min_length=1, max_length=120, pattern=r"^[^\x00-\x1f\x7f]+$")]


class _Header(BaseModel):
    model_config = ConfigDict(extra="ignore", frozen=True)
    v: Literal[1] = PROTOCOL_VERSION
    module: Id
    sent_at: SentAt = Field(default_factory=utc_now)


class _ModuleHeader(_Header):
    """What every message of a module may carry besides: the dive it was started for."""

    #: The dive the module was started for (``--dive``); the ship refuses the message (``wrong_dive``)
    #: if it records another. Absent: the module goes with whatever dive the ship records.
    dive: DiveName | None = None


class ScheduleState(BaseModel):
    """Which schedule a module runs, and whether it is running."""

    model_config = ConfigDict(extra="ignore", frozen=True)
    name: Annotated[str, Strict(), Field(max_length=80)] = ""
    version: Version = 0
    state: Literal["running", "paused", "stopped", "idle"] = "idle"


_Exposure = Annotated[float, Field(gt=0, le=3600, allow_inf_nan=False), _NUMBER]
_Gain = Annotated[float, Field(ge=-100, le=100, allow_inf_nan=False), _NUMBER]
#: Significant bits per pixel: 8 (an 8-bit image), or 9 to 16 (a 16-bit image, MSB-aligned).
BitDepth = Annotated[int, Strict(), Field(ge=8, le=16)]


class CameraInfo(BaseModel):
    """What a module's camera is and what it can take, as the camera itself says (revision 1.8).

    The ship checks a schedule for the module against these ranges (its own default limits
    otherwise) and the control page shows them.
    """

    model_config = ConfigDict(extra="ignore", frozen=True)
    model: Annotated[str, Strict(), Field(max_length=120)] = ""
    serial: Annotated[str, Strict(), Field(max_length=64)] = ""
    pixel_format: Annotated[str, Strict(), Field(max_length=40)] = ""
    bit_depth: BitDepth = 8
    width_px: Annotated[int, Strict(), Field(ge=1, le=65535)] | None = None
    height_px: Annotated[int, Strict(), Field(ge=1, le=65535)] | None = None
    exposure_range_s: tuple[_Exposure, _Exposure]
    gain_range_db: tuple[_Gain, _Gain]
    gain_step_db: Annotated[float, Field(ge=0, le=100, allow_inf_nan=False), _NUMBER] = 0.0

    @model_validator(mode="after")
    def _ordered(self) -> CameraInfo:
        for name in ("exposure_range_s", "gain_range_db"):
            lo, hi = getattr(self, name)
            if lo > hi:
                raise ValueError(f"{name}: the minimum {lo} exceeds the maximum {hi}")
        return self


class SimulatedClock(BaseModel):
    """A simulated module's clock (revision 1.10): it runs ``rate`` times as fast as real time and
    reads ``reads`` at real time ``at`` (the simulation's own definition, not its clock's readings:
    a simulated clock error shows as an offset, as a real one does)."""

    model_config = ConfigDict(extra="ignore", frozen=True)
    rate: Annotated[float, Field(gt=0, le=10000, allow_inf_nan=False), _NUMBER]
    reads: SentAt
    at: SentAt


# ------------------------------------------------------------ module -> ship
class Hello(_ModuleHeader):
    """First message after (re)connecting; repeated until the ship answers ``welcome``.

    ``clock`` (revision 1.10): a simulated module's clock, which stamps ``sent_at``, its captures and
    samples, runs faster than real time; a real module leaves it out (its clock runs at the ship's
    rate). The ship maps the module's times onto its own from this and the offset it measures at
    each heartbeat (`camcal.core.clockmap`).
    """

    type: Literal["hello"] = "hello"
    boot: Id
    software: Annotated[str, Strict(), Field(max_length=120)] = ""
    schedule: ScheduleState = ScheduleState()
    outbox_pending: Count = 0
    last_seq: Count = 0
    #: The module's camera and its ranges (revision 1.8; absent: a module that does not say).
    camera: CameraInfo | None = None
    clock: SimulatedClock | None = None


class FrameMsg(_ModuleHeader):
    """One camera frame; the payload is the encoded image (8- or 16-bit grayscale PNG or TIFF)."""

    type: Literal["frame"] = "frame"
    boot: Id
    seq: Seq
    captured_at: Timestamp
    camera: Id
    wavelength_nm: Annotated[int, Strict(), Field(ge=200, le=2000)]
    exposure_s: _Exposure
    gain_db: _Gain
    depth_m: Annotated[float, Field(ge=-1000, le=12000, allow_inf_nan=False), _NUMBER] | None = None
    width_px: Annotated[int, Strict(), Field(ge=1, le=65535)]
    height_px: Annotated[int, Strict(), Field(ge=1, le=65535)]
    encoding: Literal["png", "tiff"] = "png"
    #: Significant bits per pixel (revision 1.8): 8, or 9-16 for a 16-bit image (fewer than 16: the
    #: values MSB-aligned and a PNG's sBIT chunk saying how many). Its full scale is the saturation.
    bit_depth: BitDepth = 8
    size: Annotated[int, Strict(), Field(ge=1, le=INT_MAX)]
    sha256: Annotated[str, Strict(), Field(pattern=r"^[0-9a-f]{64}$")]
    schedule_version: Version = 0
    file: Annotated[str, Strict(), Field(min_length=1, max_length=255, pattern=FILE_PATTERN)] | None = None


class SensorsMsg(_ModuleHeader):
    """A batch of sensor samples; the payload is a JSON array of rows in ``columns`` order."""

    type: Literal["sensors"] = "sensors"
    boot: Id
    seq: Seq
    columns: Annotated[
        tuple[Annotated[str, Strict(), Field(max_length=64)], ...], Field(min_length=1, max_length=64)
    ] = SENSOR_COLUMNS
    count: Annotated[int, Strict(), Field(ge=0, le=MAX_SENSOR_ROWS)]
    size: Annotated[int, Strict(), Field(ge=1, le=INT_MAX)]
    sha256: Annotated[str, Strict(), Field(pattern=r"^[0-9a-f]{64}$")]


class Waiting(BaseModel):
    """Why a running module takes no picture now, and how long it expects that to last (revision 1.10).

    ``not_here``: captures are off where it is (on deck, on the way down or up: its schedule takes
    pictures at the stops and on station only); ``lem``: it waits for the LEM to show
    ``wavelength_nm``; ``pause``: the pause between two passes of its schedule. ``for_s`` is the
    wait left, in seconds of real time.
    """

    model_config = ConfigDict(extra="ignore", frozen=True)
    reason: Literal["not_here", "lem", "pause"]
    for_s: Annotated[float, Field(ge=0, le=10**7, allow_inf_nan=False), _NUMBER] = 0.0
    wavelength_nm: Annotated[int, Strict(), Field(ge=200, le=2000)] | None = None


class ModuleHeartbeat(_ModuleHeader):
    """Sent every second or so; tells the ship the module lives and what it runs."""

    type: Literal["heartbeat"] = "heartbeat"
    boot: Id
    schedule: ScheduleState = ScheduleState()
    outbox_pending: Count = 0
    in_flight: Count = 0
    last_seq: Count = 0
    #: Frames and sensor messages not taken since the boot because the SD card could not keep them
    #: (full, failing): nothing is sent that is not on the card first.
    card_skipped: Count = 0
    card_error: Annotated[str, Strict(), Field(max_length=200)] | None = None
    #: Camera captures and sensor reads that failed since the boot (the module retries them), and
    #: the last failure of each.
    capture_errors: Count = 0
    camera_error: Annotated[str, Strict(), Field(max_length=200)] | None = None
    sensor_errors: Count = 0
    sensor_error: Annotated[str, Strict(), Field(max_length=200)] | None = None
    #: Shots the schedule runner took at a later turn of their colour since the boot, because the
    #: LEM moved on (or was about to) amid a wavelength's shots: a schedule longer than the LEM shows
    #: a colour, or a module running slow (revision 1.6).
    deferred_shots: Count = 0
    #: The module's camera and its ranges, as in ``hello`` (revision 1.8): a camera swapped or
    #: reconfigured while the link is up.
    camera: CameraInfo | None = None
    #: Why it takes no picture now, while its schedule runs (revision 1.10; None: it is taking them).
    waiting: Waiting | None = None


class CommandStatus(_ModuleHeader):
    """The module's answer to a command."""

    type: Literal["command_status"] = "command_status"
    boot: Id
    command_id: Id
    state: Literal["accepted", "rejected", "in_progress", "done"]
    reason: Annotated[str, Strict(), Field(max_length=500)] | None = None
    schedule: ScheduleState = ScheduleState()


class Bye(_ModuleHeader):
    """The module shuts down cleanly (the ship shows it as signed off, not as a lost link)."""

    type: Literal["bye"] = "bye"
    boot: Id


# ------------------------------------------------------------ ship -> module
class Welcome(_Header):
    """The ship's answer to ``hello``: its clock, the initial window, and which ingest and dive it is.

    ``ingest`` (a new id at every start of the ingest) and ``dive`` (the name
    of the dive it records into) let a module check that it streams into the
    dive it was started for (schema revision 1.2; absent from older ships).
    """

    type: Literal["welcome"] = "welcome"
    ship_time: Timestamp = Field(default_factory=utc_now)
    window: Annotated[int, Strict(), Field(ge=1, le=65535)]
    heartbeat_s: Annotated[float, Field(gt=0, le=3600, allow_inf_nan=False), _NUMBER] = 1.0
    ingest: Id | None = None
    dive: DiveName | None = None


class Ack(_Header):
    """Data messages now committed on the ship: ranges ``[boot, first_seq, last_seq]``."""

    type: Literal["ack"] = "ack"
    ranges: tuple[tuple[Id, Seq, Seq], ...]
    window: Annotated[int, Strict(), Field(ge=1, le=65535)]


class Nack(_Header):
    """A message the ship refused, with why (`camcal.core.wire.reasons`) and whether resending can help.

    ``boot`` and ``seq`` identify the refused data message where the ship
    could read them; ``of`` is the refused message's type where known.
    """

    type: Literal["nack"] = "nack"
    boot: Id | None = None
    seq: Seq | None = None
    of: Annotated[str, Strict(), Field(max_length=40)] | None = None
    reason: Annotated[str, Strict(), Field(pattern=r"^[a-z_]{1,40}$")]
    retry: bool = False
    detail: Annotated[str, Strict(), Field(max_length=500)] = ""


class ShipHeartbeat(_Header):
    """The ship lives; ``window`` is the current credit."""

    type: Literal["ship_heartbeat"] = "ship_heartbeat"
    ship_time: Timestamp = Field(default_factory=utc_now)
    window: Annotated[int, Strict(), Field(ge=1, le=65535)]


class Command(_Header):
    """An operator's command to a module (see ``docs/protocol.md``)."""

    type: Literal["command"] = "command"
    command_id: Id
    action: Literal["set_schedule", "start", "pause", "resume", "stop"]
    target_version: Version = 0
    schedule: dict[str, Any] | None = None
    apply: Literal["now", "end_of_setting"] = "now"
    issued_by: Annotated[str, Strict(), Field(max_length=120)] = ""
    issued_at: Timestamp = Field(default_factory=utc_now)


MODULE_MESSAGES = (Hello, FrameMsg, SensorsMsg, ModuleHeartbeat, CommandStatus, Bye)
SHIP_MESSAGES = (Welcome, Ack, Nack, ShipHeartbeat, Command)
DATA_TYPES = frozenset({"frame", "sensors"})
MODULE_TYPES = frozenset(m.model_fields["type"].default for m in MODULE_MESSAGES)
SHIP_TYPES = frozenset(m.model_fields["type"].default for m in SHIP_MESSAGES)
