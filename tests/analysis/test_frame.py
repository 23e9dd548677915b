"""Per-frame analysis on simulated T-REX frames: acceptance and each rejection reason."""

from __future__ import annotations

import numpy as np
import pytest

from analysis import FrameConfig, Reason, analyze_frame
from tests.utils.sim import SMALL_CAMERA, renderer


@pytest.fixture(scope="module")
def near():
    return renderer("trex", 21.56, camera=SMALL_CAMERA, camera_id="A")


def render(r, wl=460, exposure=0.05, gain=8.0, seed=0, **kw):
    return r.render(wl, exposure, gain, rng=np.random.default_rng(seed), **kw)


def test_in_range_frame_gives_i_center_close_to_the_truth(near) -> None:
    frame, truth = render(near)
    res = analyze_frame(frame)
    assert res.ok, res.detail
    expected = truth.direct_center_gray + truth.halo_center_gray
    # The fitted constant absorbs a little halo: within 2 % of direct + halo.
    assert res.i_center_gray == pytest.approx(expected, rel=0.02)
    assert abs(res.centroid_px[0] - truth.centroid_px[0]) < 0.1
    assert 0 < res.i_center_err_gray < 1.0


def test_saturated_lem_is_rejected_even_though_hot_pixels_saturate_everywhere(near) -> None:
    frame, truth = render(near, exposure=0.5, gain=14.0)
    assert truth.expected_center_gray > 250
    res = analyze_frame(frame)
    assert res.reason == Reason.SATURATED
    assert "gray" in res.detail


def test_hot_pixels_at_255_outside_the_disk_do_not_reject_the_frame(near) -> None:
    frame, _ = render(near)
    rng = np.random.default_rng(5)
    rows, cols = rng.integers(0, frame.shape[0], 300), rng.integers(0, frame.shape[1], 300)
    far_from_lem = np.hypot(cols - 320, rows - 256) > 120
    frame[rows[far_from_lem], cols[far_from_lem]] = 255
    assert far_from_lem.sum() > 100
    res = analyze_frame(frame)
    assert res.ok


def test_too_dark_lem_is_rejected(near) -> None:
    frame, truth = render(near, wl=405, exposure=0.003, gain=0.0)
    assert truth.expected_center_gray < 5
    res = analyze_frame(frame)
    assert res.reason in (Reason.TOO_DARK, Reason.NO_SOURCE)


def test_lem_off_gives_no_source(near) -> None:
    frame, _ = render(near, lem_on=False)
    assert analyze_frame(frame).reason == Reason.NO_SOURCE


def test_lem_cut_by_the_edge_is_off_edge(near) -> None:
    frame, _ = render(near, offset_px=(300.0, 0.0))
    res = analyze_frame(frame)
    assert res.reason == Reason.OFF_EDGE
    assert res.centroid_px is not None


def test_linear_range_is_configurable(near) -> None:
    frame, truth = render(near)
    assert 100 < truth.expected_center_gray < 200
    assert analyze_frame(frame, FrameConfig(linear_range_gray=(5, 100))).reason == Reason.SATURATED
    assert analyze_frame(frame, FrameConfig(linear_range_gray=(200, 250))).reason == Reason.TOO_DARK


def test_invalid_config_is_refused() -> None:
    with pytest.raises(ValueError, match="linear_range_gray"):
        FrameConfig(linear_range_gray=(240, 5))


def test_a_frame_full_of_light_is_saturated_and_no_detail_reads_infinite() -> None:
    """An all-255 frame was `no_source` ("check the LEM is on"): it is light everywhere, `saturated`.
    A 9 x 9 px frame with a disk of 11 px expected read "best -inf σ"."""
    full = analyze_frame(np.full((120, 160), 255, np.uint8))
    assert (full.status, full.reason) == ("rejected", "saturated") and "whole frame is at 255" in full.detail
    tiny = np.random.default_rng(1).normal(2.0, 0.3, (9, 9)).round().astype(np.uint8)
    tiny[4, 4] = 200  # one hot pixel: the matched filter (11 px) finds nothing to weigh at all
    small = analyze_frame(tiny, FrameConfig(expected_radius_px=11.0))
    assert small.reason == "no_source" and "inf" not in small.detail and "nan" not in small.detail, (
        small.detail
    )


def as_12_bit(frame8: np.ndarray) -> np.ndarray:
    """The 8-bit frame as a 12-bit camera would give it, MSB-aligned in 16 bits (PNG's way)."""
    return (np.rint(frame8.astype(np.float64) * 4095 / 255).astype(np.uint16)) << 4


def test_a_12_bit_frame_is_measured_on_the_8_bit_gray_scale_with_its_saturation_level(near) -> None:
    from camcal.core.images import decode_frame_scaled, encode_png

    frame, _ = render(near)
    stored, top = decode_frame_scaled(encode_png(as_12_bit(frame), 12))  # what the ship reads back
    assert top == 4095 << 4
    eight, twelve = analyze_frame(frame), analyze_frame(stored, full_scale=top)
    assert eight.ok and twelve.ok
    assert twelve.i_center_gray == pytest.approx(eight.i_center_gray, rel=2e-3)
    assert twelve.centroid_px == pytest.approx(eight.centroid_px, abs=0.02)
    # saturated pixels are those at the 12-bit top (65520), as the 8-bit frame's are at 255
    bright, _ = render(near, exposure=0.5, gain=14.0)
    sat8 = analyze_frame(bright)
    sat12 = analyze_frame(as_12_bit(bright), full_scale=top)
    assert sat8.reason == sat12.reason == Reason.SATURATED
    assert (
        sat12.saturated_fraction == pytest.approx(sat8.saturated_fraction) and sat8.saturated_fraction > 0.5
    )
    # told the wrong full scale (16 bits), the 12-bit top pixels would not count as saturated
    assert analyze_frame(as_12_bit(bright), full_scale=65535).saturated_fraction == 0.0
