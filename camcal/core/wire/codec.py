"""Messages to frames and back: `encode`, and `decode`, which checks everything a message claims."""

from __future__ import annotations

import hashlib
from collections.abc import Generator
from typing import Annotated, Any

import zmq
from pydantic import BaseModel, Field, TypeAdapter, ValidationError

from camcal.core.wire import dialect, models, sensorrows, sensors
from camcal.core.wire.image import ImageHeaderError, check_frame
from camcal.core.wire.limits import MAX_HEADER_BYTES, MAX_PAYLOAD_BYTES
from camcal.core.wire.models import (
    DATA_TYPES,
    MODULE_TYPES,
    PROTOCOL_VERSION,
    SHIP_TYPES,
    SensorsMsg,
)

Message = Annotated[
    models.Hello
    | models.FrameMsg
    | models.SensorsMsg
    | models.ModuleHeartbeat
    | models.CommandStatus
    | models.Bye
    | models.Welcome
    | models.Ack
    | models.Nack
    | models.ShipHeartbeat
    | models.Command,
    Field(discriminator="type"),
]
ADAPTER: TypeAdapter[Any] = TypeAdapter(Message)
#: A sensor payload is a list of rows of numbers: depth 2.
_SENSOR_DEPTH = 2
#: Bytes of payload hashed per step of `check_payload`.
_HASH_STEP = 4 * 1024 * 1024


class ProtocolError(Exception):
    """A message that cannot be accepted. ``kind`` is its reason (`camcal.core.wire.reasons`).

    ``ref`` holds what could be read of the refused message (``type``,
    ``module``, ``boot``, ``seq``) so that the refusal can name it.
    """

    def __init__(self, kind: str, detail: str, ref: dict[str, Any] | None = None) -> None:
        super().__init__(f"{kind}: {detail}")
        self.kind = kind
        self.detail = detail
        self.ref = ref or {}


def sha256_hex(data: bytes | memoryview) -> str:
    return hashlib.sha256(data).hexdigest()


def encode(message: BaseModel, payload: bytes | memoryview | None = None) -> list[bytes | memoryview]:
    """The frames of a message: the JSON header, then the payload if any."""
    header = message.model_dump_json(exclude_none=True).encode()
    return [header] if payload is None else [header, payload]


def _ref(obj: dict[str, Any]) -> dict[str, Any]:
    """The parts of a refused header that are safe to echo back: well-formed ids and numbers only."""
    ref: dict[str, Any] = {}
    t = obj.get("type")
    if isinstance(t, str) and (t in MODULE_TYPES or t in SHIP_TYPES):
        ref["type"] = t
    for key in ("module", "boot"):
        v = obj.get(key)
        if models.is_id(v):
            ref[key] = v
    seq = obj.get("seq")
    if isinstance(seq, int) and not isinstance(seq, bool) and 1 <= seq <= dialect.INT_MAX:
        ref["seq"] = seq
    return ref


def decode(
    frames: list[bytes] | list[zmq.Frame] | list[bytes | memoryview],
    *,
    allowed: frozenset[str] | None = None,
    max_payload_bytes: int = MAX_PAYLOAD_BYTES,
) -> tuple[Any, Any]:
    """Parse and check one message; raise `ProtocolError` naming what is wrong.

    Checks, in order: one or two frames; header size; header is JSON of the
    protocol's dialect and an object; protocol version; known type (and one
    ``allowed`` here); fields valid; payload present exactly when the type
    has one, within size, matching the header's ``size`` and ``sha256``;
    a frame's image is 8-bit grayscale of the stated size; a sensor payload's
    rows are valid.

    Returns ``(message, payload)``: the image bytes for ``frame``, the
    checked rows (dicts keyed by every known column) for ``sensors``, None
    for the rest. Nothing but `ProtocolError` escapes, whatever the bytes.
    """
    msg, payload = decode_header(frames, allowed=allowed, max_payload_bytes=max_payload_bytes)
    if payload is None:
        return msg, None
    ref = message_ref(msg)
    if sha256_hex(payload) != msg.sha256:
        raise ProtocolError("bad_payload", "payload sha256 does not match the header", ref)
    if msg.type == "frame":
        _check_image(msg, payload, ref)
        return msg, payload
    return msg, _sensor_rows(msg, payload, ref)


def decode_header(
    frames: list[bytes] | list[zmq.Frame] | list[bytes | memoryview],
    *,
    allowed: frozenset[str] | None = None,
    max_payload_bytes: int = MAX_PAYLOAD_BYTES,
) -> tuple[Any, memoryview | None]:
    """The checks of `decode` that read the header only (and the payload's length); returns
    ``(message, payload)`` with the payload unchecked (`check_payload` checks it).

    Cheap whatever the payload: a ship's receiving thread runs it on every message and leaves the
    payload's checks (a checksum, an image header, up to 100 000 sensor rows) to `check_payload`.
    """
    if not 1 <= len(frames) <= 2:
        raise ProtocolError("bad_framing", f"expected 1 or 2 frames, got {len(frames)}")
    raw = [f.buffer if isinstance(f, zmq.Frame) else memoryview(f) for f in frames]
    head = raw[0]
    if len(head) > MAX_HEADER_BYTES:
        raise ProtocolError("oversized", f"header of {len(head)} bytes exceeds {MAX_HEADER_BYTES}")
    try:
        obj = dialect.loads(head, max_depth=dialect.MAX_HEADER_DEPTH)
    except dialect.DialectError as exc:
        raise ProtocolError("bad_header", f"header: {exc}") from None
    if not isinstance(obj, dict):
        raise ProtocolError("bad_header", "header is not a JSON object")
    ref = _ref(obj)
    version = obj.get("v")
    if type(version) is not int or version != PROTOCOL_VERSION:  # not 1.0, not true: no coercion
        raise ProtocolError(
            "bad_version", f"protocol version {str(version)[:20]!r} (this side speaks 1)", ref
        )
    kind = obj.get("type")
    if not isinstance(kind, str) or kind not in MODULE_TYPES | SHIP_TYPES:
        raise ProtocolError("unknown_type", f"message type {str(kind)[:40]!r}", ref)
    if allowed is not None and kind not in allowed:
        raise ProtocolError("unknown_type", f"message type {kind!r} not accepted here", ref)
    try:
        msg = ADAPTER.validate_python(obj)
    except ValidationError as exc:
        first = exc.errors(include_url=False)[0]
        where = ".".join(str(p) for p in first["loc"][1:]) or "header"
        raise ProtocolError("invalid_field", f"{kind}: {where}: {first['msg']}"[:300], ref) from None
    payload = raw[1] if len(raw) == 2 else None
    expects_payload = kind in DATA_TYPES
    if expects_payload != (payload is not None):
        raise ProtocolError(
            "bad_framing", f"{kind} {'needs' if expects_payload else 'takes no'} payload frame", ref
        )
    if payload is None:
        return msg, None
    if len(payload) > max_payload_bytes:
        raise ProtocolError("oversized", f"payload of {len(payload)} bytes exceeds {max_payload_bytes}", ref)
    if len(payload) != msg.size:
        raise ProtocolError("bad_payload", f"payload has {len(payload)} bytes, header says {msg.size}", ref)
    return msg, payload


def check_payload(msg: Any, payload: memoryview | bytes) -> Generator[None, None, Any]:
    """The payload checks of `decode`, in steps (a generator: each ``next`` does a few milliseconds of
    work); returns the image bytes of a ``frame``, or the rows of a ``sensors`` message as an array
    (`camcal.core.wire.sensorrows.rows_array`). Raises `ProtocolError` naming what is wrong."""
    ref = message_ref(msg)
    digest = hashlib.sha256()
    view = memoryview(payload)
    for at in range(0, len(view), _HASH_STEP):
        digest.update(view[at : at + _HASH_STEP])
        yield
    if digest.hexdigest() != msg.sha256:
        raise ProtocolError("bad_payload", "payload sha256 does not match the header", ref)
    if msg.type == "frame":
        _check_image(msg, payload, ref)
        return payload
    problem = sensors.check_columns(msg.columns)
    if problem:
        raise ProtocolError("invalid_field", f"sensors: {problem}", ref)
    try:
        return (yield from sensorrows.check_steps(msg.columns, payload, msg.count))
    except sensorrows.PayloadError as exc:
        raise ProtocolError("invalid_field", f"sensors payload: {exc}"[:300], ref) from None


#: A data message's fields that are not its data: a resend may differ in them and still be the same.
_TRANSPORT_FIELDS = frozenset({"v", "type", "module", "sent_at", "dive"})


def content_sha256(msg: Any) -> str:
    """What makes two data messages the same message: the SHA-256 of every header field but the
    transport's (`_TRANSPORT_FIELDS`: version, type, module, when it was sent, the dive), the payload's
    checksum among them. A resend of ``(module, boot, seq)`` whose content differs is a ``conflict``."""
    fields = msg.model_dump(mode="json", exclude=set(_TRANSPORT_FIELDS))
    return hashlib.sha256(dialect.dumps(dict(sorted(fields.items())))).hexdigest()


def message_ref(msg: Any) -> dict[str, Any]:
    """What names a message in its refusal: type, module, boot, seq (where it has them)."""
    return {
        "type": msg.type,
        "module": msg.module,
        "boot": getattr(msg, "boot", None),
        "seq": getattr(msg, "seq", None),
    }


def _check_image(msg: Any, payload: memoryview | bytes, ref: dict[str, Any]) -> None:
    try:
        check_frame(payload, msg.encoding, msg.width_px, msg.height_px, msg.bit_depth)
    except ImageHeaderError as exc:
        raise ProtocolError("bad_image", str(exc), ref) from None


def _sensor_rows(msg: SensorsMsg, payload: memoryview | bytes, ref: dict[str, Any]) -> list[dict[str, Any]]:
    problem = sensors.check_columns(msg.columns)
    if problem:
        raise ProtocolError("invalid_field", f"sensors: {problem}", ref)
    try:
        rows = dialect.loads(payload, max_depth=_SENSOR_DEPTH)
        return sensors.check_rows(msg.columns, rows, msg.count)
    except dialect.DialectError as exc:
        raise ProtocolError("invalid_field", f"sensors payload: {exc}", ref) from None
    except ValueError as exc:
        raise ProtocolError("invalid_field", f"sensors payload: {exc}", ref) from None


def parse_sensor_rows(msg: SensorsMsg, payload: memoryview | bytes) -> list[dict[str, Any]]:
    """The checked rows of a ``sensors`` payload (what `decode` returns for one); raises `ProtocolError`."""
    return _sensor_rows(msg, payload, {})


def sensors_payload(rows: list[list[float | None]]) -> bytes:
    """The JSON payload of a ``sensors`` message."""
    return dialect.dumps(rows)
