"""Commit and acknowledge: the store thread's part that decides every data message's fate.

A batch of frames and sensor messages is committed in one transaction:
frame files first (temporary name, fsync, rename), then the rows, the
frames' events with them, and only then the acknowledgements. Every data
message gets exactly one answer:

* stored, or stored before with the same content (a resend) -> ``ack``;
* stored before with *other* content -> ``nack`` ``conflict`` (the first
  copy is kept, its file never overwritten) and an alarm;
* the batch fails -> each message is tried alone; one that fails alone gets
  ``internal_error`` (resend later), and the second time it fails while
  others were stored it is quarantined (`ingest.quarantine`) -- unless the
  failure is the ship's own (`ships_fault`: a full or read-only disk, a
  locked or unreachable database), which no message can cause and which
  must never cost a module its frames: those are refused ``internal_error``
  every time, and the module resends them once the ship recovers.

A sensor batch the checking stage split in parts (`ingest.messages.PART_ROWS`
rows each) is committed a part per turn, each part beside the other
modules' messages; it is answered with its last part. A resend of a stored
batch, or a conflict, is told by its first part, and the parts after it are
dropped.

Nothing that happens after the commit (gaps, events, analysis queue) can
turn a stored message into a refused one: those steps are guarded apart.
"""

from __future__ import annotations

import logging
import time
from collections import OrderedDict, defaultdict
from collections.abc import Callable
from typing import Any

from camcal.core import wire
from camcal.core.events import Event, EventKind
from camcal.core.ratelog import RateLimitedLog
from camcal.core.wire.sensorrows import rows_dicts
from ingest.acknowledge import Acknowledge
from ingest.alarms import AlarmEvaluator
from ingest.analysis_pool import Job
from ingest.counters import Counters
from ingest.events import EventBus
from ingest.faults import ships_fault
from ingest.gaps import Gaps
from ingest.messages import Checked, Key
from ingest.quarantine import Quarantine
from ingest.sensorbuf import SensorBuffers
from storage import queries
from storage.store import BatchOutcome, FrameRow, SensorBatchRow, Store

log = logging.getLogger("camcal.ingest")
Guard = Callable[..., bool]


class Committer:
    def __init__(
        self,
        store: Store,
        *,
        dive_id: int,
        ingest_id: str,
        fsync: bool,
        counters: Counters,
        alarms: AlarmEvaluator,
        acknowledge: Acknowledge,
        events: EventBus,
        gaps: Gaps,
        sensors: SensorBuffers,
        analyse: Callable[[Job], None],
        guarded: Guard,
    ) -> None:
        self.store = store
        self.dive_id = dive_id
        self.ingest_id = ingest_id
        self.fsync = fsync
        self.counters = counters
        self.alarms = alarms
        self.acknowledge = acknowledge
        self.events = events
        self.gaps = gaps
        self.sensors = sensors
        self.analyse = analyse
        self.guarded = guarded
        self.quarantine = Quarantine(self.store.files.root)
        #: Committed keys -> (payload sha256, content checksum), the newest 4096.
        self.recent: OrderedDict[Key, tuple[str | None, str | None]] = OrderedDict()
        self.failures: dict[tuple[str, str, int, str], list[int]] = defaultdict(list)
        self.stored = 0  # messages committed so far (to tell a bad message from a bad disk)
        #: Sensor batches answered by their first part (a resend, a conflict, a failure): their
        #: later parts are dropped.
        self.answered_early: set[Key] = set()
        self.warn = RateLimitedLog(log)

    # -- entry -----------------------------------------------------------
    def commit(self, items: list[Checked]) -> None:
        fresh = []
        for it in items:
            if it.key in self.answered_early and it.part is not None and it.part[0] > 0:
                if it.last_part:
                    self.answered_early.discard(it.key)
                continue
            if self.quarantine.holds(self._qkey(it)):
                self._refuse(it, "quarantined", "this message failed twice on the ship; it is kept there")
            else:
                fresh.append(it)
        if not fresh:
            return
        try:
            self._commit(fresh)
            return
        except Exception as exc:
            if len(fresh) == 1:
                self._failed(fresh[0], exc)
                return
            self.warn(
                logging.WARNING, "batch", "a batch of %d failed (%s); storing one by one", len(fresh), exc
            )
        for it in fresh:
            try:
                self._commit([it])
            except Exception as exc:
                self._failed(it, exc)

    # -- the transaction -------------------------------------------------
    def _commit(self, items: list[Checked]) -> None:
        files = self.store.files
        frames: list[FrameRow] = []
        sensors: list[SensorBatchRow] = []
        payloads: dict[Key, Any] = {}
        ok: list[Checked] = []  # stored now or before with the same content (or a part of a batch)
        parts: list[tuple[Checked, Any]] = []  # sensor batches (or parts) to store, with their rows
        seen: dict[Key, str] = {}
        # Frames and sensor messages share one sequence per boot: look each key up in both tables.
        firsts = [it for it in items if it.part is None or it.part[0] == 0]
        keys = [it.key for it in firsts if it.key not in self.recent]
        stored_before = self.store.call(queries.stored_contents, keys)
        for it in items:
            m, key = it.msg, it.key
            content = wire.content_sha256(m)
            if it.part is None or it.part[0] == 0:
                if key in seen:  # the same message twice in one batch (a resend crossed the first)
                    self._settled_early(it, seen[key] == content, ok)
                    continue
                if key in self.recent or key in stored_before:
                    stored = self.recent[key] if key in self.recent else stored_before[key]
                    self._settled_early(it, _same(stored, m.sha256, content), ok)
                    continue
                seen[key] = content
            ok.append(it)
            if it.kind == "frame":
                rel = files.relative_path(self.dive_id, m.module, m.boot, m.seq, m.encoding)
                payloads[key] = (rel, it.payload)
                frames.append(
                    FrameRow(
                        module_id=m.module,
                        boot=m.boot,
                        seq=m.seq,
                        captured_unix_s=m.captured_at.timestamp(),
                        # on the ship's clock too: one axis for the dive's times (`camcal.core.clockmap`)
                        captured_ship_unix_s=it.clock.ship(m.captured_at.timestamp()),
                        received_unix_s=it.received_unix_s,
                        wavelength_nm=m.wavelength_nm,
                        exposure_s=m.exposure_s,
                        gain_db=m.gain_db,
                        depth_m=m.depth_m,
                        width_px=m.width_px,
                        height_px=m.height_px,
                        path=rel,
                        size_bytes=m.size,
                        sha256=m.sha256,
                        schedule_version=m.schedule_version,
                        content_sha256=content,
                    )
                )
            else:
                rows = _part_rows(it)
                parts.append((it, rows))
                sensors.append(
                    SensorBatchRow(
                        m.module,
                        m.boot,
                        m.seq,
                        it.received_unix_s,
                        rows_dicts(rows),
                        m.sha256,
                        part=it.part,
                        content_sha256=content,
                        clock=it.clock,
                    )
                )
        files.write_many(list(payloads.values()), fsync=self.fsync)  # every file durable before its row
        received = {it.key: it.received_mono for it in items}
        t_done = time.monotonic()

        def frame_event(f: FrameRow, fid: int) -> Event:
            payload = {
                "frame_id": fid,
                **_frame_meta(f),
                "schedule_version": f.schedule_version,
                "stored_latency_s": round(t_done - received[(f.module_id, f.boot, f.seq)], 4),
            }
            return Event(EventKind.FRAME, payload, time.time(), f.module_id, self.dive_id)

        def counted(outcome: BatchOutcome) -> tuple[str, dict[str, int]]:  # (in the transaction)
            return self.ingest_id, self.counters.flat_with(_counts(ok, outcome)[1])

        outcome = self.store.commit_batch(
            self.dive_id, frames, sensors, frame_event=frame_event, counters=counted
        )
        # -- committed: from here on nothing may refuse these messages --
        new_sensors = set(outcome.new_sensor_batches)
        answered, counts = _counts(ok, outcome)
        for it in answered:
            if it.part is not None and not it.last_part:  # stored before all the same (another ingest)
                self.answered_early.add(it.key)
        self.stored += len(answered)
        for name, n in counts.items():
            self.counters.inc(name, n)
        for it in answered:
            self._remember(it.key, (it.msg.sha256, wire.content_sha256(it.msg)))
        self.guarded("ack", self.acknowledge.ack, [it.key for it in answered])
        self.guarded("events", self.events.published_stored, outcome.events)
        by_key = {(f.module_id, f.boot, f.seq): f for f in frames}
        for key, fid in outcome.new_frames.items():
            f = by_key[key]
            self.analyse(Job(fid, f.path, {**_frame_meta(f), "received_mono": received[key]}))
        for it, rows in parts:
            if it.key in new_sensors:
                self.guarded("sensor samples", self.sensors.add, it.module, rows)
        self.guarded("gaps", self.gaps.arrived, [it.msg for it in answered])

    def _settled_early(self, it: Checked, same: bool, ok: list[Checked]) -> None:
        """A message stored before (``same`` content: acknowledged with the others) or a conflict;
        a batch in parts is settled by its first part."""
        if it.part is not None and not it.last_part:
            self.answered_early.add(it.key)
        if same:
            if it.part is not None and not it.last_part:  # acknowledged now, its other parts dropped
                it = Checked(it.msg, it.payload, it.received_unix_s, it.received_mono, it.nbytes, it.clock)
            ok.append(it)
        else:
            self._conflict(it)

    # -- refusals --------------------------------------------------------
    def _conflict(self, it: Checked) -> None:
        m = it.msg
        self.counters.inc("conflicts")
        self.alarms.observe_conflict(m.module, m.boot, m.seq, time.time())
        self._refuse(
            it,
            "conflict",
            f"{m.type} {m.boot}/{m.seq} is stored with other content (its header or its payload "
            "differs); the ship keeps the first copy: compare the module's SD card with `camcal import`",
        )

    def _failed(self, it: Checked, exc: Exception) -> None:
        key = self._qkey(it)
        fails = self.failures[key]
        fails.append(self.stored)
        self.warn(
            logging.ERROR,
            f"failed:{type(exc).__name__}",
            "storing %s %s/%s/%d failed: %s",
            it.kind,
            it.module,
            it.msg.boot,
            it.msg.seq,
            exc,
            exc_info=True,
        )
        if ships_fault(exc):  # never the message's: not held against it
            del self.failures[key]
            self._refuse(
                it,
                "internal_error",
                f"the ship cannot store now ({type(exc).__name__}: {str(exc)[:200]}); resend later",
            )
        elif len(fails) >= 2 and self.stored > fails[0]:
            header = it.msg.model_dump(mode="json")
            payload = (
                bytes(it.payload)
                if it.kind == "frame"
                else wire.sensors_payload(
                    [[r.get(c) for c in wire.SENSOR_COLUMNS] for r in rows_dicts(it.payload)]
                )
            )
            where = self.quarantine.put(key, header, payload, f"{type(exc).__name__}: {exc}")
            del self.failures[key]
            self.counters.inc("quarantined")
            self._refuse(
                it, "quarantined", f"failed twice on the ship ({type(exc).__name__}); kept in {where}"
            )
        else:
            self._refuse(
                it, "internal_error", f"the ship failed to store it ({type(exc).__name__}); resend later"
            )

    def _refuse(self, it: Checked, reason: str, detail: str) -> None:
        """Refuse a data message (a batch in parts: with the part that failed, the rest dropped)."""
        if it.part is not None and not it.last_part:
            self.answered_early.add(it.key)
        self.acknowledge.refuse(it.msg, reason, detail)

    # -- helpers ---------------------------------------------------------
    @staticmethod
    def _qkey(it: Checked) -> tuple[str, str, int, str]:
        return (it.msg.module, it.msg.boot, it.msg.seq, it.msg.sha256)

    def _remember(self, key: Key, stored: tuple[str | None, str | None]) -> None:
        self.recent[key] = stored
        self.recent.move_to_end(key)
        while len(self.recent) > 4096:
            self.recent.popitem(last=False)


def _counts(ok: list[Checked], outcome: BatchOutcome) -> tuple[list[Checked], dict[str, int]]:
    """What a commit answers (a message whole, the last part of a batch, or the first part of a batch
    stored before), and the counts of what it stored."""
    new_sensors = set(outcome.new_sensor_batches)
    answered: list[Checked] = []
    duplicates = 0
    for it in ok:
        first = it.part is None or it.part[0] == 0
        new = it.key in outcome.new_frames or it.key in new_sensors
        duplicates += first and not new
        if it.last_part or (first and not new):
            answered.append(it)
    return answered, {"frames_stored": len(outcome.new_frames), "duplicates": duplicates}


def _same(stored: tuple[str | None, str | None], sha: str, content: str) -> bool:
    """Whether a message is the one stored under its key: the same content (header fields and payload),
    or for a row stored without a content checksum (imported, older) the same payload (or no checksum)."""
    stored_sha, stored_content = stored
    if stored_content is not None:
        return stored_content == content
    return stored_sha is None or stored_sha == sha


def _part_rows(it: Checked) -> Any:
    """The sensor rows of a batch, or of the part ``it`` is of it."""
    if it.part is None:
        return it.payload
    first, n, _ = it.part
    return it.payload[first : first + n]


def _frame_meta(f: FrameRow) -> dict[str, Any]:
    """What the analysis and the events need of a frame."""
    return {
        "module": f.module_id,
        "seq": f.seq,
        "boot": f.boot,
        "wavelength_nm": f.wavelength_nm,
        "exposure_s": f.exposure_s,
        "gain_db": f.gain_db,
        "depth_m": f.depth_m,
        "captured_unix_s": f.captured_unix_s,
        "captured_ship_unix_s": f.captured_ship_unix_s,
        "width_px": f.width_px,
        "height_px": f.height_px,
    }


def frame_meta_from_row(f: Any) -> dict[str, Any]:
    """`_frame_meta` of a stored ``frames`` row (for frames recovered after a restart)."""
    meta = _frame_meta(
        FrameRow(
            module_id=f.module_id,
            boot=f.boot,
            seq=f.seq,
            captured_unix_s=f.captured_unix_s,
            received_unix_s=f.received_unix_s,
            wavelength_nm=f.wavelength_nm,
            exposure_s=f.exposure_s,
            gain_db=f.gain_db,
            depth_m=f.depth_m,
            width_px=f.width_px,
            height_px=f.height_px,
            path=f.path,
            size_bytes=f.size_bytes,
            sha256=f.sha256,
            captured_ship_unix_s=f.captured_ship_unix_s,
        )
    )
    return {**meta, "received_mono": None}
