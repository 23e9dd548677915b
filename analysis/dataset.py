"""From analysed frames to λ_att: grouping repeats, stacking, pairing, combining.

Pure logic on results already in memory; reading files is the caller's job.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from analysis.attenuation import (
    AttenuationResult,
    EmissionRatio,
    Geometry,
    PairResult,
    combine_pairs,
    pair_result,
)
from analysis.frame import FrameAnalysis
from analysis.linearity import LinearityResult, gain_factor, linearity_fit
from analysis.profile import DEFAULT_CENTER_PIXELS
from analysis.stack import StackResult, stack_frames


@dataclass(frozen=True, order=True)
class Setting:
    """One camera setting: wavelength, exposure and gain."""

    wavelength_nm: int
    exposure_s: float
    gain_db: float


@dataclass(frozen=True)
class FrameRecord:
    """An analysed frame with the camera and setting it was taken with."""

    camera: str
    setting: Setting
    analysis: FrameAnalysis


@dataclass(frozen=True)
class LinearityCheck:
    """Linearity of one camera at one wavelength.

    ``exposure`` is gray against exposure at the gain with the most distinct
    exposures; ``gain`` is gray against the linear gain factor at the exposure
    with the most distinct gains. Either is None when the data do not allow it.
    """

    camera: str
    wavelength_nm: int
    fixed_gain_db: float | None
    exposure: LinearityResult | None
    fixed_exposure_s: float | None
    gain: LinearityResult | None


@dataclass(frozen=True)
class SetResult:
    """Everything measured on a set of frames."""

    stacks: dict[tuple[str, Setting], StackResult] = field(repr=False)
    pairs: dict[int, tuple[PairResult, ...]]
    attenuation: dict[int, AttenuationResult]
    linearity: tuple[LinearityCheck, ...]
    skipped: dict[int, str]


def stack_by_setting(
    records: Sequence[FrameRecord], center_pixels: int = DEFAULT_CENTER_PIXELS
) -> dict[tuple[str, Setting], StackResult]:
    """Stack the accepted repeats of each (camera, setting)."""
    groups: dict[tuple[str, Setting], list[FrameAnalysis]] = defaultdict(list)
    for rec in records:
        if rec.analysis.ok:
            groups[(rec.camera, rec.setting)].append(rec.analysis)
    return {key: stack_frames(items, center_pixels) for key, items in sorted(groups.items())}


def analyze_records(
    records: Sequence[FrameRecord],
    geometry: Geometry,
    emission_ratios: Mapping[int, EmissionRatio],
    linear_range_gray: tuple[float, float] = (5.0, 240.0),
    center_pixels: int = DEFAULT_CENTER_PIXELS,
) -> SetResult:
    """Stack repeats, pair near and far stacks at equal settings, combine per wavelength.

    A wavelength without an emission ratio, or without any setting where
    both cameras have accepted frames, is listed in ``skipped`` with why.
    """
    stacks = stack_by_setting(records, center_pixels)
    by_wavelength: dict[int, list[PairResult]] = defaultdict(list)
    wavelengths = sorted({rec.setting.wavelength_nm for rec in records})
    skipped: dict[int, str] = {}
    for (camera, setting), near in stacks.items():
        if camera != geometry.near_camera:
            continue
        far = stacks.get((geometry.far_camera, setting))
        ratio = emission_ratios.get(setting.wavelength_nm)
        if far is None or ratio is None:
            continue
        by_wavelength[setting.wavelength_nm].append(
            pair_result(
                setting.wavelength_nm,
                setting.exposure_s,
                setting.gain_db,
                (near.i_center_gray, near.i_center_err_gray, near.n_frames),
                (far.i_center_gray, far.i_center_err_gray, far.n_frames),
                geometry,
                ratio,
            )
        )
    attenuation: dict[int, AttenuationResult] = {}
    for wl in wavelengths:
        if wl not in emission_ratios:
            skipped[wl] = f"no emission ratio I0'/I0 for {wl} nm in setup.json or options"
            continue
        pairs = by_wavelength.get(wl, [])
        usable = [p for p in pairs if np.isfinite(p.log_ratio)]
        if not usable:
            skipped[wl] = (
                f"no setting at {wl} nm with accepted frames from both cameras "
                f"{geometry.near_camera} and {geometry.far_camera}"
            )
            continue
        attenuation[wl] = combine_pairs(usable, geometry, emission_ratios[wl])
    pairs_out = {wl: tuple(p) for wl, p in sorted(by_wavelength.items())}
    return SetResult(
        stacks=stacks,
        pairs=pairs_out,
        attenuation=attenuation,
        linearity=tuple(linearity_checks(records, linear_range_gray)),
        skipped=skipped,
    )


def linearity_checks(
    records: Sequence[FrameRecord], linear_range_gray: tuple[float, float] = (5.0, 240.0)
) -> list[LinearityCheck]:
    """Gray of the LEM centre against exposure and against gain, per camera and wavelength.

    Uses the raw centre gray of every frame where the LEM was found, the
    saturated ones included: they show where the response leaves the line.
    """
    means: dict[tuple[str, int], dict[tuple[float, float], list[float]]] = defaultdict(
        lambda: defaultdict(list)
    )
    for rec in records:
        g = rec.analysis.center_gray
        if g is None or not np.isfinite(g):
            continue
        s = rec.setting
        means[(rec.camera, s.wavelength_nm)][(s.exposure_s, s.gain_db)].append(g)
    checks = []
    for (camera, wl), settings in sorted(means.items()):
        points = {k: float(np.mean(v)) for k, v in settings.items()}
        exp_fit, fixed_gain = _best_sweep(points, vary=0, linear_range_gray=linear_range_gray)
        gain_fit, fixed_exp = _best_sweep(points, vary=1, linear_range_gray=linear_range_gray)
        if exp_fit or gain_fit:
            checks.append(LinearityCheck(camera, wl, fixed_gain, exp_fit, fixed_exp, gain_fit))
    return checks


def _best_sweep(
    points: dict[tuple[float, float], float], vary: int, linear_range_gray: tuple[float, float]
) -> tuple[LinearityResult | None, float | None]:
    """Fit the sweep (over exposure if ``vary == 0``, gain if 1) with most usable points."""
    fixed_index = 1 - vary
    sweeps: dict[float, list[tuple[float, float]]] = defaultdict(list)
    for key, gray in points.items():
        sweeps[key[fixed_index]].append((key[vary], gray))
    lo, hi = linear_range_gray

    def usable(item: tuple[float, list[tuple[float, float]]]) -> int:
        return sum(1 for _, g in item[1] if lo <= g <= hi)

    for fixed, pts in sorted(sweeps.items(), key=usable, reverse=True):
        if usable((fixed, pts)) < 3:
            break
        xs = [p[0] for p in pts]
        if vary == 1:
            xs = [float(gain_factor(x)) for x in xs]
        try:
            return linearity_fit(xs, [p[1] for p in pts], linear_range_gray), fixed
        except ValueError:
            continue
    return None, None
