"""Emission ratio I0'/I0 of the LEM and its temperature dependence.

The LEM emits unevenly: the hemisphere toward the far camera (I0') is
brighter than the one toward the near camera (I0). In the lab, a camera
photographs each hemisphere in turn at the same distance and setting; the
ratio of the background-subtracted centre grays is I0'/I0. Repeating this
in a cold room (~2 °C, the deep sea) and at room temperature (~19 °C) shows
whether the ratio moves with temperature (the paper: by < 1 %).
"""

from __future__ import annotations

import itertools
import math
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from analysis.calibration.fit import Combined, combine_repeats, fit_line

HEMISPHERES = ("near", "far")


@dataclass(frozen=True)
class HemisphereValue:
    """One frame's centre intensity of one LEM hemisphere.

    ``value`` is I_center normalised to the setting (gray per second at
    0 dB), so frames taken at different settings can be compared; ``err``
    its one-sigma error. ``temperature_c`` is None when not recorded.
    """

    wavelength_nm: int
    hemisphere: str
    temperature_c: float | None
    value: float
    err: float

    def __post_init__(self) -> None:
        if self.hemisphere not in HEMISPHERES:
            raise ValueError(f"hemisphere must be 'near' or 'far', got {self.hemisphere!r}")


def group_temperatures(temperatures_c: Sequence[float], tolerance_c: float = 2.0) -> list[int]:
    """Group temperature readings into runs: sorted readings closer than ``tolerance_c`` share a group.

    A cold-room run logs 2.1 ± 0.5 °C and a warm one 18.9 ± 0.5 °C; the
    frames of one run carry slightly different readings, so exact equality
    would split a run. Returns one group index per reading (0 = coldest).
    """
    if tolerance_c <= 0:
        raise ValueError(f"tolerance_c must be > 0, got {tolerance_c}")
    t = np.asarray(temperatures_c, dtype=np.float64)
    if t.size == 0:
        return []
    order = np.argsort(t, kind="stable")
    labels = np.zeros(t.size, dtype=int)
    group = 0
    for prev, cur in itertools.pairwise(order):
        if t[cur] - t[prev] > tolerance_c:
            group += 1
        labels[cur] = group
    return labels.tolist()


@dataclass(frozen=True)
class RatioAtTemperature:
    """I0'/I0 of one wavelength from the frames of one temperature run."""

    wavelength_nm: int
    temperature_c: float | None
    temperature_spread_c: float | None
    near: Combined
    far: Combined
    ratio: float
    ratio_err: float


@dataclass(frozen=True)
class TemperatureEffect:
    """How I0'/I0 (and the LEM's brightness) changed from the coldest to the warmest run.

    ``ratio_change`` is ``R(warm) / R(cold) - 1``; ``brightness_change`` the
    same for the near hemisphere's intensity (the LED output and camera
    response together, which cancel in the ratio).
    """

    cold_c: float
    warm_c: float
    ratio_change: float
    ratio_change_err: float
    brightness_change: float
    brightness_change_err: float

    @property
    def ratio_change_per_c(self) -> float:
        return self.ratio_change / (self.warm_c - self.cold_c)


#: Where the ratio is needed: the deep sea at the T-REX site is ~1.5-2 °C.
DEEP_SEA_TEMPERATURE_C = 2.0


@dataclass(frozen=True)
class EmissionRatioResult:
    """I0'/I0 of one wavelength: per temperature run, at the temperature of use, and its temperature effect.

    ``ratio`` (with ``ratio_err``) is the ratio at ``temperature_c``: the
    runs' ratios fitted by a straight line in temperature and read off there
    (with one run, that run's ratio). It is the value for setup.json when
    ``temperature_c`` is the temperature the LEM will shine at.
    ``ratio_per_c`` is the line's slope (None with fewer than two runs);
    ``temperature_effect`` the change from the coldest run to the warmest.
    """

    wavelength_nm: int
    runs: tuple[RatioAtTemperature, ...]
    temperature_c: float | None
    ratio: float
    ratio_err: float
    ratio_per_c: float | None
    ratio_per_c_err: float | None
    temperature_effect: TemperatureEffect | None


def _ratio(far: Combined, near: Combined) -> tuple[float, float]:
    r = far.mean / near.mean
    return r, abs(r) * math.hypot(far.err / far.mean, near.err / near.mean)


def emission_ratios(
    values: Sequence[HemisphereValue],
    temperature_tolerance_c: float = 2.0,
    temperature_c: float = DEEP_SEA_TEMPERATURE_C,
) -> dict[int, EmissionRatioResult]:
    """I0'/I0 per wavelength from frames of both hemispheres.

    1. readings are grouped into temperature runs (`group_temperatures`);
       frames without a temperature form one run of their own;
    2. per wavelength and run, the repeats of each hemisphere are combined
       (`combine_repeats`) and the ratio far / near is taken, errors in quadrature;
    3. the runs of a wavelength are fitted by a line in temperature, read
       off at ``temperature_c`` (the ratio depends on temperature, so an
       average of cold and warm runs would suit neither), and the coldest
       and warmest runs give the temperature effect.

    Raises `ValueError` naming the wavelength when a run lacks one
    hemisphere (a ratio needs both sides under the same conditions), or
    when frames with and without a temperature would have to be combined.
    """
    if not values:
        raise ValueError("values is empty: no usable frame of either hemisphere")
    with_t = [v for v in values if v.temperature_c is not None]
    labels = group_temperatures([v.temperature_c for v in with_t], temperature_tolerance_c)  # type: ignore[misc]
    run_of: dict[int, int] = {id(v): lab for v, lab in zip(with_t, labels, strict=True)}
    groups: dict[tuple[int, int], dict[str, list[HemisphereValue]]] = defaultdict(lambda: defaultdict(list))
    for v in values:
        groups[(v.wavelength_nm, run_of.get(id(v), -1))][v.hemisphere].append(v)

    runs: dict[int, list[RatioAtTemperature]] = defaultdict(list)
    for (wl, run), sides in sorted(groups.items()):
        missing = [h for h in HEMISPHERES if not sides.get(h)]
        if missing:
            where = "frames without temperature" if run < 0 else f"the run near {_mean_t(sides):.1f} °C"
            raise ValueError(f"{wl} nm: no usable frame of the {missing[0]} hemisphere in {where}")
        near = combine_repeats([v.value for v in sides["near"]], [v.err for v in sides["near"]])
        far = combine_repeats([v.value for v in sides["far"]], [v.err for v in sides["far"]])
        ratio, err = _ratio(far, near)
        temps = [v.temperature_c for h in HEMISPHERES for v in sides[h] if v.temperature_c is not None]
        t_mean = float(np.mean(temps)) if temps else None
        t_spread = float(np.std(temps)) if temps else None
        runs[wl].append(RatioAtTemperature(wl, t_mean, t_spread, near, far, ratio, err))

    out: dict[int, EmissionRatioResult] = {}
    for wl, items in sorted(runs.items()):
        pairs = sorted(
            ((r.temperature_c, r) for r in items if r.temperature_c is not None), key=lambda p: p[0]
        )
        temps_c, known = [t for t, _ in pairs], [r for _, r in pairs]
        if len(items) > 1 and len(known) < len(items):
            raise ValueError(f"{wl} nm: frames with and without temperature_c cannot be combined")
        if len(known) >= 2:
            line = fit_line(temps_c, [r.ratio for r in known], [r.ratio_err for r in known])
            value, err = float(line.predict(temperature_c)), float(line.predict_err(temperature_c))
            at: float | None = temperature_c
            slope, slope_err = line.slope, line.slope_err
            cold, warm = known[0], known[-1]
            rc, rc_err = _ratio(
                Combined(warm.ratio, warm.ratio_err, 1, 0.0), Combined(cold.ratio, cold.ratio_err, 1, 0.0)
            )
            bc, bc_err = _ratio(warm.near, cold.near)
            effect = TemperatureEffect(
                cold_c=temps_c[0],
                warm_c=temps_c[-1],
                ratio_change=rc - 1.0,
                ratio_change_err=rc_err,
                brightness_change=bc - 1.0,
                brightness_change_err=bc_err,
            )
        else:
            only = items[0]
            value, err, slope, slope_err, effect = only.ratio, only.ratio_err, None, None, None
            at = only.temperature_c
        out[wl] = EmissionRatioResult(wl, tuple(items), at, value, err, slope, slope_err, effect)
    return out


def _mean_t(sides: dict[str, list[HemisphereValue]]) -> float:
    temps = [v.temperature_c for vs in sides.values() for v in vs if v.temperature_c is not None]
    return float(np.mean(temps)) if temps else float("nan")
