"""I0'/I0 from the two hemispheres, temperature runs and the temperature effect."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from analysis.calibration import HemisphereValue, emission_ratios, group_temperatures


def test_group_temperatures_splits_runs_by_gaps() -> None:
    assert group_temperatures([2.1, 18.9, 1.8, 19.3, 2.4], tolerance_c=2.0) == [0, 1, 0, 1, 0]
    assert group_temperatures([5.0, 6.5, 8.0], tolerance_c=2.0) == [0, 0, 0]  # a slow drift is one run
    with pytest.raises(ValueError, match="tolerance_c must be > 0"):
        group_temperatures([1.0], tolerance_c=0)


def _frames(
    ratio_at: dict[float, float], n: int = 4, err: float = 2.0, seed: int = 0
) -> list[HemisphereValue]:
    """Near and far frames per run: near ~1000 gray/s, far = ratio x near, with noise."""
    rng = np.random.default_rng(seed)
    out = []
    for t, ratio in ratio_at.items():
        for side, level in (("near", 1000.0), ("far", 1000.0 * ratio)):
            for _ in range(n):
                reading = t + rng.normal(0, 0.3)
                out.append(HemisphereValue(460, side, reading, level + rng.normal(0, err), err))
    return out


def test_ratio_at_the_deep_sea_temperature_from_two_runs() -> None:
    # The ratio rises 0.04 %/°C from 1.27 at 2 °C.
    true = {2.1: 1.27 * (1 + 4e-4 * 0.1), 18.9: 1.27 * (1 + 4e-4 * 16.9)}
    r = emission_ratios(_frames(true), temperature_c=2.0)[460]
    assert len(r.runs) == 2
    assert abs(r.ratio - 1.27) < 3 * r.ratio_err
    assert r.ratio_per_c is not None and r.ratio_per_c_err is not None
    assert abs(r.ratio_per_c - 1.27 * 4e-4) < 3 * r.ratio_per_c_err
    e = r.temperature_effect
    assert e is not None
    assert abs(e.ratio_change - (true[18.9] / true[2.1] - 1)) < 3 * e.ratio_change_err
    assert_allclose([e.cold_c, e.warm_c], [2.1, 18.9], atol=0.5)


def test_one_run_without_temperature_gives_its_ratio() -> None:
    values = [HemisphereValue(405, "near", None, 100.0, 0.5), HemisphereValue(405, "far", None, 104.0, 0.5)]
    r = emission_ratios(values)[405]
    assert r.temperature_c is None and r.temperature_effect is None
    assert_allclose(r.ratio, 1.04)
    assert_allclose(r.ratio_err, 1.04 * np.hypot(0.5 / 104, 0.5 / 100))


def test_a_run_missing_a_hemisphere_is_named() -> None:
    values = [
        v for v in _frames({2.0: 1.2, 19.0: 1.21}) if not (v.hemisphere == "far" and v.temperature_c > 10)
    ]
    with pytest.raises(
        ValueError, match=r"460 nm: no usable frame of the far hemisphere in the run near 1[89]\.[0-9] °C"
    ):
        emission_ratios(values)


def test_frames_with_and_without_temperature_are_not_mixed() -> None:
    values = _frames({2.0: 1.2}) + [HemisphereValue(460, s, None, 1000.0, 1.0) for s in ("near", "far")]
    with pytest.raises(ValueError, match="with and without temperature_c"):
        emission_ratios(values)


def test_hemisphere_must_be_near_or_far() -> None:
    with pytest.raises(ValueError, match="hemisphere must be 'near' or 'far'"):
        HemisphereValue(460, "left", None, 1.0, 0.1)
