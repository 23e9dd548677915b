"""Replaying a recorded frame set as if a camera were taking it now."""

from __future__ import annotations

import struct
import threading
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from camcal.core.frameset import ManifestRow, read_manifest
from camcal.core.images import FrameReadError, decode_frame, encode_png
from camcal.core.schedule import Shot
from camcal.core.utctime import parse_utc
from lrm.runner import Capture


@dataclass(frozen=True)
class ReplayedFrame:
    """A recorded frame: the PNG bytes are sent as they are (no re-encoding)."""

    png: bytes
    captured_at: datetime
    exposure_s: float
    gain_db: float
    camera: str
    wavelength_nm: int
    depth_m: float | None
    extra: dict[str, Any] = field(default_factory=dict)
    pixels: Any = None


class ReplaySource:
    """The frames of one camera of a frame set, in manifest order, at recorded pace or faster.

    ``speed`` scales the recorded intervals between timestamps (2 = twice as
    fast); ``speed = 0`` sends as fast as the link takes them. Rows without
    a timestamp follow each other after their exposure time. Unusable rows
    and unreadable images are skipped and counted.
    """

    def __init__(self, folder: Path, camera: str, clock: Any, speed: float = 1.0) -> None:
        self.folder = Path(folder)
        self.rows: list[ManifestRow] = [
            r for r in read_manifest(self.folder) if r.camera == camera and not r.error
        ]
        self.camera = camera
        self.clock = clock
        self.speed = speed
        self.skipped: list[tuple[str, str]] = []
        self._i = 0
        self._t0_clock: float | None = None
        self._t0_rec: datetime | None = None

    def __len__(self) -> int:
        return len(self.rows)

    def __call__(self, stop: threading.Event) -> Capture | None:
        while self._i < len(self.rows) and not stop.is_set():
            row = self.rows[self._i]
            self._i += 1
            recorded = _parse_time(row.timestamp)
            if self.speed > 0 and recorded is not None:
                if self._t0_clock is None or self._t0_rec is None:
                    self._t0_clock, self._t0_rec = self.clock.monotonic(), recorded
                due = self._t0_clock + (recorded - self._t0_rec).total_seconds() / self.speed
                wait = due - self.clock.monotonic()
                if wait > 0 and stop.wait(wait):
                    return None
            elif self.speed > 0:
                stop.wait(row.exposure_s / self.speed)
            try:
                data = (self.folder / row.file).read_bytes()
                if data.startswith(PNG_SIGNATURE):
                    width, height = check_png(data, row.file)  # sent as it is: no need to decode it
                else:
                    frame = decode_frame(data, row.file)
                    data = encode_png(frame)
                    height, width = frame.shape
            except (OSError, FrameReadError) as exc:
                self.skipped.append((row.file, str(exc)))
                continue
            f = ReplayedFrame(
                data,
                recorded or datetime.now(UTC),
                row.exposure_s,
                row.gain_db,
                self.camera,
                row.wavelength_nm,
                row.depth_m,
                {"source": row.file, "size": (width, height)},
            )
            shot = Shot(row.wavelength_nm, row.exposure_s, row.gain_db, 0)
            return Capture(f, shot, row.wavelength_nm, row.schedule_version or 0)
        return None


PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_END = b"\x00\x00\x00\x00IEND\xaeB`\x82"


def check_png(data: bytes, name: str = "frame") -> tuple[int, int]:
    """(width, height) of an 8-bit grayscale PNG, from its header, without decoding it.

    Decoding a 5 MP PNG costs tens of milliseconds, as much as analysing it
    on the ship; a replay only needs to know the file is a whole 8-bit
    grayscale PNG (header, and the end chunk a truncated file lacks). A PNG
    damaged inside is caught by the ship's analysis (``unreadable``).
    Raises `FrameReadError` like `decode_frame`.
    """
    if len(data) < 33 or not data.startswith(PNG_SIGNATURE) or data[12:16] != b"IHDR":
        raise FrameReadError("unreadable", f"{name}: not a decodable PNG/TIFF (truncated or corrupt?)")
    width, height = struct.unpack(">II", data[16:24])
    bit_depth, color_type = data[24], data[25]
    if color_type != 0:
        raise FrameReadError("bad_format", f"{name}: PNG colour type {color_type}, expected 8-bit grayscale")
    if bit_depth != 8:
        raise FrameReadError("bad_format", f"{name}: {bit_depth}-bit PNG, expected 8-bit grayscale")
    if not data.endswith(_PNG_END):
        raise FrameReadError("unreadable", f"{name}: PNG without its end chunk (truncated?)")
    if width == 0 or height == 0:
        raise FrameReadError("unreadable", f"{name}: PNG of {width} x {height} pixels")
    return width, height


def _parse_time(text: str | None) -> datetime | None:
    if not text:
        return None
    try:
        return parse_utc(text)
    except ValueError:
        return None
