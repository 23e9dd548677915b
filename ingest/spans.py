"""λ_att over a span of a dive (the station, the whole dive, a depth range): stacks, pairs, depth bands.

The frames of each camera are stacked per setting and the near camera's
stacks paired with the far camera's, within one depth band only: a span
that crosses depths (1200 m, 2021 m, 3420 m) holds other water at each, so
its bands get a value each, and the span's one value only where they agree.
The API's λ_att table, ``camcal report``, the export and ``camcal fit
--dive`` all take their span here.
"""

from __future__ import annotations

import bisect
import itertools
import math
from collections import defaultdict
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from analysis import AttenuationResult, EmissionRatio, Geometry, combine_pairs, pair_result
from camcal.core.frameset import Setup
from ingest.derived import ResultRow, geometry_and_ratios, result_row

#: LEM depths of neighbouring frames further apart than this begin another depth band (other water).
BAND_GAP_M = 50.0
#: A depth band is at most this tall: frames taken all the way down form bands of this height.
BAND_MAX_M = 100.0
#: Bands whose λ_att differ beyond this χ²/ndof (of their log ratios about their mean) hold other water.
BANDS_DIFFER_CHI2_NDOF = 4.0


@dataclass(frozen=True)
class DepthBand:
    """λ_att per wavelength from the frames of a span at one depth: a stop, the station, or a slice
    of a profile. Depths are the LEM's (the frames' module depth plus its distance to the LEM)."""

    depth_min_m: float | None
    depth_max_m: float | None
    n_frames: int
    results: dict[int, AttenuationResult]

    @property
    def depth_m(self) -> float | None:
        if self.depth_min_m is None or self.depth_max_m is None:
            return None
        return (self.depth_min_m + self.depth_max_m) / 2


@dataclass(frozen=True)
class SpanAttenuation:
    """λ_att per wavelength over a span (``overall``) and per depth band (``bands``, deepest last).

    Near and far frames are stacked and paired within a band only: frames of one setting taken at
    1200 m and 3420 m are not one stack. With several bands ``overall`` combines every band's
    pairs when the bands agree, and has no value (its note names the bands) when they differ.
    """

    overall: dict[int, AttenuationResult]
    bands: list[DepthBand]

    def pair_depth_m(self, wavelength_nm: int) -> list[float | None]:
        """The LEM depth of each pair of ``overall[wavelength_nm].pairs``, in their order."""
        out: list[float | None] = []
        for b in self.bands:
            res = b.results.get(wavelength_nm)
            out += [b.depth_m] * (len(res.pairs) if res else 0)
        return out


def depth_bands(depths_m: Sequence[float]) -> list[tuple[float, float]]:
    """Bands ``(top, bottom)`` of depth: the sorted depths cut where neighbours lie more than
    `BAND_GAP_M` apart, and a cluster taller than `BAND_MAX_M` cut into equal slices no taller."""
    ds = sorted(depths_m)
    if not ds:
        return []
    clusters = []
    top = prev = ds[0]
    for d in ds[1:]:
        if d - prev > BAND_GAP_M:
            clusters.append((top, prev))
            top = d
        prev = d
    clusters.append((top, prev))
    out = []
    for lo, hi in clusters:
        n = max(1, math.ceil((hi - lo) / BAND_MAX_M - 1e-9))
        edges = [lo + (hi - lo) * k / n for k in range(n)] + [hi]
        out += list(itertools.pairwise(edges))
    return out


def _pairs(
    rows: Iterable[ResultRow], geometry: Geometry, ratios: dict[int, EmissionRatio]
) -> dict[int, list[Any]]:
    """Near/far pairs per wavelength: each setting's frames of a camera stacked, near with far."""
    stacks: dict[tuple[str, int, float, float], list[tuple[float, float]]] = defaultdict(list)
    for r in rows:
        if r.status == "ok" and r.i_center_gray is not None and r.i_center_err_gray is not None:
            stacks[(r.module, r.wavelength_nm, r.exposure_s, r.gain_db)].append(
                (r.i_center_gray, r.i_center_err_gray)
            )
    pairs: dict[int, list[Any]] = defaultdict(list)
    for (cam, wl, exp, gain), near in stacks.items():
        if cam != geometry.near_camera or wl not in ratios:
            continue
        far = stacks.get((geometry.far_camera, wl, exp, gain))
        if not far:
            continue
        pair = pair_result(wl, exp, gain, _stack(near), _stack(far), geometry, ratios[wl])
        if math.isfinite(pair.log_ratio) and pair.log_ratio_err > 0:
            pairs[wl].append(pair)
    return pairs


def span_attenuation_by_band(rows: Iterable[ResultRow], setup: Setup) -> SpanAttenuation:
    """λ_att per wavelength over a span of frames, per depth band and overall (`SpanAttenuation`)."""
    gr = geometry_and_ratios(setup)
    if gr is None:
        return SpanAttenuation({}, [])
    geometry, ratios = gr
    rows = list(rows)
    offset = {m: c.distance_m for m, c in setup.cameras.items()}

    def lem_depth(r: ResultRow) -> float | None:  # None where unknown (a NaN or inf row is unknown too)
        d = None if r.depth_m is None else r.depth_m + offset.get(r.module, 0.0)
        return d if d is not None and math.isfinite(d) else None

    bounds = depth_bands([d for d in map(lem_depth, rows) if d is not None])
    members: dict[int, list[ResultRow]] = defaultdict(list)  # band index (-1: depth unknown)
    for r in rows:
        d = lem_depth(r)
        k = -1 if d is None else max(0, bisect.bisect_right([lo for lo, _ in bounds], d) - 1)
        members[k].append(r)
    bands = []
    for k in sorted(members):
        pairs = _pairs(members[k], geometry, ratios)
        lo, hi = bounds[k] if k >= 0 else (None, None)
        results = {wl: combine_pairs(ps, geometry, ratios[wl]) for wl, ps in pairs.items() if ps}
        bands.append(DepthBand(lo, hi, len(members[k]), results))
    overall = {}
    for wl in sorted({wl for b in bands for wl in b.results}):
        per_band = [(b, b.results[wl]) for b in bands if wl in b.results]
        res = combine_pairs([p for _, r in per_band for p in r.pairs], geometry, ratios[wl])
        if len(per_band) > 1:
            res = _across_bands(res, per_band)
        overall[wl] = res
    return SpanAttenuation(overall, bands)


def _across_bands(
    res: AttenuationResult, per_band: list[tuple[DepthBand, AttenuationResult]]
) -> AttenuationResult:
    """The combination of several bands' pairs: kept, with a note, when the bands agree; without a
    value, its note naming each band's, when they differ (other water at other depths)."""
    lr = np.array([r.log_ratio for _, r in per_band])
    err = np.array([r.log_ratio_err for _, r in per_band])
    w = 1 / err**2
    chi2_ndof = float(np.sum(w * (lr - np.sum(w * lr) / np.sum(w)) ** 2) / (len(per_band) - 1))
    values = "; ".join(
        f"{_depth_label(b)}: "
        + (f"{r.lambda_att_m:.2f} ± {r.stat_err_m:.2f} m" if r.lambda_att_m is not None else "none")
        for b, r in per_band
    )
    if chi2_ndof > BANDS_DIFFER_CHI2_NDOF:
        return replace(
            res,
            lambda_att_m=None,
            stat_err_m=None,
            sys_err_m=None,
            note=f"the span crosses {len(per_band)} depths whose water differs (χ²/ndof {chi2_ndof:.1f} "
            f"between them): no one value; per depth {values}",
        )
    return replace(
        res,
        note=f"pairs of {len(per_band)} depths whose λ_att agree (χ²/ndof {chi2_ndof:.1f} between them): "
        f"{values}",
    )


def _depth_label(b: DepthBand) -> str:
    if b.depth_min_m is None or b.depth_max_m is None:
        return "depth unknown"
    if b.depth_max_m - b.depth_min_m < 30:
        return f"{b.depth_m:.0f} m"
    return f"{b.depth_min_m:.0f}–{b.depth_max_m:.0f} m"


def span_attenuation(rows: Iterable[ResultRow], setup: Setup) -> dict[int, AttenuationResult]:
    """λ_att per wavelength over a span of frames: stacks per setting and depth band, pairs, combination."""
    return span_attenuation_by_band(rows, setup).overall


#: The station: frames within this many metres of the deepest frame of a dive.
STATION_SPAN_M = 50.0


@dataclass(frozen=True)
class Span:
    """A part of a dive: frames between two depths and two times (each bound optional).

    `select` fills a missing lower depth with the station's: the deepest
    frame's depth minus `STATION_SPAN_M`.
    """

    depth_min_m: float | None = None
    depth_max_m: float | None = None
    t_from: float | None = None
    t_to: float | None = None

    def select(self, rows: Sequence[Mapping[str, Any]]) -> tuple[list[Mapping[str, Any]], dict[str, Any]]:
        """The rows (``depth_m``, ``captured_unix_s``) inside the span, and the span as applied."""
        depths = [r["depth_m"] for r in rows if r["depth_m"] is not None]
        lo = self.depth_min_m
        if lo is None and depths:
            lo = max(depths) - STATION_SPAN_M
        hi = self.depth_max_m
        sel = [
            r
            for r in rows
            if (lo is None or (r["depth_m"] is not None and r["depth_m"] >= lo))
            and (hi is None or (r["depth_m"] is not None and r["depth_m"] <= hi))
            and (self.t_from is None or r["captured_unix_s"] >= self.t_from)
            and (self.t_to is None or r["captured_unix_s"] <= self.t_to)
        ]
        info = {
            "depth_min_m": lo,
            "depth_max_m": hi,
            "t_from": self.t_from,
            "t_to": self.t_to,
            "n_frames": len(sel),
        }
        return sel, info


def attenuation_over_span(
    rows: Sequence[Mapping[str, Any]], setup: Setup, span: Span | None = None
) -> tuple[dict[str, Any], SpanAttenuation]:
    """λ_att per wavelength over a span of a run's results (default: the station), and the span applied.

    ``rows`` are `storage.queries.result_rows` dicts. The API's λ_att
    table, ``camcal report`` and ``camcal fit --dive`` all take their span here.
    """
    sel, info = (span or Span()).select(rows)
    gr = geometry_and_ratios(setup)
    if gr is not None and sel:
        near, far = gr[0].near_camera, gr[0].far_camera
        present = sorted({r["module"] for r in sel})
        if near not in present or far not in present:  # the modules hang apart: a depth range can cut one
            info["note"] = (
                f"the span holds frames of {', '.join(present)} only: λ_att needs both {near} and {far} "
                f"({gr[0].baseline_m:.0f} m apart along the cable): widen it"
            )
    return info, span_attenuation_by_band([result_row(r) for r in sel], setup)


def table_rows(table: SpanAttenuation) -> dict[str, Any]:
    """The λ_att table of a span as the API, the report and the export give it: a row per
    wavelength (its pairs with their depths) and, when the span crosses depths, a table per band."""
    return {
        "rows": [attenuation_dict(table.overall[wl], table.pair_depth_m(wl)) for wl in sorted(table.overall)],
        "bands": [
            {
                "depth_min_m": b.depth_min_m,
                "depth_max_m": b.depth_max_m,
                "depth_m": b.depth_m,
                "n_frames": b.n_frames,
                "rows": [
                    attenuation_dict(b.results[wl], [b.depth_m] * len(b.results[wl].pairs))
                    for wl in sorted(b.results)
                ],
            }
            for b in table.bands
        ]
        if len(table.bands) > 1
        else [],
    }


def _stack(values: list[tuple[float, float]]) -> tuple[float, float, int]:
    v = np.array([x for x, _ in values])
    e = np.array([x for _, x in values])
    n = len(v)
    propagated = float(np.sqrt(np.sum(e**2)) / n)
    scatter = float(v.std(ddof=1) / math.sqrt(n)) if n >= 3 else 0.0
    return float(v.mean()), max(scatter, propagated), n


def attenuation_dict(res: AttenuationResult, pair_depth_m: Sequence[float | None] = ()) -> dict[str, Any]:
    """A row of the λ_att table; ``pair_depth_m``: the LEM depth of each pair (`SpanAttenuation`)."""
    depths = list(pair_depth_m) + [None] * (len(res.pairs) - len(pair_depth_m))
    return {
        "wavelength_nm": res.wavelength_nm,
        "lambda_att_m": res.lambda_att_m,
        "stat_err_m": res.stat_err_m,
        "sys_err_m": res.sys_err_m,
        "total_err_m": res.total_err_m,
        "n_pairs": res.n_pairs,
        "chi2_ndof": res.chi2_ndof,
        "emission_ratio": res.emission_ratio.value,
        "emission_ratio_err": res.emission_ratio.err,
        "note": res.note,
        "pairs": [
            {
                "exposure_s": p.exposure_s,
                "gain_db": p.gain_db,
                "i_near_gray": p.i_near_gray,
                "i_near_err_gray": p.i_near_err_gray,
                "i_far_gray": p.i_far_gray,
                "i_far_err_gray": p.i_far_err_gray,
                "n_near": p.n_near,
                "n_far": p.n_far,
                "lambda_att_m": p.lambda_att_m,
                "stat_err_m": p.stat_err_m,
                "depth_m": depth,
            }
            for p, depth in zip(res.pairs, depths, strict=True)
        ],
    }
