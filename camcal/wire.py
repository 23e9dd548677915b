"""The wire protocol between the modules (LRMs) and the ship: one home for both sides.

ZeroMQ DEALER (module) to ROUTER (ship) over TCP. Every message is a
multipart message of one UTF-8 JSON header and at most one binary payload.
``docs/protocol.md`` describes it for someone writing a module in another
language; this module is the reference implementation. JSON headers and raw
bytes only: never pickle.
"""

from __future__ import annotations

import hashlib
import json
import re
from datetime import UTC, datetime
from typing import Annotated, Any, Literal

import zmq
from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, ValidationError, field_validator

PROTOCOL_VERSION: Literal[1] = 1
#: Largest header accepted (bytes of JSON).
MAX_HEADER_BYTES = 64 * 1024
#: Largest payload accepted by default: a 5 MP PNG is ~2 MB, an uncompressed one 5 MB.
MAX_PAYLOAD_BYTES = 32 * 1024 * 1024
#: Columns of a sensor sample row, in order (the payload of a ``sensors`` message).
SENSOR_COLUMNS: tuple[str, ...] = (
    "t_unix_s",
    "temperature_c",
    "humidity_pct",
    "acc_x_m_s2",
    "acc_y_m_s2",
    "acc_z_m_s2",
    "gyro_x_dps",
    "gyro_y_dps",
    "gyro_z_dps",
    "depth_m",
)
_ID = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")


class ProtocolError(Exception):
    """A message that cannot be accepted. ``kind`` is the counter it goes to."""

    def __init__(self, kind: str, detail: str) -> None:
        super().__init__(f"{kind}: {detail}")
        self.kind = kind
        self.detail = detail


def utc_now() -> datetime:
    return datetime.now(UTC)


def _check_id(v: str) -> str:
    if not _ID.match(v):
        raise ValueError("must be 1-64 characters of letters, digits, '_', '.', '-'")
    return v


class _Header(BaseModel):
    model_config = ConfigDict(extra="ignore", frozen=True)
    v: Literal[1] = PROTOCOL_VERSION
    module: str
    sent_at: datetime = Field(default_factory=utc_now)

    _module = field_validator("module")(_check_id)


class ScheduleState(BaseModel):
    """Which schedule a module runs, and whether it is running."""

    model_config = ConfigDict(extra="ignore", frozen=True)
    name: str = ""
    version: int = 0
    state: Literal["running", "paused", "stopped", "idle"] = "idle"


# ------------------------------------------------------------ module -> ship
class Hello(_Header):
    """First message after (re)connecting; repeated until the ship answers ``welcome``."""

    type: Literal["hello"] = "hello"
    boot: str
    software: str = ""
    schedule: ScheduleState = ScheduleState()
    outbox_pending: int = Field(0, ge=0)
    last_seq: int = Field(0, ge=0)

    _boot = field_validator("boot")(_check_id)


class FrameMsg(_Header):
    """One camera frame; the payload is the encoded image (PNG)."""

    type: Literal["frame"] = "frame"
    boot: str
    seq: int = Field(ge=1)
    captured_at: datetime
    camera: str
    wavelength_nm: int = Field(gt=0)
    exposure_s: float = Field(gt=0)
    gain_db: float
    depth_m: float | None = None
    width_px: int = Field(gt=0)
    height_px: int = Field(gt=0)
    encoding: Literal["png", "tiff"] = "png"
    size: int = Field(ge=0)
    sha256: str = Field(pattern=r"^[0-9a-f]{64}$")
    schedule_version: int = Field(0, ge=0)
    file: str | None = None

    _boot = field_validator("boot")(_check_id)


class SensorsMsg(_Header):
    """A batch of sensor samples; the payload is a JSON array of rows in ``columns`` order."""

    type: Literal["sensors"] = "sensors"
    boot: str
    seq: int = Field(ge=1)
    columns: tuple[str, ...] = SENSOR_COLUMNS
    count: int = Field(ge=0, le=100_000)
    size: int = Field(ge=0)
    sha256: str = Field(pattern=r"^[0-9a-f]{64}$")

    _boot = field_validator("boot")(_check_id)


class ModuleHeartbeat(_Header):
    """Sent every second or so; tells the ship the module lives and what it runs."""

    type: Literal["heartbeat"] = "heartbeat"
    boot: str
    schedule: ScheduleState = ScheduleState()
    outbox_pending: int = Field(0, ge=0)
    in_flight: int = Field(0, ge=0)
    last_seq: int = Field(0, ge=0)

    _boot = field_validator("boot")(_check_id)


class CommandStatus(_Header):
    """The module's answer to a command."""

    type: Literal["command_status"] = "command_status"
    boot: str
    command_id: str
    state: Literal["accepted", "rejected", "in_progress", "done"]
    reason: str | None = None
    schedule: ScheduleState = ScheduleState()


class Bye(_Header):
    """The module shuts down cleanly."""

    type: Literal["bye"] = "bye"
    boot: str


# ------------------------------------------------------------ ship -> module
class Welcome(_Header):
    """The ship's answer to ``hello``: its clock and the initial window."""

    type: Literal["welcome"] = "welcome"
    ship_time: datetime = Field(default_factory=utc_now)
    window: int = Field(ge=1)
    heartbeat_s: float = Field(1.0, gt=0)


class Ack(_Header):
    """Data messages now committed on the ship: ranges ``[boot, first_seq, last_seq]``."""

    type: Literal["ack"] = "ack"
    ranges: tuple[tuple[str, int, int], ...]
    window: int = Field(ge=1)


class Nack(_Header):
    """A data message the ship could not accept as sent (e.g. checksum): send it again."""

    type: Literal["nack"] = "nack"
    boot: str
    seq: int = Field(ge=1)
    reason: str


class ShipHeartbeat(_Header):
    """The ship lives; ``window`` is the current credit."""

    type: Literal["ship_heartbeat"] = "ship_heartbeat"
    ship_time: datetime = Field(default_factory=utc_now)
    window: int = Field(ge=1)


class Command(_Header):
    """An operator's command to a module (see ``docs/protocol.md``)."""

    type: Literal["command"] = "command"
    command_id: str
    action: Literal["set_schedule", "start", "pause", "resume", "stop"]
    target_version: int = Field(0, ge=0)
    schedule: dict[str, Any] | None = None
    apply: Literal["now", "end_of_setting"] = "now"
    issued_by: str = ""
    issued_at: datetime = Field(default_factory=utc_now)


Message = Annotated[
    Hello
    | FrameMsg
    | SensorsMsg
    | ModuleHeartbeat
    | CommandStatus
    | Bye
    | Welcome
    | Ack
    | Nack
    | ShipHeartbeat
    | Command,
    Field(discriminator="type"),
]
_ADAPTER: TypeAdapter[Any] = TypeAdapter(Message)
DATA_TYPES = frozenset({"frame", "sensors"})
MODULE_TYPES = frozenset({"hello", "frame", "sensors", "heartbeat", "command_status", "bye"})
SHIP_TYPES = frozenset({"welcome", "ack", "nack", "ship_heartbeat", "command"})


def sha256_hex(data: bytes | memoryview) -> str:
    return hashlib.sha256(data).hexdigest()


def encode(message: BaseModel, payload: bytes | memoryview | None = None) -> list[bytes | memoryview]:
    """The frames of a message: the JSON header, then the payload if any."""
    header = message.model_dump_json(exclude_none=True).encode()
    return [header] if payload is None else [header, payload]


def decode(
    frames: list[bytes] | list[zmq.Frame],
    *,
    allowed: frozenset[str] | None = None,
    max_payload_bytes: int = MAX_PAYLOAD_BYTES,
) -> tuple[Any, memoryview | None]:
    """Parse and check one message; raise `ProtocolError` naming what is wrong.

    Checks, in order: one or two frames; header size; header is a JSON object;
    protocol version; known type (and one ``allowed`` here); fields valid;
    payload present exactly when the type has one, within size, and matching
    the header's ``size`` and ``sha256``.
    """
    if not 1 <= len(frames) <= 2:
        raise ProtocolError("bad_framing", f"expected 1 or 2 frames, got {len(frames)}")
    raw = [f.buffer if isinstance(f, zmq.Frame) else memoryview(f) for f in frames]
    head = raw[0]
    if len(head) > MAX_HEADER_BYTES:
        raise ProtocolError("oversized", f"header of {len(head)} bytes exceeds {MAX_HEADER_BYTES}")
    try:
        obj = json.loads(bytes(head))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ProtocolError("bad_header", f"header is not JSON: {exc}") from None
    if not isinstance(obj, dict):
        raise ProtocolError("bad_header", "header is not a JSON object")
    if obj.get("v") != PROTOCOL_VERSION:
        raise ProtocolError("bad_version", f"protocol version {obj.get('v')!r} (this side speaks 1)")
    kind = obj.get("type")
    if not isinstance(kind, str) or kind not in MODULE_TYPES | SHIP_TYPES:
        raise ProtocolError("unknown_type", f"message type {kind!r}")
    if allowed is not None and kind not in allowed:
        raise ProtocolError("unknown_type", f"message type {kind!r} not accepted here")
    try:
        msg = _ADAPTER.validate_python(obj)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"][1:]) or "header"
        raise ProtocolError("invalid_field", f"{kind}: {where}: {first['msg']}") from None
    payload = raw[1] if len(raw) == 2 else None
    expects_payload = kind in DATA_TYPES
    if expects_payload != (payload is not None):
        raise ProtocolError(
            "bad_framing", f"{kind} {'needs' if expects_payload else 'takes no'} payload frame"
        )
    if payload is not None:
        if len(payload) > max_payload_bytes:
            raise ProtocolError("oversized", f"payload of {len(payload)} bytes exceeds {max_payload_bytes}")
        if len(payload) != msg.size:
            raise ProtocolError("bad_payload", f"payload has {len(payload)} bytes, header says {msg.size}")
        if sha256_hex(payload) != msg.sha256:
            raise ProtocolError("bad_payload", "payload sha256 does not match the header")
    return msg, payload


def sensors_payload(rows: list[list[float | None]]) -> bytes:
    """The JSON payload of a ``sensors`` message."""
    return json.dumps(rows, separators=(",", ":")).encode()


def parse_sensor_rows(msg: SensorsMsg, payload: memoryview | bytes) -> list[dict[str, float | None]]:
    """Rows of a ``sensors`` payload as dicts keyed by column; raises `ProtocolError`."""
    try:
        rows = json.loads(bytes(payload))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ProtocolError("bad_payload", f"sensor payload is not JSON: {exc}") from None
    if not isinstance(rows, list) or len(rows) != msg.count:
        raise ProtocolError("bad_payload", f"expected a list of {msg.count} rows")
    out = []
    width = len(msg.columns)
    for row in rows:
        if not isinstance(row, list) or len(row) != width:
            raise ProtocolError("bad_payload", f"sensor row must have {width} values")
        if not all(v is None or (isinstance(v, int | float) and not isinstance(v, bool)) for v in row):
            raise ProtocolError("bad_payload", "sensor values must be numbers or null")
        out.append(dict(zip(msg.columns, row, strict=True)))
    return out


# ------------------------------------------------------------------ sockets
def ship_socket(
    ctx: zmq.Context[Any], endpoint: str, *, max_message_bytes: int = 2 * MAX_PAYLOAD_BYTES
) -> Any:
    """The ship's ROUTER, bound to ``endpoint`` (``tcp://*:PORT``).

    ``ROUTER_HANDOVER`` lets a module that reconnects (a new TCP connection
    under the same identity) take its identity over at once; ``MAXMSGSIZE``
    caps what a misbehaving peer can make the ship buffer.
    """
    sock = ctx.socket(zmq.ROUTER)
    sock.setsockopt(zmq.ROUTER_HANDOVER, 1)
    sock.setsockopt(zmq.ROUTER_MANDATORY, 0)
    sock.setsockopt(zmq.MAXMSGSIZE, max_message_bytes)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.RCVHWM, 1000)
    sock.setsockopt(zmq.SNDHWM, 1000)
    sock.bind(endpoint)
    return sock


def module_socket(ctx: zmq.Context[Any], endpoint: str, module: str) -> Any:
    """A module's DEALER, connected to the ship with the module id as its identity.

    ZeroMQ reconnects by itself after a broken link; ``IMMEDIATE`` keeps
    messages from queueing for a peer that is not connected (the outbox holds
    them instead), and ZMTP heartbeats detect a dead TCP link within seconds.
    """
    sock = ctx.socket(zmq.DEALER)
    sock.setsockopt(zmq.ROUTING_ID, module.encode())
    sock.setsockopt(zmq.IMMEDIATE, 1)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.SNDHWM, 64)
    sock.setsockopt(zmq.RECONNECT_IVL, 200)
    sock.setsockopt(zmq.RECONNECT_IVL_MAX, 2000)
    sock.setsockopt(zmq.HEARTBEAT_IVL, 1000)
    sock.setsockopt(zmq.HEARTBEAT_TIMEOUT, 3000)
    sock.connect(endpoint)
    return sock
