"""The live λ_att series: one point per LEM visit, kept up to date as frame results arrive.

A visit is a run of one wavelength's frames of the near and far cameras:
all frames (accepted or not) sorted by capture time form segments of one
wavelength, cut where the wavelength changes, where no frame came for more
than ``visit_gap_s`` or where the LEM's depth jumps by more than
``visit_depth_jump_m`` between two frames (the winch moved between a stop
and the next); a segment longer than ``visit_max_s`` is cut at multiples of
``visit_max_s`` (UTC). The segments are a function of the set
of frames alone, not of the order their results arrive in, so the live
ingest (results in any order, two modules interleaved) and a re-analysis
(all results at once) cut the same visits and compute the same points
(`analysis.visit.visit_attenuation`).

A visit's point is *provisional* while frames may still join it and
*final* once both cameras have moved on: each has sent a frame of another
wavelength after the visit's last frame, or a frame more than
``visit_gap_s`` later. A result that arrives after that (a frame still in
analysis, a module catching up after a lost link) updates the point again,
so the stored series always equals what a re-analysis of the same frames
gives. A visit's trend prior comes from each camera's levels in the
wavelength's previous visits (`analysis.visit.trend_prior`), so a change to
a visit recomputes the next visits of its wavelength as well.

`VisitSeries.add` takes a batch of frame results and returns the changes
to store: points to insert or update (keyed by ``visit_key``) and the keys
of visits that no longer exist (two visits joined by a late frame).
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

from analysis import EmissionRatio, Geometry
from analysis.visit import (
    CameraLevel,
    TrendPrior,
    VisitFrame,
    VisitResult,
    camera_level,
    trend_prior,
    visit_attenuation,
)
from camcal.core.frameset import SeriesSetup, Setup
from ingest.derived import geometry_and_ratios

#: Most frame results a series keeps in memory; the oldest are forgotten beyond it.
MAX_SAMPLES = 200_000
#: Visits of a wavelength without a camera's frames skipped looking for its earlier levels.
MAX_SKIPPED_VISITS = 2


@dataclass(frozen=True)
class Sample:
    """One analysed frame as the series needs it (rejected frames too: they mark visits)."""

    frame_id: int
    module: str
    wavelength_nm: int
    t_unix_s: float
    depth_m: float | None
    exposure_s: float
    gain_db: float
    ok: bool = False
    i_center_gray: float | None = None
    i_center_err_gray: float | None = None
    #: ``t_unix_s`` on the ship's clock (`camcal.core.clockmap`; None: not known).
    t_ship_unix_s: float | None = None

    @property
    def order(self) -> tuple[float, str, int]:
        return (self.t_unix_s, self.module, self.frame_id)

    @classmethod
    def from_result(cls, r: dict[str, Any]) -> Sample:
        """From a `storage.store.Store.result_rows` dict (or the same keys)."""
        ok = r["status"] == "ok" and r["i_center_gray"] is not None and r["i_center_err_gray"] is not None
        return cls(
            int(r["frame_id"]),
            r["module"],
            int(r["wavelength_nm"]),
            float(r["captured_unix_s"]),
            r["depth_m"],
            float(r["exposure_s"]),
            float(r["gain_db"]),
            ok,
            r["i_center_gray"] if ok else None,
            r["i_center_err_gray"] if ok else None,
            r.get("captured_ship_unix_s"),
        )


@dataclass
class Visit:
    """A visit as last computed: its frames, its point (None: no pair yet), and each camera's
    level and the LEM's mean depth (what the next visits' trend priors read)."""

    key: str
    wavelength_nm: int
    samples: list[Sample]
    result: VisitResult | None
    levels: dict[str, CameraLevel | None]
    lem_depth_m: float | None
    final: bool = False
    row: dict[str, Any] | None = field(default=None, repr=False)


@dataclass(frozen=True)
class Changes:
    """What a batch changed: rows to upsert (by ``visit_key``) and visit keys to delete."""

    upserts: list[dict[str, Any]]
    deletes: list[str]

    def __bool__(self) -> bool:
        return bool(self.upserts or self.deletes)


class VisitSeries:
    """The per-visit λ_att series of one analysis run (see the module docstring)."""

    def __init__(self, setup: Setup) -> None:
        gr = geometry_and_ratios(setup)
        if gr is None:
            raise ValueError("a λ_att series needs two cameras with distances in the setup")
        self.geometry: Geometry = gr[0]
        self.ratios: dict[int, EmissionRatio] = gr[1]
        self.rules: SeriesSetup = setup.series
        self.distances = {name: cam.distance_m for name, cam in setup.cameras.items()}
        #: A module's clock ahead of true time: its frames' times are corrected before pairing.
        self.clock_offsets = {n: c.clock_offset_s for n, c in setup.cameras.items() if c.clock_offset_s}
        self._cams = (self.geometry.near_camera, self.geometry.far_camera)
        self._samples: list[Sample] = []  # every sample of the two cameras, in capture order
        self._orders: list[tuple[float, str, int]] = []
        self._seen: set[int] = set()
        self._visits: dict[str, Visit] = {}
        self._by_wl: dict[int, list[tuple[float, str]]] = {}  # (first frame's time, key), sorted
        self._open: set[str] = set()
        self._newest: dict[str, float] = {}
        self._newest_by_wl: dict[tuple[str, int], float] = {}

    # ------------------------------------------------------------------ input
    def add(self, samples: Iterable[Sample]) -> Changes:
        """Add a batch of analysed frames; returns the points to store."""
        spans: list[tuple[float, float]] = []
        for s in samples:
            if s.module not in self._cams or s.frame_id in self._seen:
                continue
            if s.module in self.clock_offsets:
                s = replace(s, t_unix_s=s.t_unix_s - self.clock_offsets[s.module])
            self._seen.add(s.frame_id)
            i = bisect.bisect(self._orders, s.order)
            self._orders.insert(i, s.order)
            self._samples.insert(i, s)
            spans.append(self._segment_span(i))
            self._newest[s.module] = max(self._newest.get(s.module, -math.inf), s.t_unix_s)
            key = (s.module, s.wavelength_nm)
            self._newest_by_wl[key] = max(self._newest_by_wl.get(key, -math.inf), s.t_unix_s)
        changes = self._recompute(_merge(spans)) if spans else Changes([], [])
        finals = self._close(lambda v: self._moved_on(v))
        self._forget()
        return Changes(_dedupe(changes.upserts + finals.upserts), changes.deletes)

    def close_all(self) -> Changes:
        """Every open visit is final (the stream ended: a re-analysis, or the modules went quiet)."""
        return self._close(lambda v: True)

    def points(self) -> list[dict[str, Any]]:
        """The current rows of every visit with a point, in time order."""
        rows = [v.row for v in self._visits.values() if v.row is not None]
        return sorted(rows, key=lambda r: (r["t_unix_s"], r["wavelength_nm"]))

    # ------------------------------------------------------------------ visits
    def _segment_span(self, i: int) -> tuple[float, float]:
        """Capture-time span of the samples a new sample at index ``i`` can affect."""
        lo = i
        while lo > 0 and not self._cut(lo):
            lo -= 1
        hi = i
        while hi + 1 < len(self._samples) and not self._cut(hi + 1):
            hi += 1
        # One more segment on each side: the new sample may have joined it or split it off.
        lo = max(lo - 1, 0)
        while lo > 0 and not self._cut(lo):
            lo -= 1
        hi = min(hi + 1, len(self._samples) - 1)
        while hi + 1 < len(self._samples) and not self._cut(hi + 1):
            hi += 1
        return self._samples[lo].t_unix_s, self._samples[hi].t_unix_s

    def _cut(self, j: int) -> bool:
        """True if a segment starts at sample ``j``: a new wavelength, a gap, or the LEM moved."""
        a, b = self._samples[j - 1], self._samples[j]
        if a.wavelength_nm != b.wavelength_nm or b.t_unix_s - a.t_unix_s > self.rules.visit_gap_s:
            return True
        if a.depth_m is None or b.depth_m is None:
            return False
        jump = (b.depth_m + self.distances[b.module]) - (a.depth_m + self.distances[a.module])
        return abs(jump) > self.rules.visit_depth_jump_m

    def _segments(self, t_lo: float, t_hi: float) -> list[list[Sample]]:
        """The visits whose samples lie in [t_lo, t_hi] (a span that starts and ends at cuts)."""
        i0 = bisect.bisect_left(self._orders, (t_lo, "", -1))
        i1 = bisect.bisect_right(self._orders, (t_hi, "\U0010ffff", 2**63))
        out: list[list[Sample]] = []
        for j in range(i0, i1):
            if j == i0 or self._cut(j):
                out.append([])
            out[-1].append(self._samples[j])
        visits = []
        step = self.rules.visit_max_s
        for seg in out:
            if seg[-1].t_unix_s - seg[0].t_unix_s <= step:
                visits.append(seg)
                continue
            chunks: dict[int, list[Sample]] = {}
            for s in seg:
                chunks.setdefault(math.floor(s.t_unix_s / step), []).append(s)
            visits.extend(chunks[k] for k in sorted(chunks))
        return visits

    def _recompute(self, spans: Sequence[tuple[float, float]]) -> Changes:
        upserts: list[dict[str, Any]] = []
        deletes: list[str] = []
        changed: dict[str, tuple[int, float]] = {}  # visits made, remade or gone: (wavelength, t)
        for t_lo, t_hi in spans:
            old = {
                k
                for k, v in self._visits.items()
                if v.samples[0].t_unix_s <= t_hi and v.samples[-1].t_unix_s >= t_lo
            }
            new: dict[str, list[Sample]] = {}
            for seg in self._segments(t_lo, t_hi):
                new[_visit_key(seg)] = seg
            for k in sorted(old - set(new)):
                self._open.discard(k)
                gone = self._drop(k)
                changed[k] = (gone.wavelength_nm, gone.samples[0].t_unix_s)
                if gone.row is not None:
                    deletes.append(k)
            for k, seg in new.items():
                prev = self._visits.get(k)
                if prev is not None and prev.samples == seg:
                    continue
                if prev is None:
                    bisect.insort(self._by_wl.setdefault(seg[0].wavelength_nm, []), (seg[0].t_unix_s, k))
                visit = self._make(k, seg, final=bool(prev and prev.final))
                changed[k] = (visit.wavelength_nm, seg[0].t_unix_s)
                if not visit.final:
                    self._open.add(k)
                if visit.row is not None:
                    upserts.append(visit.row)
                elif prev is not None and prev.row is not None:
                    deletes.append(k)
        # The next visits of a changed visit's wavelength take their trend priors from it.
        for k in self._followers(changed):
            v = self._visits[k]
            v = self._make(k, v.samples, final=v.final)
            if v.row is not None:
                upserts.append(v.row)
        return Changes(upserts, deletes)

    def _make(self, key: str, seg: list[Sample], *, final: bool) -> Visit:
        """Compute a visit's point from its frames and the wavelength's earlier visits; keep it."""
        wl = seg[0].wavelength_nm
        frames = [
            VisitFrame(
                s.module,
                s.exposure_s,
                s.gain_db,
                s.t_unix_s,
                float(s.i_center_gray),  # type: ignore[arg-type]
                float(s.i_center_err_gray),  # type: ignore[arg-type]
                None if s.depth_m is None else s.depth_m + self.distances[s.module],
            )
            for s in seg
            if s.ok
        ]
        levels = {cam: camera_level(frames, cam) for cam in self._cams}
        depths = [f.lem_depth_m for f in frames if f.lem_depth_m is not None]
        visit = Visit(key, wl, seg, None, levels, sum(depths) / len(depths) if depths else None, final)
        ratio = self.ratios.get(wl)
        if ratio is not None:
            visit.result = visit_attenuation(
                frames,
                wl,
                self.geometry,
                ratio,
                repeatability=self.rules.repeatability_at(wl),
                trend_prior_per_s=self.rules.trend_prior_per_s,
                trend_priors=self._priors(visit),
            )
        if visit.result is not None:
            visit.row = self._row(visit)
        self._visits[key] = visit
        return visit

    def _priors(self, visit: Visit) -> dict[str, TrendPrior]:
        """Each camera's trend prior from its levels in this visit and the wavelength's two latest
        visits before it that have one (visits without that camera's frames skipped), each
        within ``trend_visits_max_s`` of the next and at the same LEM depth."""
        index = self._by_wl.get(visit.wavelength_nm, [])
        i = bisect.bisect_left(index, (visit.samples[0].t_unix_s, visit.key))
        rep = self.rules.repeatability_at(visit.wavelength_nm)
        priors = {}
        for cam in self._cams:
            if visit.levels[cam] is None:
                continue
            chain = [visit]
            for _, k in reversed(index[max(i - MAX_SKIPPED_VISITS - 2, 0) : i]):
                earlier, later = self._visits[k], chain[0]
                gap = later.samples[0].t_unix_s - earlier.samples[-1].t_unix_s
                if gap > self.rules.trend_visits_max_s or not _same_depth(
                    earlier.lem_depth_m, later.lem_depth_m, self.rules.visit_depth_jump_m
                ):
                    break
                if earlier.levels[cam] is not None:
                    chain.insert(0, earlier)
                    if len(chain) == 3:
                        break
            levels = [v.levels[cam] for v in chain]
            priors[cam] = trend_prior(levels, rep, self.rules.trend_prior_per_s)  # type: ignore[arg-type]
        return priors

    def _followers(self, changed: dict[str, tuple[int, float]]) -> list[str]:
        """The visits (not themselves changed) whose trend priors may read a changed visit: the
        next ones of its wavelength, as many as `_priors` looks back over."""
        out: list[str] = []
        for wl, t in sorted(changed.values()):
            index = self._by_wl.get(wl, [])
            i = bisect.bisect_right(index, (t, "\U0010ffff"))
            for _, k in index[i : i + 2 + MAX_SKIPPED_VISITS]:
                if k not in changed and k not in out:
                    out.append(k)
        return sorted(out, key=lambda k: self._visits[k].samples[0].t_unix_s)

    def _drop(self, key: str) -> Visit:
        visit = self._visits.pop(key)
        index = self._by_wl[visit.wavelength_nm]
        index.pop(bisect.bisect_left(index, (visit.samples[0].t_unix_s, key)))
        return visit

    def _moved_on(self, v: Visit) -> bool:
        """Both cameras have sent a later frame of another wavelength, or one beyond the gap."""
        t_last = v.samples[-1].t_unix_s
        for cam in self._cams:
            newest = self._newest.get(cam, -math.inf)
            if newest > t_last + self.rules.visit_gap_s:
                continue
            same = self._newest_by_wl.get((cam, v.wavelength_nm), -math.inf)
            if newest > t_last and newest > same:
                continue  # its newest frame is of another wavelength and later than the visit
            return False
        return True

    def _close(self, done: Callable[[Visit], bool]) -> Changes:
        rows = []
        for k in sorted(self._open):
            v = self._visits[k]
            if done(v):
                v.final = True
                self._open.discard(k)
                if v.result is not None:
                    v.row = self._row(v)
                    rows.append(v.row)
        return Changes(rows, [])

    def _row(self, v: Visit) -> dict[str, Any]:
        res = v.result
        assert res is not None
        return {
            "visit_key": v.key,
            "wavelength_nm": res.wavelength_nm,
            "t_unix_s": res.t_s,
            "t_ship_unix_s": _on_ship(v.samples, res.t_s),
            "t_first_unix_s": res.t_first_s,
            "t_last_unix_s": res.t_last_s,
            "depth_m": res.lem_depth_m,
            "lambda_att_m": res.lambda_att_m,
            "stat_err_m": res.stat_err_m,
            "sys_err_m": res.sys_err_m,
            "n_pairs": res.n_pairs,
            "n_frames": res.n_frames,
            "chi2_ndof": res.chi2_ndof,
            "window_s": res.t_last_s - res.t_first_s,
            "final": v.final,
            "details": visit_details(res),
        }

    def _forget(self) -> None:
        """Drop the oldest samples (and their final visits) beyond `MAX_SAMPLES`."""
        extra = len(self._samples) - MAX_SAMPLES
        if extra <= 0:
            return
        cutoff = self._samples[extra].t_unix_s
        for k in [k for k, v in self._visits.items() if v.final and v.samples[-1].t_unix_s < cutoff]:
            self._drop(k)
        for s in self._samples[:extra]:
            self._seen.discard(s.frame_id)
        del self._samples[:extra]
        del self._orders[:extra]


def visit_details(res: VisitResult) -> dict[str, Any]:
    """What a stored point keeps besides its columns: pairs, error terms, trends."""
    return {
        "log_ratio": res.log_ratio,
        "log_ratio_err": res.log_ratio_err,
        "terms": res.terms,
        "trends": {c: [t.slope_per_s, t.slope_err_per_s, t.fitted, t.prior] for c, t in res.trends.items()},
        "pairs": [
            [p.exposure_s, p.gain_db, p.n_near, p.n_far, p.log_ratio, p.log_ratio_err, p.trend_shift]
            for p in res.pairs
        ],
        "note": res.note,
    }


def _on_ship(samples: Sequence[Sample], t_unix_s: float) -> float | None:
    """A time of the visit's frames (their modules' clocks) on the ship's: interpolated between its
    frames' two times (the mapping is linear per module boot), None where they have no ship's time."""
    known = sorted((s.t_unix_s, s.t_ship_unix_s) for s in samples if s.t_ship_unix_s is not None)
    if not known:
        return None
    if len(known) == 1:
        t, ship = known[0]
        return ship + (t_unix_s - t)  # (one frame: its rate is not known here; the shift is)
    i = min(max(bisect.bisect_left([t for t, _ in known], t_unix_s), 1), len(known) - 1)
    (t0, s0), (t1, s1) = known[i - 1], known[i]
    return s0 if t1 == t0 else s0 + (s1 - s0) * (t_unix_s - t0) / (t1 - t0)


def _same_depth(a: float | None, b: float | None, jump_m: float) -> bool:
    return a is None or b is None or abs(a - b) <= jump_m


def _visit_key(seg: Sequence[Sample]) -> str:
    first = seg[0]
    return f"{first.wavelength_nm}:{first.t_unix_s:.6f}:{first.module}:{first.frame_id}"


def _merge(spans: list[tuple[float, float]]) -> list[tuple[float, float]]:
    spans = sorted(spans)
    out = [spans[0]]
    for lo, hi in spans[1:]:
        if lo <= out[-1][1]:
            out[-1] = (out[-1][0], max(out[-1][1], hi))
        else:
            out.append((lo, hi))
    return out


def _dedupe(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The last row per visit key, in first-seen order."""
    last = {r["visit_key"]: r for r in rows}
    return list(last.values())


def series_rows(samples: Iterable[Sample], setup: Setup) -> list[dict[str, Any]]:
    """The final per-visit series of a set of frames, all at once (a re-analysis)."""
    series = VisitSeries(setup)
    series.add(samples)
    series.close_all()
    return series.points()
