"""Reads of the ingest: what is stored already (checksums, sequence numbers), open gaps, counters."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import Any

from sqlalchemy import select, tuple_
from sqlalchemy.orm import Session

from storage.models import (
    Frame,
    Gap,
    IngestCounter,
    SensorBatch,
)


def stored_checksums(
    s: Session, frame_keys: Sequence[tuple[str, str, int]], sensor_keys: Sequence[tuple[str, str, int]]
) -> tuple[dict[tuple[str, str, int], str | None], dict[tuple[str, str, int], str | None]]:
    """The sha256 of frames and sensor batches already stored under these keys (module, boot, seq)."""
    frames: dict[tuple[str, str, int], str | None] = {}
    sensors: dict[tuple[str, str, int], str | None] = {}
    for table, keys, out in (
        (Frame, frame_keys, frames),
        (SensorBatch, sensor_keys, sensors),
    ):
        for chunk in _chunks(sorted(set(keys)), 300):
            rows = s.execute(
                select(table.module_id, table.boot, table.seq, table.sha256).where(
                    tuple_(table.module_id, table.boot, table.seq).in_(chunk)
                )
            )
            for mid, boot, seq, sha in rows:
                out[(mid, boot, int(seq))] = sha
    return frames, sensors


def known_seqs(s: Session, module_id: str, boot: str) -> set[int]:
    """Every sequence number of a module's boot that is stored (frames and sensor batches)."""
    a = s.scalars(select(Frame.seq).where(Frame.module_id == module_id, Frame.boot == boot))
    b = s.scalars(select(SensorBatch.seq).where(SensorBatch.module_id == module_id, SensorBatch.boot == boot))
    return {int(x) for x in a} | {int(x) for x in b}


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
