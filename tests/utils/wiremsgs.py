"""Protocol messages for tests, good and bad: a valid frame or sensor message with any field replaced.

``raw`` puts JSON text in a field verbatim (``NaN``, ``1e400``, a 5,000-digit
number): what a module written in another language might send, which
Python's ``json`` would not write.
"""

from __future__ import annotations

import json
from datetime import UTC, datetime
from typing import Any

import cv2
import numpy as np

from camcal.core import wire

T0 = datetime(2026, 11, 25, 3, 0, tzinfo=UTC)


def png_bytes(image: np.ndarray | None = None) -> bytes:
    img = np.full((48, 64), 17, np.uint8) if image is None else image
    ok, buf = cv2.imencode(".png", img)
    assert ok
    return buf.tobytes()


def _header(obj: dict[str, Any], raw: dict[str, str] | None) -> bytes:
    raw = raw or {}
    for k in raw:
        obj[k] = f"__RAW_{k}__"
    text = json.dumps(obj)
    for k, v in raw.items():
        text = text.replace(f'"__RAW_{k}__"', v)
    return text.encode()


def frame_parts(
    *,
    raw: dict[str, str] | None = None,
    payload: bytes | None = None,
    image: np.ndarray | None = None,
    **over: Any,
) -> list[bytes]:
    """The two frames of a valid ``frame`` message (a 64 x 48 PNG), with ``over`` fields replaced."""
    data = payload if payload is not None else png_bytes(image)
    obj: dict[str, Any] = {
        "v": 1,
        "type": "frame",
        "module": "A",
        "boot": "b1",
        "seq": 7,
        "sent_at": T0.isoformat(),
        "captured_at": T0.isoformat(),
        "camera": "A",
        "wavelength_nm": 460,
        "exposure_s": 0.05,
        "gain_db": 8.0,
        "depth_m": 3398.4,
        "width_px": 64,
        "height_px": 48,
        "encoding": "png",
        "size": len(data),
        "sha256": wire.sha256_hex(data),
        "schedule_version": 1,
    }
    obj.update(over)
    return [_header(obj, raw), data]


def sensors_parts(
    rows: list[list[Any]] | bytes,
    columns: tuple[str, ...] = wire.SENSOR_COLUMNS,
    *,
    count: int | None = None,
    raw: dict[str, str] | None = None,
    **over: Any,
) -> list[bytes]:
    """The two frames of a ``sensors`` message of ``rows`` (or of payload bytes given as is)."""
    data = rows if isinstance(rows, bytes) else json.dumps(rows).encode()
    obj: dict[str, Any] = {
        "v": 1,
        "type": "sensors",
        "module": "A",
        "boot": "b1",
        "seq": 8,
        "columns": list(columns),
        "count": count if count is not None else (len(rows) if isinstance(rows, list) else 1),
        "size": len(data),
        "sha256": wire.sha256_hex(data),
    }
    obj.update(over)
    return [_header(obj, raw), data]
