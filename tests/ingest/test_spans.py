"""λ_att over a span that crosses depths: stacked and paired per depth band, and said so.

Seen on deck: the whole-dive λ_att pooled the frames of 1200, 2021 and 3420 m into one stack per
setting (460 nm: 28.00 ± 0.32, χ²/ndof 1.73, against 28.26 ± 0.09 on station), and the pairs table
did not show the depths. Now each depth band has its own value, the span's own value stands only
where the bands agree, and each pair carries its depth.
"""

from __future__ import annotations

import math

import pytest

from camcal.core.frameset import Setup
from ingest.derived import ResultRow
from ingest.spans import Span, attenuation_over_span, depth_bands, table_rows

SETUP = Setup()
LAMBDA_AT = {1200.0: 20.0, 3420.0: 30.0}  # m of λ_att at the LEM's depth: other water at each


def rows_at(lem_depth_m: float, lambda_att_m: float, n: int = 6) -> list[dict[str, object]]:
    """Result rows of both cameras at one LEM depth, whose intensities give ``lambda_att_m``."""
    near, far = SETUP.cameras["A"].distance_m, SETUP.cameras["B"].distance_m
    ratio = SETUP.emission_ratio[460].value
    out = []
    for k, (exp, gain) in enumerate(((0.05, 6.0), (0.07, 6.0), (0.11, 6.0)) * (n // 3)):
        i_near = 120.0 * exp / 0.05
        i_far = i_near * ratio * math.exp(-(far - near) / lambda_att_m)
        for cam, dist, gray in (("A", near, i_near), ("B", far, i_far)):
            row = ResultRow(cam, 460, exp, gain, 1e9 + k, lem_depth_m - dist, "ok", gray, gray, 0.3)
            out.append({**row.__dict__, "captured_unix_s": 1e9 + k})
    return out


def test_the_depth_bands_of_stops_and_of_a_profile() -> None:
    assert depth_bands([3420, 1200, 1203, 2021, 3418]) == [(1200, 1203), (2021, 2021), (3418, 3420)]
    profile = depth_bands([float(d) for d in range(1000, 1251)])  # frames all the way down
    assert len(profile) == 3 and profile[0][0] == 1000 and profile[-1][1] == 1250
    assert all(b - a <= 100 for a, b in profile)


def test_a_span_across_other_water_has_a_value_per_depth_and_none_of_its_own() -> None:
    rows = rows_at(1200.0, LAMBDA_AT[1200.0]) + rows_at(3420.0, LAMBDA_AT[3420.0])
    _, table = attenuation_over_span(rows, SETUP, None)  # the station only, by default...
    assert [b.depth_m for b in table.bands] == [pytest.approx(3420.0)]
    _, table = attenuation_over_span(rows, SETUP, Span(depth_min_m=0.0))  # ...or the whole dive
    out = table_rows(table)
    bands = {round(b["depth_m"]): b for b in out["bands"]}
    assert set(bands) == {1200, 3420}
    for depth, band in bands.items():
        (row,) = band["rows"]
        assert row["lambda_att_m"] == pytest.approx(LAMBDA_AT[float(depth)], rel=1e-6)
        assert {round(p["depth_m"]) for p in row["pairs"]} == {depth}
    (whole,) = out["rows"]
    assert whole["lambda_att_m"] is None and whole["n_pairs"] == 6
    assert "crosses 2 depths whose water differs" in whole["note"], whole["note"]
    assert "1200 m: 20.00" in whole["note"] and "3420 m: 30.00" in whole["note"]
    assert sorted(round(p["depth_m"]) for p in whole["pairs"]) == [1200] * 3 + [3420] * 3


def test_a_span_across_the_same_water_keeps_its_value_and_says_it_pools_depths() -> None:
    rows = rows_at(1200.0, 25.0) + rows_at(3420.0, 25.0)
    _, table = attenuation_over_span(rows, SETUP, Span(depth_min_m=0.0))
    (whole,) = table_rows(table)["rows"]
    assert whole["lambda_att_m"] == pytest.approx(25.0, rel=1e-6)
    assert "pairs of 2 depths whose λ_att agree" in whole["note"]
