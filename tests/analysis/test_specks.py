"""A bioluminescence speck or a hot pixel on or beside the LEM is not the LEM, nor its centre's light.

Frames drawn with numpy alone (`tests.analysis.test_censor.draw_frame`: a uniform
40-gray disk of radius 45 px over a 5-gray dark level, 2.5 gray of noise), then
a speck added. Before, a 3 x 3 speck of +120 gray on the disk's centre was taken
for the source (radius 1.3 px, the background fitted inside the disk: I_center
41.9 ± 0.9 for 39.8), and a hot pixel among the centre pixels moved I_center by 5 %.
"""

from __future__ import annotations

import numpy as np
import pytest

from analysis import analyze_frame
from tests.analysis.test_censor import CONFIG, RADIUS_PX, draw_frame


def with_speck(frame: np.ndarray, y: int, x: int, half: int, gray: int) -> np.ndarray:
    out = frame.copy()
    patch = out[y - half : y + half + 1, x - half : x + half + 1].astype(int) + gray
    out[y - half : y + half + 1, x - half : x + half + 1] = np.minimum(patch, 255)
    return out


@pytest.mark.parametrize(
    ("where", "dy", "dx", "half", "gray"),
    [
        ("on the centre", 0, 0, 1, 120),
        ("on the disk, off centre", 22, -27, 3, 160),
        ("beside the disk", 62, -67, 3, 210),
        ("one hot pixel among the centre pixels", 0, 2, 0, 255),
    ],
)
def test_the_lem_is_measured_as_without_the_speck(where: str, dy: int, dx: int, half: int, gray: int) -> None:
    rng = np.random.default_rng(1)
    clean = draw_frame(rng, 40.0, 2.5, black_gray=5.0)
    ref = analyze_frame(clean, CONFIG)
    assert ref.ok and ref.centroid_px is not None
    y, x = round(ref.centroid_px[1]), round(ref.centroid_px[0])
    got = analyze_frame(with_speck(clean, y + dy, x + dx, half, gray), CONFIG)
    assert got.ok, (where, got.reason, got.detail)
    assert got.radius_px == pytest.approx(RADIUS_PX, rel=0.05), where
    assert got.i_center_gray == pytest.approx(ref.i_center_gray, abs=3 * ref.i_center_err_gray), where
    assert got.background_gray == pytest.approx(ref.background_gray, abs=0.1), where
