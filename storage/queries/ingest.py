"""Reads of the ingest: what is stored already (checksums, sequence numbers), open gaps, counters."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import Any

from sqlalchemy import bindparam, literal, select, tuple_, union_all
from sqlalchemy.orm import Session

from storage.models import (
    Frame,
    Gap,
    IngestCounter,
    SensorBatch,
)


def _checksums_statement() -> Any:
    """One SELECT of both tables for a list of keys (built once: a Core statement, cached compiled)."""
    keys: Any = bindparam("keys", expanding=True)
    parts = [
        select(
            t.c.module_id,
            t.c.boot,
            t.c.seq,
            t.c.sha256,
            t.c.content_sha256,
            literal(is_frame).label("is_frame"),
        ).where(tuple_(t.c.module_id, t.c.boot, t.c.seq).in_(keys), *extra)
        for t, is_frame, extra in (
            (Frame.__table__, True, ()),
            (SensorBatch.__table__, False, (SensorBatch.__table__.c.complete.is_(True),)),
        )
    ]
    return union_all(*parts)


_CHECKSUMS = _checksums_statement()


def stored_checksums(
    s: Session, frame_keys: Sequence[tuple[str, str, int]], sensor_keys: Sequence[tuple[str, str, int]]
) -> tuple[dict[tuple[str, str, int], str | None], dict[tuple[str, str, int], str | None]]:
    """The sha256 of frames and (complete) sensor batches already stored under these keys (module, boot, seq).

    One statement for both tables (a frame and a sensor message share a boot's sequence); keys
    looked up in one table only are dropped from the other's answer."""
    frames: dict[tuple[str, str, int], str | None] = {}
    sensors: dict[tuple[str, str, int], str | None] = {}
    fkeys, skeys = set(frame_keys), set(sensor_keys)
    for chunk in _chunks(sorted(fkeys | skeys), 300):
        for mid, boot, seq, sha, _, is_frame in s.execute(_CHECKSUMS, {"keys": list(chunk)}):
            key = (mid, boot, int(seq))
            if is_frame and key in fkeys:
                frames[key] = sha
            elif not is_frame and key in skeys:
                sensors[key] = sha
    return frames, sensors


def stored_contents(
    s: Session, keys: Sequence[tuple[str, str, int]]
) -> dict[tuple[str, str, int], tuple[str | None, str | None]]:
    """What is stored under these keys (module, boot, seq), frame or complete sensor batch: the
    payload's sha256 and the message's content checksum (`camcal.core.wire.content_sha256`; None for a
    row stored without one), in one statement."""
    out: dict[tuple[str, str, int], tuple[str | None, str | None]] = {}
    for chunk in _chunks(sorted(set(keys)), 300):
        for mid, boot, seq, sha, content, is_frame in s.execute(_CHECKSUMS, {"keys": list(chunk)}):
            key = (mid, boot, int(seq))
            if is_frame or key not in out:  # (a frame and a batch under one key: the frame's)
                out[key] = (sha, content)
    return out


def known_seqs(s: Session, module_id: str, boot: str) -> set[int]:
    """Every sequence number of a module's boot that is stored (frames and sensor batches)."""
    a = s.scalars(select(Frame.seq).where(Frame.module_id == module_id, Frame.boot == boot))
    b = s.scalars(
        select(SensorBatch.seq).where(
            SensorBatch.module_id == module_id, SensorBatch.boot == boot, SensorBatch.complete.is_(True)
        )
    )
    return {int(x) for x in a} | {int(x) for x in b}


def frame_contents(
    s: Session, dive_id: int, module_id: str
) -> dict[str, list[tuple[int, float, float, float]]]:
    """A module's frames of a dive by the sha256 of their file: (wavelength, exposure, gain, capture
    time) of each (an import tells a copy of a stored frame from a frame of its own)."""
    out: dict[str, list[tuple[int, float, float, float]]] = {}
    q = select(
        Frame.sha256, Frame.wavelength_nm, Frame.exposure_s, Frame.gain_db, Frame.captured_unix_s
    ).where(Frame.dive_id == dive_id, Frame.module_id == module_id)
    for sha, wl, exp, gain, t in s.execute(q):
        if sha:
            out.setdefault(sha, []).append((int(wl), float(exp), float(gain), float(t)))
    return out


def open_gaps(s: Session, module_id: str | None = None) -> list[Gap]:
    q = select(Gap).where(Gap.filled_unix_s.is_(None))
    if module_id:
        q = q.where(Gap.module_id == module_id)
    return list(s.scalars(q.order_by(Gap.id)))


def load_counters(s: Session, ingest_id: str) -> dict[str, int]:
    """The counters an ingest saved before (``group.name`` -> value)."""
    rows = s.execute(
        select(IngestCounter.name, IngestCounter.value).where(IngestCounter.ingest_id == ingest_id)
    )
    return {name: int(value) for name, value in rows}


def _chunks(items: Sequence[Any], n: int) -> Iterator[Sequence[Any]]:
    for i in range(0, len(items), n):
        yield items[i : i + n]
