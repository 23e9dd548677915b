"""The simulator against its own physics."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lrm.sim import CameraModel, FrameRenderer, Placement
from lrm.sim.scene import water_preset
from tests.utils.sim import SMALL_CAMERA, renderer


def center_mean(frame: np.ndarray, xy: tuple[float, float], r: int = 5) -> float:
    x, y = round(xy[0]), round(xy[1])
    return float(frame[y - r : y + r + 1, x - r : x + r + 1].mean())


@pytest.mark.parametrize("distance_m", [8.0, 21.56, 41.62])
def test_disk_radius_follows_pinhole_geometry(distance_m: float) -> None:
    r = renderer("trex", distance_m, camera=SMALL_CAMERA)
    expected = SMALL_CAMERA.focal_px * 0.215 / math.sqrt(distance_m**2 - 0.215**2)
    assert r.disk_radius_px == pytest.approx(expected)
    frame, truth = r.render(460, 0.05, 6.0, rng=np.random.default_rng(0))
    above = frame > truth.background_gray + 0.5 * truth.direct_center_gray
    assert math.sqrt(above.sum() / math.pi) == pytest.approx(expected, rel=0.03)


def test_radius_times_distance_is_constant() -> None:
    radii = [renderer("trex", d, camera=SMALL_CAMERA).disk_radius_px * d for d in (10, 20, 40)]
    assert max(radii) / min(radii) == pytest.approx(1.0, abs=2e-3)


def test_centre_gray_scales_with_exposure_and_gain_until_saturation() -> None:
    r = renderer("trex", 21.56, camera=SMALL_CAMERA)
    base = r.expected_center_gray(460, 0.01, 0.0) - SMALL_CAMERA.black_level_gray
    for exposure, gain in [(0.02, 0.0), (0.05, 0.0), (0.01, 6.0), (0.02, 12.0)]:
        expected = base * exposure / 0.01 * 10 ** (gain / 20)
        got = r.expected_center_gray(460, exposure, gain) - SMALL_CAMERA.black_level_gray
        assert got == pytest.approx(expected, rel=2e-3)
        frame, truth = r.render(460, exposure, gain, rng=np.random.default_rng(1))
        assert center_mean(frame, truth.centroid_px) - truth.background_gray == pytest.approx(
            expected, rel=0.03
        )
    # Far beyond the knee the centre sits at 255, never above.
    frame, truth = r.render(460, 1.0, 20.0, rng=np.random.default_rng(2))
    assert truth.expected_center_gray == pytest.approx(255, abs=0.6)
    assert center_mean(frame, truth.centroid_px) == pytest.approx(255, abs=0.5)


def test_noise_variance_is_shot_plus_read_noise() -> None:
    cam = CameraModel(
        width_px=400,
        height_px=400,
        fov_deg=16.0,
        psf_sigma_px=0.0,
        hot_pixel_fraction=0.0,
        dark_current_e_per_s=0.0,
    )
    big = FrameRenderer(cam, Placement("A", 3.0), water_preset("clear"))
    frame, truth = big.render(460, 0.002, 12.0, rng=np.random.default_rng(3))
    x, y = (round(v) for v in truth.centroid_px)
    patch = frame[y - 40 : y + 40, x - 40 : x + 40].astype(float)
    gain_total = cam.gray_per_electron * 10 ** (12 / 20)
    mean_gray = patch.mean() - cam.black_level_gray
    electrons = mean_gray / gain_total
    modelled = (electrons + cam.read_noise_e**2) * gain_total**2 + 1 / 12
    assert patch.var() == pytest.approx(modelled, rel=0.08)
    dark = frame[:40, :40].astype(float)
    assert dark.var() == pytest.approx(cam.read_noise_e**2 * gain_total**2 + 1 / 12, rel=0.25)


def test_same_seed_same_frame_and_hot_pixels_stay_put() -> None:
    r1 = renderer("trex", 21.56, camera=SMALL_CAMERA)
    r2 = FrameRenderer(SMALL_CAMERA, r1.placement, water_preset("trex"), seed=0)
    f1, _ = r1.render(405, 0.1, 8.0, rng=np.random.default_rng(7))
    f2, _ = r2.render(405, 0.1, 8.0, rng=np.random.default_rng(7))
    np.testing.assert_array_equal(f1, f2)
    f3, _ = r1.render(405, 0.1, 8.0, rng=np.random.default_rng(8))
    assert not np.array_equal(f1, f3)
    rows, cols, _ = r1._hot
    assert len(rows) > 0 and np.all(f3[rows, cols] > 20)


def test_halo_surrounds_the_disk_and_falls_off() -> None:
    r = renderer("turbid", 21.56, camera=SMALL_CAMERA)
    table = r.halo_table(460)
    psi_disk = math.asin(0.215 / 21.56)
    psi = r._psi_grid
    h = np.interp([1.2 * psi_disk, 2 * psi_disk, 4 * psi_disk], psi, table)
    assert h[0] > h[1] > h[2] > 0
    clear = renderer("clear", 21.56, camera=SMALL_CAMERA).halo_table(460)
    assert np.interp(2 * psi_disk, psi, table) / math.exp(-21.56 / 12.5) > np.interp(
        2 * psi_disk, psi, clear
    ) / math.exp(-21.56 / 58.3)


def test_double_image_near_the_edge_of_camera_a_only() -> None:
    cam = SMALL_CAMERA
    ghosty = FrameRenderer(cam, Placement("A", 21.56), water_preset("trex"), double_image=True)
    _, centred = ghosty.render(460, 0.05, 6.0, rng=np.random.default_rng(0))
    frame, edge = ghosty.render(460, 0.05, 6.0, rng=np.random.default_rng(0), offset_px=(-200, 0))
    assert not centred.double_image
    assert edge.double_image
    # Light lands ~15 px toward the centre: the disk widens along x.
    row = frame[round(edge.centroid_px[1])].astype(float)
    width = np.count_nonzero(row > edge.background_gray + 0.3 * edge.direct_center_gray)
    assert width == pytest.approx(2 * ghosty.disk_radius_px + 15, abs=4)


def test_motion_blur_smears_the_edge_along_the_motion() -> None:
    r = renderer("trex", 21.56, camera=SMALL_CAMERA)
    sharp, t = r.render(460, 0.05, 6.0, rng=np.random.default_rng(0))
    blurred, _ = r.render(460, 0.05, 6.0, rng=np.random.default_rng(0), blur_px=(20.0, 0.0))
    y = round(t.centroid_px[1])
    thr = t.background_gray + 0.1 * t.direct_center_gray
    assert np.count_nonzero(blurred[y] > thr) > np.count_nonzero(sharp[y] > thr) + 10


def test_settings_outside_the_camera_range_are_refused() -> None:
    r = renderer("trex", 21.56, camera=SMALL_CAMERA)
    with pytest.raises(ValueError, match="exposure_s"):
        r.render(460, -0.1, 6.0, rng=np.random.default_rng(0))
    with pytest.raises(ValueError, match="gain_db"):
        r.render(460, 0.1, 60.0, rng=np.random.default_rng(0))
    with pytest.raises(ValueError, match="no water optics"):
        r.render(600, 0.1, 6.0, rng=np.random.default_rng(0))
