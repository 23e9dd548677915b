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

Nothing that happens after the commit (gaps, events, analysis queue) can
turn a stored message into a refused one: those steps are guarded apart.
"""

from __future__ import annotations

import logging
import time
from collections import OrderedDict, defaultdict
from typing import TYPE_CHECKING, Any

from camcal.core import wire
from camcal.core.events import Event, EventKind
from camcal.core.ratelog import RateLimitedLog
from ingest.faults import ships_fault
from ingest.network import Incoming, nack
from ingest.quarantine import Quarantine
from storage import queries
from storage.store import FrameRow, SensorBatchRow

if TYPE_CHECKING:
    from ingest.storeloop import StoreState

log = logging.getLogger("camcal.ingest")
Key = tuple[str, str, int]


class Committer:
    def __init__(self, state: StoreState) -> None:
        self.st = state
        self.svc = state.svc
        self.store = state.store
        self.quarantine = Quarantine(self.store.files.root)
        self.recent: OrderedDict[Key, str | None] = OrderedDict()  # committed keys -> sha256 (LRU)
        self.failures: dict[tuple[str, str, int, str], list[int]] = defaultdict(list)
        self.stored = 0  # messages committed so far (to tell a bad message from a bad disk)
        self.warn = RateLimitedLog(log)

    # -- entry -----------------------------------------------------------
    def commit(self, items: list[Incoming]) -> None:
        fresh = []
        for it in items:
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
    def _commit(self, items: list[Incoming]) -> None:
        svc, files = self.svc, self.store.files
        frames: list[FrameRow] = []
        sensors: list[SensorBatchRow] = []
        payloads: dict[Key, Any] = {}
        ok: list[Incoming] = []  # stored now or before with the same content: acknowledged
        seen: dict[Key, str] = {}
        # Frames and sensor messages share one sequence per boot: look each key up in both tables.
        keys = [self._key(it) for it in items if self._key(it) not in self.recent]
        stored_frames, stored_sensors = self.store.call(queries.stored_checksums, keys, keys)
        stored_before: dict[Key, str | None] = {**stored_sensors, **stored_frames}
        for it in items:
            m, key = it.msg, self._key(it)
            if key in seen:  # the same message twice in one batch (a resend crossed the first)
                if seen[key] == m.sha256:
                    ok.append(it)
                else:
                    self._conflict(it)
                continue
            if key in self.recent or key in stored_before:
                stored = self.recent[key] if key in self.recent else stored_before[key]
                if stored is None or stored == m.sha256:  # (None: stored before checksums were kept)
                    ok.append(it)
                else:
                    self._conflict(it)
                continue
            seen[key] = m.sha256
            ok.append(it)
            if it.kind == "frame":
                rel = files.relative_path(svc.dive.id, m.module, m.boot, m.seq, m.encoding)
                payloads[key] = (rel, it.payload)
                frames.append(
                    FrameRow(
                        module_id=m.module,
                        boot=m.boot,
                        seq=m.seq,
                        captured_unix_s=m.captured_at.timestamp(),
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
                    )
                )
            else:
                sensors.append(
                    SensorBatchRow(m.module, m.boot, m.seq, it.received_unix_s, it.payload, m.sha256)
                )
        files.write_many(list(payloads.values()), fsync=svc.config.fsync)  # every file durable before its row
        received = {self._key(it): it.received_mono for it in items}
        t_done = time.monotonic()

        def frame_event(f: FrameRow, fid: int) -> Event:
            payload = {
                "frame_id": fid,
                **_frame_meta(f),
                "schedule_version": f.schedule_version,
                "stored_latency_s": round(t_done - received[(f.module_id, f.boot, f.seq)], 4),
            }
            return Event(EventKind.FRAME, payload, time.time(), f.module_id, svc.dive.id)

        outcome = self.store.commit_batch(svc.dive.id, frames, sensors, frame_event=frame_event)
        # -- committed: from here on nothing may refuse these messages --
        self.stored += len(ok)
        svc.counters.inc("frames_stored", len(outcome.new_frames))
        svc.counters.inc("duplicates", len(ok) - len(outcome.new_frames) - len(outcome.new_sensor_batches))
        for it in ok:
            self._remember(self._key(it), it.msg.sha256)
        self.st.guarded("ack", self._ack, ok)
        self.st.guarded("events", svc.events.published_stored, outcome.events)
        by_key = {(f.module_id, f.boot, f.seq): f for f in frames}
        for key, fid in outcome.new_frames.items():
            f = by_key[key]
            svc.queue_analysis(fid, f.path, {**_frame_meta(f), "received_mono": received[key]})
        for b in sensors:
            if (b.module_id, b.boot, b.seq) in outcome.new_sensor_batches:
                self.st.guarded("sensor samples", self.st.sensor_samples, b)
        self.st.guarded("gaps", self.st.gaps.arrived, ok)

    # -- refusals --------------------------------------------------------
    def _conflict(self, it: Incoming) -> None:
        m = it.msg
        self.svc.counters.inc("conflicts")
        self.st.alarms.observe_conflict(m.module, m.boot, m.seq, time.time())
        self._refuse(
            it,
            "conflict",
            f"{m.type} {m.boot}/{m.seq} is stored with other content (sha256 differs); the ship keeps "
            "the first copy: compare the module's SD card with `camcal import`",
        )

    def _failed(self, it: Incoming, exc: Exception) -> None:
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
                else wire.sensors_payload([[r.get(c) for c in wire.SENSOR_COLUMNS] for r in it.payload])
            )
            where = self.quarantine.put(key, header, payload, f"{type(exc).__name__}: {exc}")
            del self.failures[key]
            self.svc.counters.inc("quarantined")
            self._refuse(
                it, "quarantined", f"failed twice on the ship ({type(exc).__name__}); kept in {where}"
            )
        else:
            self._refuse(
                it, "internal_error", f"the ship failed to store it ({type(exc).__name__}); resend later"
            )

    def _refuse(self, it: Incoming, reason: str, detail: str) -> None:
        m = it.msg
        self.svc.counters.refuse(reason, malformed=False)
        self.svc.send_to_module(
            m.module, nack(reason, detail, {"type": m.type, "boot": m.boot, "seq": m.seq})
        )

    # -- acknowledgements ------------------------------------------------
    def _ack(self, items: list[Incoming]) -> None:
        """Acknowledge committed messages, new or duplicate, as ranges per module."""
        per_module: dict[str, dict[str, list[int]]] = defaultdict(lambda: defaultdict(list))
        for it in items:
            per_module[it.msg.module][it.msg.boot].append(it.msg.seq)
        for module, boots in per_module.items():
            ranges: list[tuple[str, int, int]] = []
            for boot, seqs in boots.items():
                seqs = sorted(set(seqs))
                start = prev = seqs[0]
                for q in seqs[1:]:
                    if q != prev + 1:
                        ranges.append((boot, start, prev))
                        start = q
                    prev = q
                ranges.append((boot, start, prev))
            self.svc.send_to_module(
                module, wire.Ack(module="ship", ranges=tuple(ranges), window=self.svc.window)
            )
            self.svc.counters.inc("acks_sent")

    # -- helpers ---------------------------------------------------------
    @staticmethod
    def _key(it: Incoming) -> Key:
        return (it.msg.module, it.msg.boot, it.msg.seq)

    @staticmethod
    def _qkey(it: Incoming) -> tuple[str, str, int, str]:
        return (it.msg.module, it.msg.boot, it.msg.seq, it.msg.sha256)

    def _remember(self, key: Key, sha: str) -> None:
        self.recent[key] = sha
        self.recent.move_to_end(key)
        while len(self.recent) > 4096:
            self.recent.popitem(last=False)


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
        )
    )
    return {**meta, "received_mono": None}
