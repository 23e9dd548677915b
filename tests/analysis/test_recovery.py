"""The science: λ_att of simulated 5 MP frames against the simulator's truth.

Three waters (clear ~55 m, T-REX-like ~20-28 m, turbid ~12 m) and two
geometries (T-REX, and a nearer pair whose LEM needs a larger crop).
"""

from __future__ import annotations

import zlib

import pytest

from analysis import EmissionRatio, Geometry, analyze_records
from tests.utils.sim import FULL_CAMERA, in_range_settings, records_for, renderer

GEOMETRIES = {"trex": (21.56, 41.62), "near": (8.0, 20.0)}
RATIOS = {405: 1.04, 460: 1.27, 525: 1.23}


@pytest.mark.slow
@pytest.mark.parametrize("geometry", sorted(GEOMETRIES))
@pytest.mark.parametrize("water", ["clear", "trex", "turbid"])
def test_lambda_att_recovered_within_3_percent_and_errors_cover_truth(water: str, geometry: str) -> None:
    d_near, d_far = GEOMETRIES[geometry]
    near = renderer(water, d_near, camera=FULL_CAMERA, camera_id="A")
    far = renderer(water, d_far, far_side=True, camera=FULL_CAMERA, camera_id="B")
    settings = []
    for wl in (405, 460, 525):
        candidates = in_range_settings(near, far, wl)
        assert candidates, f"no usable setting at {wl} nm"
        # two settings from the middle of the usable list
        mid = len(candidates) // 2
        settings += [(wl, e, g) for e, g in candidates[max(mid - 1, 0) : mid + 1]]
    # A seed of its own per case, the same in every run (hash() of a str changes from one
    # interpreter to the next: the frames were other ones each run, and now and then one drew a
    # 3-sigma deviation of the short baseline's clear water: 3.1 % for ~1 % of stat. error).
    seed = zlib.crc32(f"{water}/{geometry}".encode()) % 1000
    records = records_for(near, far, settings, repeats=3, seed=seed)
    assert all(r.analysis.ok for r in records), [r.analysis.detail for r in records if not r.analysis.ok]
    geo = Geometry("A", "B", d_near, 0.02, d_far, 0.04)
    ratios = {wl: EmissionRatio(v, 0.03) for wl, v in RATIOS.items()}
    result = analyze_records(records, geo, ratios)
    for wl in (405, 460, 525):
        truth = near.water.at(wl).lambda_att_m
        res = result.attenuation[wl]
        assert res.lambda_att_m == pytest.approx(truth, rel=0.03), (wl, res.lambda_att_m, truth)
        pull = (res.lambda_att_m - truth) / res.total_err_m
        assert abs(pull) < 3, (wl, pull)
        assert res.stat_err_m > 0 and res.sys_err_m > 0
