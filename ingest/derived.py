"""Results derived from many frames: linearity per module, the dive phase, predictions of settings
(λ_att over a span: `ingest.spans`).

Used by the live ingest, by re-analyses and by the API, so that all three
compute these the same way.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from analysis import EmissionRatio, Geometry, linearity_fit
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


def result_row(r: Mapping[str, Any]) -> ResultRow:
    """A `ResultRow` from a `storage.queries.result_rows` dict."""
    return ResultRow(*(r[k] for k in ResultRow.__dataclass_fields__))


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
