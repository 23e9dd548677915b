"""Frames saturated by the schedule's design, told apart from the unexpected ones.

A schedule that sweeps exposures and gains (T-REX's 0.2–1 s, its high gains)
saturates many frames on purpose: the schedule preview predicts which, from the
frames seen so far (`ingest.derived.predict_settings`: the LEM's brightness per
unit of exposure and gain, per module and wavelength). A saturated frame at a
setting the same prediction calls saturated is *by design*; one at a setting
predicted usable (or not yet predictable) is unexpected: the water, the LEM or
the camera changed, and that is what the deck must see. The live cards colour
only the unexpected ones (`server.routers.live`, the hub's result events).
"""

from __future__ import annotations

import threading
import time
from typing import Any

from sqlalchemy.orm import Session

from ingest.derived import predict_settings, result_row
from storage import queries
from storage.store import Store

#: The newest analysed frames of the dive a prediction is made from (as the schedule preview).
NEWEST = 3000
#: How often the hub renews its prediction (new frames, a new schedule, other water).
REFRESH_S = 10.0

Setting = tuple[int, float, float]


def setting_key(wavelength_nm: Any, exposure_s: Any, gain_db: Any) -> Setting:
    """A setting as a key that the database's floats and an event's JSON floats both make alike."""
    return int(wavelength_nm), round(float(exposure_s), 6), round(float(gain_db), 3)


def newest_results(s: Session, module: str | None = None) -> list[dict[str, Any]]:
    """The newest analysed frames of the newest dive in its live run (of ``module`` if given)."""
    dives = queries.dives(s)
    run = queries.live_run_id(s, dives[0]["id"]) if dives else None
    if run is None:
        return []
    rows = queries.newest_result_rows(s, run, dives[0]["id"], NEWEST)
    return [r for r in rows if module in (None, r["module"])]


def saturated_by_design(
    rows: list[dict[str, Any]], linear_range: tuple[float, float]
) -> dict[str, frozenset[Setting]]:
    """Per module, the settings of ``rows`` (`storage.queries.result_rows` dicts) predicted saturated."""
    rr = [result_row(r) for r in rows]
    settings = sorted({(r.wavelength_nm, r.exposure_s, r.gain_db) for r in rr})
    pred = predict_settings(rr, settings, linear_range) if rr else {}
    return {
        m: frozenset(
            setting_key(p["wavelength_nm"], p["exposure_s"], p["gain_db"])
            for p in ps
            if p["verdict"] == "saturated"
        )
        for m, ps in pred.items()
    }


class SaturationByDesign:
    """The prediction the hub labels result events with, renewed every `REFRESH_S` by `refresh`
    (a database read: called from the hub's thread, never from the event loop)."""

    def __init__(self, store: Store, linear_range: tuple[float, float]) -> None:
        self.store = store
        self.linear_range = linear_range
        self.settings: dict[str, frozenset[Setting]] = {}
        self.at = -float("inf")
        self._lock = threading.Lock()

    def refresh(self, now_mono: float | None = None, force: bool = False) -> None:
        now_mono = time.monotonic() if now_mono is None else now_mono
        if not force and now_mono - self.at < REFRESH_S:
            return
        self.at = now_mono
        rows = self.store.call(newest_results)
        settings = saturated_by_design(rows, self.linear_range)
        with self._lock:
            self.settings = settings

    def expected(self, module: str | None, wavelength_nm: Any, exposure_s: Any, gain_db: Any) -> bool:
        """Whether a saturated frame of ``module`` at this setting is what the schedule's design predicts."""
        if module is None or wavelength_nm is None or exposure_s is None or gain_db is None:
            return False
        with self._lock:
            return setting_key(wavelength_nm, exposure_s, gain_db) in self.settings.get(module, frozenset())


def quality_split(
    quality: dict[str, int], saturated: dict[Setting, int], by_design: frozenset[Setting]
) -> dict[str, int]:
    """A module's frames by outcome, its saturated ones split into ``saturated_by_design`` and
    ``saturated`` (the unexpected), from its saturated frames counted by setting."""
    expected = sum(n for key, n in saturated.items() if setting_key(*key) in by_design)
    out = dict(quality)
    if expected:
        out["saturated_by_design"] = expected
        left = out.get("saturated", 0) - expected
        if left > 0:
            out["saturated"] = left
        else:
            out.pop("saturated", None)
    return out
