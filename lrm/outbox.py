"""The SD-card outbox: everything a module produces is written here first, then sent.

Layout of an outbox folder::

    frames/          a frame set (docs/frameset.md) with the extra columns
                     ``boot`` and ``schedule_version``; ``seq`` is the wire
                     sequence number of the frame
    sensors.jsonl    one line per sensors message: {"boot", "seq", "columns", "rows"}
    acked.log        one line per acknowledgement: "BOOT FIRST LAST"
    commands.jsonl   every command this module has answered, with its last state
    schedule.json    the schedule the module runs (resumed after a reboot)

Nothing is deleted when the ship acknowledges it: the SD card is the copy
scientists import after the dive. The outbox only remembers what is
acknowledged, so that after a reconnect (or a reboot) it resends exactly
what the ship does not have.
"""

from __future__ import annotations

import json
import logging
import os
import struct
import threading
from collections import Counter
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

from camcal.core import wire
from camcal.core.files import AppendLog, write_atomic
from camcal.core.frameset import (
    DAMAGED,
    DAMAGED_ROW,
    MANIFEST,
    ManifestRow,
    Setup,
    decode_text,
    parse_manifest,
)
from camcal.core.framewriter import FrameSetWriter
from camcal.core.utctime import parse_utc
from camcal.core.wire.dialect import INT_MAX
from camcal.core.wire.image import read_header

log = logging.getLogger("camcal.lrm")


@dataclass(frozen=True)
class Entry:
    """One data message kept in the outbox."""

    kind: str  # frame | sensors
    boot: str
    seq: int
    ref: Any  # ManifestRow for a frame, the parsed JSON line for sensors


def drop_cut_line(path: Path) -> bool:
    """Remove a last line that has no newline: a power loss cut it while it was being written.

    Every line of the outbox's logs is written whole before its message is
    sent, so a cut line was never sent and holds nothing to keep. Left in
    place, the next line appended after a reboot would run on from it, and
    both would be unreadable. Returns True if something was removed.
    """
    try:
        fh = path.open("rb+")
    except FileNotFoundError:
        return False
    with fh:
        end = fh.seek(0, os.SEEK_END)
        if end == 0:
            return False
        fh.seek(end - 1)
        if fh.read(1) == b"\n":
            return False
        keep, pos = 0, end
        while pos > 0:
            step = min(pos, 1 << 16)
            pos -= step
            fh.seek(pos)
            chunk = fh.read(step)
            i = chunk.rfind(b"\n")
            if i >= 0:
                keep = pos + i + 1
                break
        fh.truncate(keep)
        fh.flush()
        os.fsync(fh.fileno())
        return True


def _seq(value: Any) -> int:
    """A sequence number read back from the card: an integer 1 … 2⁶³−1, else ValueError."""
    q = int(value)
    if not 1 <= q <= INT_MAX:
        raise ValueError(f"sequence number {q} out of range")
    return q


def png_size(data: bytes) -> tuple[int, int]:
    """(width, height) from a PNG's IHDR chunk, without decoding the image."""
    if len(data) < 24 or data[:8] != b"\x89PNG\r\n\x1a\n" or data[12:16] != b"IHDR":
        raise ValueError("not a PNG")
    return struct.unpack(">II", data[16:24])


class OutboxUnavailable(OSError):
    """The outbox cannot be opened for writing: the module takes nothing it cannot keep there."""

    def __init__(self, root: Path, exc: OSError) -> None:
        super().__init__(
            exc.errno,
            f"the outbox {root} cannot be written ({exc.strerror or exc}): the SD card is read-only, "
            "full, missing or not ours; remount it read-write, free or swap it, or give another "
            "--outbox. The module takes nothing it cannot keep on its card",
        )

    def __str__(self) -> str:
        return str(self.strerror)


class Outbox:
    """Write-first, send-later store of a module's frames and sensor packets. Thread-safe."""

    def __init__(self, root: Path, module: str, *, fsync: bool = True, setup: Setup | None = None) -> None:
        self.root = Path(root)
        self.module = module
        self.fsync = fsync
        self._lock = threading.RLock()
        try:
            self._open(setup)
        except OSError as exc:
            self.close()
            raise OutboxUnavailable(self.root, exc) from exc
        self._acked: set[tuple[str, int]] = set()
        self._pending: dict[tuple[str, int], Entry] = {}
        self._last_seq: dict[str, int] = {}
        self._load()

    def _open(self, setup: Setup | None) -> None:
        """The card's folder and logs, opened for appending (a power cut's last lines dropped)."""
        self.root.mkdir(parents=True, exist_ok=True)
        frames_dir = self.root / "frames"
        for name in (f"frames/{MANIFEST}", "sensors.jsonl", "acked.log", "refused.jsonl", "commands.jsonl"):
            drop_cut_line(self.root / name)
        fresh = not (frames_dir / MANIFEST).exists()
        self._writer = FrameSetWriter(frames_dir, setup if fresh else None, fsync=self.fsync)
        # Each line on the card whole or not at all, even when the card fills up as it is written.
        self._sensors = AppendLog(self.root / "sensors.jsonl", fsync=self.fsync)
        self._acked_fh = AppendLog(self.root / "acked.log", fsync=self.fsync)
        self._refused_fh = AppendLog(self.root / "refused.jsonl", fsync=self.fsync)

    # ------------------------------------------------------------ loading
    def _load(self) -> None:
        """What the card holds and what of it the ship has. A damaged line (a failing card: bytes
        that are not UTF-8, values that do not parse) is skipped, counted in `damaged` and logged;
        the others load: a module must start whatever one line of its card says."""
        damaged: Counter[str] = Counter()
        entries: list[Entry] = []
        text = self._text(f"frames/{MANIFEST}")
        rows = parse_manifest(text, str(self.root / "frames" / MANIFEST)) if text.strip() else []
        for row in rows:  # a damaged row is not offered: its values cannot be trusted (it stays on the card)
            if row.boot and row.seq is not None and DAMAGED_ROW not in (row.error or ""):
                entries.append(Entry("frame", row.boot, row.seq, row))
        for line in self._text("sensors.jsonl").splitlines():
            try:
                if DAMAGED in line:
                    raise ValueError("not UTF-8")
                obj = json.loads(line)
                entries.append(Entry("sensors", str(obj["boot"]), _seq(obj["seq"]), obj))
                if not isinstance(obj["rows"], list):
                    raise TypeError("rows")
            except (ValueError, KeyError, TypeError):  # a line cut by a power loss was never sent
                damaged["sensors.jsonl"] += bool(line.strip())
                continue
        for e in entries:
            self._last_seq[e.boot] = max(self._last_seq.get(e.boot, 0), e.seq)
        for line in self._text("acked.log").splitlines():
            parts = line.split()
            try:
                boot, first, last = parts[0], _seq(parts[1]), _seq(parts[2])
                # A range beyond what the card holds was never acknowledged (the ship acknowledges
                # what was sent, and only what is on the card is sent): a damaged number.
                if len(parts) != 3 or first > last or last > self._last_seq.get(boot, 0) or DAMAGED in line:
                    raise ValueError(line)
            except (IndexError, ValueError):
                damaged["acked.log"] += bool(line.strip())
                continue
            self._acked.update((boot, q) for q in range(first, last + 1))
        for line in self._text("refused.jsonl").splitlines():
            try:
                obj = json.loads(line)
                self._acked.add((str(obj["boot"]), _seq(obj["seq"])))  # settled: never offered again
            except (ValueError, KeyError, TypeError):
                damaged["refused.jsonl"] += bool(line.strip())
        for e in entries:
            self._index(e)
        damaged[f"frames/{MANIFEST}"] += sum(DAMAGED in line for line in text.splitlines())
        #: Damaged lines found at start, per file of the card (a row of the manifest is kept, as
        #: the frame set's rules say, with its damaged value).
        self.damaged = {k: n for k, n in damaged.items() if n}
        if self.damaged:
            log.error(
                "outbox %s: damaged line(s) on the SD card (%s) skipped: the card may be failing; "
                "replace it at the next recovery (what it holds is kept)",
                self.root,
                ", ".join(f"{k}: {n}" for k, n in self.damaged.items()),
            )

    def _text(self, name: str) -> str:
        """A file of the card as text ("" if absent); bytes that are not UTF-8 (a damaged card)
        read as `DAMAGED`, so that only the line they are in fails to parse, not the whole file."""
        try:
            return decode_text((self.root / name).read_bytes())
        except FileNotFoundError:
            return ""

    def _index(self, e: Entry) -> None:
        self._last_seq[e.boot] = max(self._last_seq.get(e.boot, 0), e.seq)
        if (e.boot, e.seq) not in self._acked:
            self._pending[(e.boot, e.seq)] = e

    # ------------------------------------------------------------ writing
    def last_seq(self, boot: str) -> int:
        with self._lock:
            return self._last_seq.get(boot, 0)

    def add_frame(
        self,
        boot: str,
        seq: int,
        png: bytes,
        *,
        captured_at: datetime,
        camera: str,
        wavelength_nm: int,
        exposure_s: float,
        gain_db: float,
        depth_m: float | None,
        schedule_version: int,
    ) -> Entry:
        """Store a frame (image, then its manifest row) before it is sent."""
        name = f"{boot}/{camera}_{wavelength_nm}_{seq:07d}.png"
        row = ManifestRow(
            index=seq,
            file=name,
            camera=camera,
            wavelength_nm=wavelength_nm,
            exposure_s=exposure_s,
            gain_db=gain_db,
            timestamp=captured_at.isoformat().replace("+00:00", "Z"),
            depth_m=depth_m,
            seq=seq,
            boot=boot,
            schedule_version=schedule_version,
        )
        with self._lock:
            self._writer.add(png, row)
            e = Entry("frame", boot, seq, row)
            self._index(e)
            return e

    def add_sensors(self, boot: str, seq: int, rows: list[list[float | None]]) -> Entry:
        obj = {"boot": boot, "seq": seq, "columns": list(wire.SENSOR_COLUMNS), "rows": rows}
        line = json.dumps(obj, separators=(",", ":")) + "\n"
        with self._lock:
            self._sensors.append(lambda fh: fh.write(line))
            e = Entry("sensors", boot, seq, obj)
            self._index(e)
            return e

    def ack(self, boot: str, first: int, last: int) -> int:
        """Record an acknowledged range; returns how many pending entries it settled."""
        with self._lock:
            settled = 0
            for q in range(first, last + 1):
                if self._pending.pop((boot, q), None) is not None:
                    settled += 1
                self._acked.add((boot, q))
            self._acked_fh.append(lambda fh: fh.write(f"{boot} {first} {last}\n"))
            return settled

    def refuse(self, boot: str, seq: int, reason: str, detail: str = "") -> bool:
        """The ship refused an entry for good (a ``nack`` that resending cannot help).

        It stays on the card (``camcal import`` still reads it) and is written
        to ``refused.jsonl`` with the reason, so it is not offered again, even
        after a reboot. Returns whether it was pending.
        """
        with self._lock:
            was = self._pending.pop((boot, seq), None) is not None
            self._acked.add((boot, seq))
            line = {"boot": boot, "seq": seq, "reason": reason, "detail": detail[:500]}
            self._refused_fh.append(lambda fh: fh.write(json.dumps(line) + "\n"))
            return was

    def discard(self, boot: str, seq: int) -> None:
        """Stop offering an entry that cannot be sent (its image is gone or damaged).

        Nothing is written: the entry is found again after a restart and
        skipped again. The ship keeps a gap for it.
        """
        with self._lock:
            self._pending.pop((boot, seq), None)

    # ------------------------------------------------------------ reading
    def pending(self) -> list[Entry]:
        """Unacknowledged entries, oldest boot first, in sequence order."""
        with self._lock:
            return sorted(self._pending.values(), key=lambda e: (e.boot, e.seq))

    def pending_count(self) -> int:
        with self._lock:
            return len(self._pending)

    def get(self, boot: str, seq: int) -> Entry | None:
        with self._lock:
            return self._pending.get((boot, seq))

    def message(self, e: Entry, module: str) -> tuple[Any, bytes]:
        """The wire message (header, payload) of an entry, rebuilt from the SD card."""
        if e.kind == "frame":
            row: ManifestRow = e.ref
            data = (self.root / "frames" / row.file).read_bytes()
            width, height = png_size(data)
            depth = read_header(data, "png")
            header: wire.FrameMsg | wire.SensorsMsg = wire.FrameMsg(
                module=module,
                boot=e.boot,
                seq=e.seq,
                captured_at=parse_utc(row.timestamp) if row.timestamp else wire.utc_now(),
                camera=row.camera,
                wavelength_nm=row.wavelength_nm,
                exposure_s=row.exposure_s,
                gain_db=row.gain_db,
                depth_m=row.depth_m,
                width_px=width,
                height_px=height,
                encoding="png",
                bit_depth=depth.significant_bits,
                size=len(data),
                sha256=wire.sha256_hex(data),
                schedule_version=row.schedule_version or 0,
                file=row.file,
            )
            return header, data
        obj = e.ref
        payload = wire.sensors_payload(obj["rows"])
        header = wire.SensorsMsg(
            module=module,
            boot=e.boot,
            seq=e.seq,
            columns=tuple(obj["columns"]),
            count=len(obj["rows"]),
            size=len(payload),
            sha256=wire.sha256_hex(payload),
        )
        return header, payload

    # ------------------------------------------------------------ state files
    def load_json(self, name: str) -> Any:
        path = self.root / name
        if not path.exists():
            return None
        try:
            return json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):  # not JSON, or not UTF-8 (a damaged card)
            return None

    def save_json(self, name: str, obj: Any) -> None:
        write_atomic(
            self.root / name, (json.dumps(obj, indent=1, default=str) + "\n").encode(), fsync=self.fsync
        )

    def append_jsonl(self, name: str, obj: Any) -> None:
        text = json.dumps(obj, default=str) + "\n"
        with self._lock:
            log = AppendLog(self.root / name, fsync=self.fsync)  # the line whole or not at all
            try:
                log.append(lambda fh: fh.write(text))
            finally:
                log.close()

    def read_jsonl(self, name: str) -> list[Any]:
        out = []
        for line in self._text(name).splitlines():
            try:
                out.append(json.loads(line))
            except json.JSONDecodeError:
                continue
        return out

    def close(self) -> None:
        with self._lock:  # (what `_open` opened: all of it, or part of it when it failed)
            for name in ("_writer", "_sensors", "_acked_fh", "_refused_fh"):
                if hasattr(self, name):
                    getattr(self, name).close()
