"""Results derived from many frames: linearity per module, λ_att over a span, re-analysis.

Used by the live ingest, by re-analyses and by the API, so that all three
compute these the same way.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from analysis import AttenuationResult, EmissionRatio, Geometry, combine_pairs, linearity_fit, pair_result
from analysis.linearity import gain_factor
from camcal.core.frameset import Setup


@dataclass(frozen=True)
class ResultRow:
    """The fields of a stored frame result the derived quantities need."""

    module: str
    wavelength_nm: int
    exposure_s: float
    gain_db: float
    captured_unix_s: float
    depth_m: float | None
    status: str
    center_gray: float | None
    i_center_gray: float | None
    i_center_err_gray: float | None


def geometry_and_ratios(setup: Setup) -> tuple[Geometry, dict[int, EmissionRatio]] | None:
    """Near and far camera (by distance) and the emission ratios of a setup."""
    cams = sorted(setup.cameras.items(), key=lambda kv: kv[1].distance_m)
    if len(cams) < 2:
        return None
    (near, dn), (far, df) = cams[0], cams[-1]
    geometry = Geometry(near, far, dn.distance_m, dn.distance_err_m, df.distance_m, df.distance_err_m)
    return geometry, {wl: EmissionRatio(r.value, r.err) for wl, r in setup.emission_ratio.items()}


def linearity_rows(
    points: Mapping[tuple[float, float], float], linear_range: tuple[float, float]
) -> list[dict[str, Any]]:
    """Linearity fits of one module and wavelength from mean centre gray per (exposure, gain).

    Against exposure at the gain with the most in-range points, and against
    the linear gain factor at the exposure with the most; each needs >= 3
    in-range points.
    """
    lo, hi = linear_range
    out = []
    for sweep, vary in (("exposure", 0), ("gain", 1)):
        groups: dict[float, list[tuple[float, float]]] = defaultdict(list)
        for key, gray in points.items():
            groups[key[1 - vary]].append((key[vary], gray))
        best = None
        for fixed, pts in groups.items():
            n_in = sum(1 for _, g in pts if lo <= g <= hi)
            if n_in >= 3 and (best is None or n_in > best[0]):
                best = (n_in, fixed, pts)
        if best is None:
            continue
        _, fixed, pts = best
        xs = [p[0] if vary == 0 else float(gain_factor(p[0])) for p in pts]
        try:
            fit = linearity_fit(xs, [p[1] for p in pts], (lo, hi))
        except ValueError:
            continue
        out.append(
            {
                "sweep": sweep,
                "fixed_value": fixed,
                "slope": fit.slope,
                "slope_err": fit.slope_err if math.isfinite(fit.slope_err) else None,
                "intercept_gray": fit.intercept_gray,
                "r2": fit.r2,
                "n_used": fit.n_used,
                "linear_max_gray": fit.linear_max_gray,
                "knee_x": fit.knee_x,
                "points": {"x": list(fit.x), "gray": list(fit.gray), "used": list(fit.used)},
            }
        )
    return out


def mean_gray_by_setting(
    rows: Iterable[ResultRow],
) -> dict[tuple[str, int], dict[tuple[float, float], float]]:
    acc: dict[tuple[str, int], dict[tuple[float, float], list[float]]] = defaultdict(
        lambda: defaultdict(list)
    )
    for r in rows:
        if r.center_gray is not None:
            acc[(r.module, r.wavelength_nm)][(r.exposure_s, r.gain_db)].append(r.center_gray)
    return {k: {s: float(np.mean(v)) for s, v in d.items()} for k, d in acc.items()}


def span_attenuation(rows: Iterable[ResultRow], setup: Setup) -> dict[int, AttenuationResult]:
    """λ_att per wavelength over a span of frames: stacks per setting, pairs, combination."""
    gr = geometry_and_ratios(setup)
    if gr is None:
        return {}
    geometry, ratios = gr
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
        pairs[wl].append(pair_result(wl, exp, gain, _stack(near), _stack(far), geometry, ratios[wl]))
    out = {}
    for wl, plist in pairs.items():
        usable = [p for p in plist if math.isfinite(p.log_ratio) and p.log_ratio_err > 0]
        if usable:
            out[wl] = combine_pairs(usable, geometry, ratios[wl])
    return out


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


def result_row(r: Mapping[str, Any]) -> ResultRow:
    """A `ResultRow` from a `storage.queries.result_rows` dict."""
    return ResultRow(*(r[k] for k in ResultRow.__dataclass_fields__))


def attenuation_over_span(
    rows: Sequence[Mapping[str, Any]], setup: Setup, span: Span | None = None
) -> tuple[dict[str, Any], dict[int, AttenuationResult]]:
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
    return info, span_attenuation([result_row(r) for r in sel], setup)


def _stack(values: list[tuple[float, float]]) -> tuple[float, float, int]:
    v = np.array([x for x, _ in values])
    e = np.array([x for _, x in values])
    n = len(v)
    propagated = float(np.sqrt(np.sum(e**2)) / n)
    scatter = float(v.std(ddof=1) / math.sqrt(n)) if n >= 3 else 0.0
    return float(v.mean()), max(scatter, propagated), n


def attenuation_dict(res: AttenuationResult) -> dict[str, Any]:
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
            }
            for p in res.pairs
        ],
    }


#: A stop within this of the station depth (planned, or the deepest so far) is the station.
STATION_TOLERANCE_M = 50.0


def dive_phase(
    t_unix_s: list[float] | np.ndarray,
    depth_m: list[float] | np.ndarray,
    max_depth_m: float | None = None,
    station_depth_m: float | None = None,
) -> str:
    """The dive phase from a module's recent depth: deck, descent, stop, station or ascent.

    The rate of depth change over the last ~30 s tells moving from stopped.
    A stop near the planned ``station_depth_m`` is the station, any other a
    (test) stop. Without a plan, a stop near the deepest depth seen so far
    (``max_depth_m``, else the deepest of the samples given) is taken for
    the station: on the way down a test stop shows as the station until the
    module goes deeper, which only the plan avoids.
    """
    t = np.asarray(t_unix_s, dtype=np.float64)
    d = np.asarray(depth_m, dtype=np.float64)
    if t.size == 0:
        return "unknown"
    depth = float(d[-1])
    if depth < 5.0:
        return "deck"
    recent = t >= t[-1] - 30.0
    rate = 0.0
    if recent.sum() >= 3 and t[recent][-1] > t[recent][0]:
        rate = float(np.polyfit(t[recent] - t[recent][0], d[recent], 1)[0])
    if rate > 0.2:
        return "descent"
    if rate < -0.2:
        return "ascent"
    if station_depth_m is not None:
        return "station" if abs(depth - station_depth_m) <= STATION_TOLERANCE_M else "stop"
    deepest = max(float(d.max()), max_depth_m or 0.0)
    return "station" if depth >= deepest - STATION_TOLERANCE_M else "stop"


#: The dark level a setting's prediction assumes for a module none of whose frames measured it [gray].
DEFAULT_BACKGROUND_GRAY = 2.5


def predict_settings(
    rows: Iterable[ResultRow],
    settings: Iterable[tuple[int, float, float]],
    linear_range: tuple[float, float],
    background_gray: float | None = None,
) -> dict[str, list[dict[str, Any]]]:
    """What each setting of a schedule will look like, judged from the frames seen so far.

    Per module and wavelength, the LEM's brightness per unit of exposure and
    linear gain is the median of ``(centre gray - background) / (exposure *
    10^(gain/20))`` over frames in the linear range; a setting then predicts
    ``background + brightness * exposure * gain factor``: ``too_dark``,
    ``ok`` or ``saturated`` against the linear range (``unknown`` without
    usable frames at that wavelength). The background is each module's own,
    the median of what its frames measured (centre gray - I_center: a camera
    whose dark level sits at 0 and one at 10 gray judge their faint settings
    alike), else ``background_gray``, else `DEFAULT_BACKGROUND_GRAY`.
    """
    lo, hi = linear_range
    rows = list(rows)
    fallback = DEFAULT_BACKGROUND_GRAY if background_gray is None else background_gray
    measured: dict[str, list[float]] = defaultdict(list)
    if background_gray is None:
        for r in rows:
            if r.status == "ok" and r.center_gray is not None and r.i_center_gray is not None:
                measured[r.module].append(r.center_gray - r.i_center_gray)
    backgrounds = {m: float(np.median(v)) for m, v in measured.items()}
    rates: dict[tuple[str, int], list[float]] = defaultdict(list)
    for r in rows:
        if r.center_gray is not None and lo <= r.center_gray <= hi:
            g = float(gain_factor(r.gain_db))
            bg = backgrounds.get(r.module, fallback)
            rates[(r.module, r.wavelength_nm)].append((r.center_gray - bg) / (r.exposure_s * g))
    # One median per module and wavelength, not per setting: a schedule of 20,000 settings costs
    # 20,000 multiplications, not 20,000 medians (the preview is open to every browser on the ship).
    rate = {k: float(np.median(v)) for k, v in rates.items()}
    factors: dict[float, float] = {}
    modules = sorted({m for m, _ in rates})
    out: dict[str, list[dict[str, Any]]] = {}
    for m in modules:
        preds = []
        for wl, exp, gain in settings:
            brightness = rate.get((m, wl))
            if brightness is None:
                preds.append(
                    {
                        "wavelength_nm": wl,
                        "exposure_s": exp,
                        "gain_db": gain,
                        "center_gray": None,
                        "verdict": "unknown",
                    }
                )
                continue
            if gain not in factors:
                factors[gain] = float(gain_factor(gain))
            gray = backgrounds.get(m, fallback) + brightness * exp * factors[gain]
            verdict = "saturated" if gray > hi else ("too_dark" if gray < lo else "ok")
            preds.append(
                {
                    "wavelength_nm": wl,
                    "exposure_s": exp,
                    "gain_db": gain,
                    "center_gray": round(min(gray, 999.0), 1),
                    "verdict": verdict,
                }
            )
        out[m] = preds
    return out
