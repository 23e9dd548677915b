"""Finding the LEM: sub-pixel centroid, robustness to hot pixels, no source, edges."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose

from analysis import FrameFormatError, check_frame, locate_source


def disk_frame(
    x: float,
    y: float,
    radius: float,
    level: float,
    shape=(400, 500),
    background: float = 3.0,
    noise: float = 0.0,
    seed: int = 0,
) -> np.ndarray:
    """An antialiased uniform disk centred at (x, y) in pixel-centre coordinates."""
    rows = np.arange(shape[0])[:, None]
    cols = np.arange(shape[1])[None, :]
    dist = np.sqrt((cols - x) ** 2 + (rows - y) ** 2)
    cover = np.clip(radius - dist + 0.5, 0, 1)
    img = background + level * cover
    if noise:
        img = img + np.random.default_rng(seed).normal(0, noise, shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


@settings(max_examples=40, deadline=None)
@given(x=st.floats(60, 440), y=st.floats(60, 340), radius=st.floats(6, 50), level=st.floats(30, 220))
def test_centroid_is_subpixel_accurate(x: float, y: float, radius: float, level: float) -> None:
    det = locate_source(disk_frame(x, y, radius, level))
    assert det.found
    assert_allclose([det.x_px, det.y_px], [x, y], atol=0.05)
    assert det.radius_px == pytest.approx(radius, rel=0.06, abs=0.6)
    assert not det.touches_edge


@settings(max_examples=15, deadline=None)
@given(x=st.floats(80, 420), y=st.floats(80, 320), seed=st.integers(0, 1000))
def test_centroid_with_noise_stays_within_a_tenth_of_a_pixel(x: float, y: float, seed: int) -> None:
    det = locate_source(disk_frame(x, y, 45, 90, noise=4.0, seed=seed))
    assert_allclose([det.x_px, det.y_px], [x, y], atol=0.1)


def test_hot_pixels_do_not_move_or_fake_the_source() -> None:
    frame = disk_frame(250.3, 180.7, 30, 60)
    rng = np.random.default_rng(1)
    rows, cols = rng.integers(0, 400, 200), rng.integers(0, 500, 200)
    keep = np.hypot(cols - 250.3, rows - 180.7) > 40
    frame[rows[keep], cols[keep]] = 255
    det = locate_source(frame)
    assert det.found
    assert_allclose([det.x_px, det.y_px], [250.3, 180.7], atol=0.05)


def test_dark_frame_with_hot_pixels_has_no_source() -> None:
    frame = disk_frame(0, 0, 0, 0, noise=1.0)
    frame[np.random.default_rng(2).integers(0, 400, 50), np.random.default_rng(3).integers(0, 500, 50)] = 255
    assert not locate_source(frame).found


def test_point_source_is_found_by_the_full_resolution_search() -> None:
    rows, cols = np.mgrid[:400, :500]
    img = 3 + 120 * np.exp(-((cols - 301.2) ** 2 + (rows - 99.6) ** 2) / (2 * 1.3**2))
    det = locate_source(np.rint(img).astype(np.uint8))
    assert det.found
    assert_allclose([det.x_px, det.y_px], [301.2, 99.6], atol=0.1)


def test_disk_cut_by_the_frame_edge_is_flagged() -> None:
    det = locate_source(disk_frame(15.0, 200.0, 40, 100))
    assert det.found and det.touches_edge


def test_double_image_shows_as_elongation() -> None:
    single = locate_source(disk_frame(250, 200, 45, 100))
    a = disk_frame(250, 200, 45, 58, background=1.5).astype(float)
    b = disk_frame(265, 200, 45, 42, background=1.5).astype(float)
    double = locate_source(np.clip(a + b, 0, 255).astype(np.uint8))
    assert single.elongation < 0.005
    assert double.elongation > 4 * single.elongation + 0.01


@pytest.mark.parametrize(
    ("bad", "fragment"),
    [
        (np.zeros((100, 100), dtype=np.uint16), "dtype uint16"),
        (np.zeros((100, 100, 3), dtype=np.uint8), "shape (100, 100, 3)"),
        (np.zeros((4, 4), dtype=np.uint8), "too small"),
        ([[1, 2], [3, 4]], "2-D uint8"),
    ],
)
def test_wrong_frames_are_refused_with_a_message_naming_them(bad, fragment: str) -> None:
    with pytest.raises(FrameFormatError, match="frame") as info:
        check_frame(bad)
    assert fragment in str(info.value)
