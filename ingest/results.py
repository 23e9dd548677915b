"""Analysis results back from the pool: stored, published, turned into λ_att and linearity."""

from __future__ import annotations

import logging
import time
from collections import defaultdict, deque
from concurrent.futures.process import BrokenProcessPool
from typing import Any

import numpy as np

from camcal.core.events import Event, EventKind, ResultPayload
from ingest.context import StoreContext
from ingest.derived import linearity_rows
from ingest.faults import ships_fault
from ingest.messages import Analysed
from ingest.rolling import Changes, Sample, VisitSeries
from storage import queries
from storage.db import error_line

log = logging.getLogger("camcal.ingest")

#: How long kept results wait before the next try to store them (`Results.store_unsaved`).
UNSAVED_RETRY_S = 2.0
#: One transaction of results: their rows, their events, the λ_att visits they changed.
Commit = tuple[list[dict[str, Any]], list[Event], Changes | None]
#: A frame's result when it killed an analysis process on its own (`ingest.analysis_pool`).
CRASHED = (
    "the analysis process died while analysing this frame alone (after dying with it among "
    "others): the frame file is stored; run `camcal analyze` on it to see why"
)


def crashed_row() -> dict[str, Any]:
    """The result of a frame that killed an analysis process on its own (live and re-analysis)."""
    return {"status": "rejected", "reason": "analysis_crashed", "detail": CRASHED}


class Results:
    def __init__(self, ctx: StoreContext) -> None:
        self.st = ctx
        self.store = ctx.store
        #: Commits the ship could not store yet (`store_unsaved`), oldest first.
        self.unsaved: deque[Commit] = deque()
        self.unsaved_retry_mono = 0.0
        self.series: VisitSeries | None = None
        self.last_result_mono = time.monotonic()
        try:
            self.series = VisitSeries(ctx.config.setup)
        except ValueError:
            log.warning("no λ_att series: the setup has fewer than two cameras with distances")
        if self.series is not None:  # after a restart: the visits of the frames already analysed
            served = ctx.config.serves  # (another ingest's modules are its own business)
            rows = self.store.call(queries.result_rows, ctx.run_id, ctx.dive_id)
            self._store_points(self.series.add(Sample.from_result(r) for r in rows if served(r["module"])))
        self.linearity: dict[tuple[str, int], dict[tuple[float, float], list[float]]] = defaultdict(
            lambda: defaultdict(list)
        )
        self.linearity_dirty: set[tuple[str, int]] = set()

    def handle(self, items: list[Analysed]) -> None:
        rows = []
        done = []
        for it in items:
            frame_id, meta, fut = it.frame_id, it.meta, it.future
            if self.st.analysis.crashed(fut):  # its process died: analysed again, alone
                continue
            try:
                row = fut.result()
            except BrokenProcessPool:  # analysed alone, and its process died again
                log.error("frame %s killed an analysis process on its own: stored as rejected", frame_id)
                row = crashed_row()
            except Exception as exc:  # the analysis raised: record it, keep going
                log.exception("analysis of frame %s failed", frame_id)
                row = {"status": "rejected", "reason": "analysis_error", "detail": str(exc)[:500]}
            analysis_s = row.pop("analysis_s", None)
            row.pop("width_px", None)
            row.pop("height_px", None)
            rows.append({**row, "frame_id": frame_id, "analysed_unix_s": time.time()})
            done.append((frame_id, meta, row, analysis_s))
        if not done:  # all of them are to be analysed again
            return
        now_mono = time.monotonic()
        samples: list[Sample] = []
        events: list[Event] = []
        for item in done:  # a result that cannot be taken in is still stored (without its event)
            self.st.guarded("result", self._take_in, item, now_mono, events, samples)
        changes: list[Changes] = []
        if self.series is not None:
            self.last_result_mono = now_mono
            series = self.series
            self.st.guarded("λ_att series", lambda: changes.append(series.add(samples)))
        self._commit(rows, events, changes[0] if changes else None)

    def _take_in(
        self,
        item: tuple[int, dict[str, Any], dict[str, Any], float | None],
        now_mono: float,
        events: list[Event],
        samples: list[Sample],
    ) -> None:
        """Count a result, show it to the alarms and the linearity fits; its event and λ_att sample."""
        st = self.st
        frame_id, meta, row, analysis_s = item
        module = meta["module"]
        if meta.get("received_mono") is not None:
            st.latency_s.append(now_mono - meta["received_mono"])
        st.counters.inc("frames_analysed")
        st.counters.inc(f"result_{row['status'] if row['status'] == 'ok' else row['reason']}")
        centroid = (
            (row["centroid_x_px"], row["centroid_y_px"]) if row.get("centroid_x_px") is not None else None
        )
        self.st.alarms.observe_frame(
            module,
            row["status"],
            row.get("reason"),
            centroid,
            row.get("radius_px"),
            (meta.get("width_px") or 1, meta.get("height_px") or 1),
            int(meta.get("wavelength_nm") or 0),
        )
        payload: ResultPayload = {
            "frame_id": frame_id,
            "seq": meta["seq"],
            "wavelength_nm": meta["wavelength_nm"],
            "exposure_s": meta["exposure_s"],
            "gain_db": meta["gain_db"],
            "depth_m": meta["depth_m"],
            "captured_unix_s": meta["captured_unix_s"],
            "captured_ship_unix_s": meta.get("captured_ship_unix_s"),
            "status": row["status"],
            "reason": row.get("reason"),
            "centroid_px": list(centroid) if centroid else None,
            "radius_px": row.get("radius_px"),
            "i_center_gray": row.get("i_center_gray"),
            "i_center_err_gray": row.get("i_center_err_gray"),
            "background_gray": row.get("background_gray"),
            "width_px": meta.get("width_px"),
            "height_px": meta.get("height_px"),
            "thumb": f"/api/frames/{frame_id}/thumbnail",
            "analysis_s": round(analysis_s, 4) if analysis_s else None,
        }
        if row.get("center_gray") is not None:
            key = (module, meta["wavelength_nm"])
            self.linearity[key][(meta["exposure_s"], meta["gain_db"])].append(row["center_gray"])
            self.linearity_dirty.add(key)
        sample = Sample.from_result({**meta, **row, "frame_id": frame_id})
        events.append(Event(EventKind.RESULT, dict(payload), time.time(), module, st.dive_id))
        samples.append(sample)

    def close_idle_visits(self) -> None:
        """The modules went quiet (no result for ``visit_idle_close_s``): their open visits are final."""
        if (
            self.series is not None
            and time.monotonic() - self.last_result_mono > self.st.config.visit_idle_close_s
        ):
            self._store_points(self.series.close_all())

    def _store_points(self, changes: Changes) -> None:
        """Store the λ_att visits that changed and publish them (``final`` false: provisional)."""
        if changes:
            self._commit([], [], changes)

    def _commit(self, rows: list[dict[str, Any]], events: list[Event], changes: Changes | None) -> None:
        """Results, the visits they changed and all their events in one transaction; then published.

        When the ship cannot store (`ships_fault`: a full disk, a locked database) they are kept,
        in order, and stored by `store_unsaved` once it can: what is taken in (counts, the λ_att
        series in memory) is never taken in twice, and a later commit never overtakes an earlier
        one (a visit's newer values must win).
        """
        self.unsaved.append((rows, events, changes))
        self.store_unsaved()

    def store_unsaved(self) -> None:
        """Store the kept commits, oldest first, until one fails again (then try later)."""
        if not self.unsaved or time.monotonic() < self.unsaved_retry_mono:
            return
        while self.unsaved:
            try:
                self._commit_now(*self.unsaved[0])
            except Exception as exc:
                if not ships_fault(exc):  # its own fault: retrying it whole cannot help
                    failed = self.unsaved.popleft()
                    parts = split_commit(*failed)  # each result alone: one bad result costs one
                    if len(parts) == 1:  # one result: stored as rejected (a replacement, visits: lost)
                        parts = unstorable(*failed, exc)
                        if not parts:
                            raise
                        self.st.counters.inc("handler_errors")
                        log.error(
                            "a result could not be stored, stored as rejected: %s: %s",
                            type(exc).__name__,
                            exc,
                        )
                    self.unsaved.extendleft(reversed(parts))
                    continue
                self.unsaved_retry_mono = time.monotonic() + UNSAVED_RETRY_S
                self.st.warn(
                    logging.ERROR,
                    "results unsaved",
                    "ingest: cannot store analysis results now (%s: %s); %d commit(s) kept, retried every "
                    "%g s",
                    type(exc).__name__,
                    exc,
                    len(self.unsaved),
                    UNSAVED_RETRY_S,
                )
                return
            self.unsaved.popleft()

    def _commit_now(self, rows: list[dict[str, Any]], events: list[Event], changes: Changes | None) -> None:
        st = self.st
        upserts = (
            [{**r, "run_id": st.run_id, "dive_id": st.dive_id} for r in changes.upserts] if changes else []
        )
        deletes = list(changes.deletes) if changes else []

        def point_events(ids: dict[str, int]) -> list[Event]:
            now, dive = time.time(), st.dive_id
            out = [
                Event(EventKind.ATTENUATION, {"visit_key": key, "deleted": True}, now, None, dive)
                for key in deletes
            ]
            for r in upserts:  # the point's columns (`storage.models.AttenuationPoint`) but its details
                payload = {
                    "point_id": ids.get(r["visit_key"]),
                    **{k: v for k, v in r.items() if k != "details"},
                }
                out.append(Event(EventKind.ATTENUATION, payload, now, None, dive))
            return out

        stored = self.store.commit_results(
            st.run_id, rows, events, upserts=upserts, deletes=deletes, point_events=point_events
        )
        st.events.published_stored(stored)

    def update_linearity(self) -> None:
        st = self.st
        lr = tuple(st.config.setup.linear_range)
        rows = []
        for module, wl in list(self.linearity_dirty):
            points = {k: float(np.mean(v)) for k, v in self.linearity[(module, wl)].items()}
            rows += [
                {
                    **row,
                    "run_id": st.run_id,
                    "module_id": module,
                    "wavelength_nm": wl,
                    "updated_unix_s": time.time(),
                }
                for row in linearity_rows(points, lr)  # type: ignore[arg-type]
            ]
        self.store.upsert_linearity(rows)  # one transaction (one fsync) for all of them
        self.linearity_dirty.clear()


def split_commit(rows: list[dict[str, Any]], events: list[Event], changes: Changes | None) -> list[Commit]:
    """A commit that failed for its own reason, as one commit per result (with that frame's events)
    and one for the λ_att visits and any other events: what is good is stored, the bad part alone
    fails. Nothing is taken in again (counts, alarms, linearity and the series saw each result once).
    """
    by_frame: dict[Any, list[Event]] = defaultdict(list)
    for e in events:
        by_frame[e.payload.get("frame_id")].append(e)
    parts: list[Commit] = [([r], by_frame.pop(r["frame_id"], []), None) for r in rows]
    rest = [e for es in by_frame.values() for e in es]
    if changes or rest or not parts:
        parts.append(([], rest, changes))
    return parts


#: The start of the detail of a result that replaced one the database refused (`unstorable`).
UNSTORABLE = "its analysis result could not be stored"


def unstorable(
    rows: list[dict[str, Any]], events: list[Event], changes: Changes | None, exc: Exception
) -> list[Commit]:
    """One result the database refused for its own reason (not the ship's: a value it cannot take),
    as a rejected result of that frame, so that the frame is not left unanalysed (and analysed again
    at every start); nothing if ``rows`` is not one result, or already such a replacement."""
    if len(rows) != 1 or changes or str(rows[0].get("detail") or "").startswith(UNSTORABLE):
        return []
    row = rows[0]
    detail = f"{UNSTORABLE} ({type(exc).__name__}: {error_line(exc)}); run `camcal analyze` on the frame"
    kept = {"frame_id": row["frame_id"], "analysed_unix_s": row.get("analysed_unix_s"), "status": "rejected"}
    kept |= {"reason": "analysis_error", "detail": detail[:500]}
    shown = [
        Event(
            e.kind, {**e.payload, "status": "rejected", "reason": "analysis_error"}, e.t, e.module, e.dive_id
        )
        for e in events
    ]
    return [([kept], shown, None)]
