"""The lab simulator: media, the temperature-dependent LEM, the point source, lab frame sets."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from lrm.labset import TRUTH, lab_spec, match_truth, truth_values
from lrm.sim.camera import CameraModel
from lrm.sim.lab import PointSourceRenderer, TemperatureModel, air, expected_mean_gray, expose, tap_water
from lrm.sim.scene import LEMModel
from tests.utils.labsets import SMALL_CAMERA, make_lab_set


def test_air_attenuates_little_but_not_nothing() -> None:
    medium = air()
    # Over a 41 m scan the centre gray drops by ~0.1 % at 405 nm, less at longer wavelengths.
    loss = {wl: 1 - math.exp(-41.2 / medium.at(wl).lambda_att_m) for wl in (405, 460, 525)}
    assert 5e-4 < loss[405] < 3e-3
    assert loss[405] > loss[460] > loss[525] > 0
    assert_allclose(medium.at(460).lambda_sca_m / medium.at(405).lambda_sca_m, (460 / 405) ** 4)
    assert 4.0 < tap_water().at(405).lambda_att_m < 9.0


def test_temperature_model_changes_brightness_and_ratio_from_the_reference() -> None:
    tm = TemperatureModel()
    lem = LEMModel()
    assert tm.lem_at(lem, tm.reference_c).emission_ratio == lem.emission_ratio
    warm = tm.lem_at(lem, 18.9)
    dt = 18.9 - tm.reference_c
    assert_allclose(warm.emission_ratio[460], 1.27 * (1 + tm.ratio_per_c[460] * dt))
    assert_allclose(warm.radiance_e_per_s[460], 65000 * (1 + tm.brightness_per_c[460] * dt))
    # The T-REX lab saw < 1 % between 2 and 19 °C: so does the default model.
    assert all(abs(warm.emission_ratio[w] / lem.emission_ratio[w] - 1) < 0.01 for w in (405, 460, 525))
    with pytest.raises(ValueError, match="temperature_c must lie in"):
        tm.lem_at(lem, 120.0)


@pytest.mark.parametrize("electrons", [0.0, 20.0, 1500.0, 5900.0, 6400.0, 9000.0])
def test_expected_mean_gray_matches_the_sensor_it_describes(electrons: float) -> None:
    # The truth of the linearity calibration: mean gray with noise, knee and 8-bit steps,
    # checked against many pixels exposed by the sensor chain itself.
    camera = CameraModel(width_px=400, height_px=400, dark_current_e_per_s=0.0, hot_pixel_fraction=0.0)
    frame = expose(camera, np.full((400, 400), electrons), 0.01, 0.0, np.random.default_rng(1))
    values = frame.astype(float)
    expected = float(expected_mean_gray(camera, electrons, 0.0))
    assert abs(values.mean() - expected) < 4 * max(values.std(), 0.3) / math.sqrt(values.size)
    if electrons == 0.0:  # with 0.12 gray of read noise the 2.4 gray dark level reads low
        assert expected < camera.black_level_gray - 0.1


def test_point_source_conserves_its_flux_and_sits_where_placed() -> None:
    camera = CameraModel(width_px=64, height_px=64, psf_sigma_px=1.5, hot_pixel_fraction=0.0)
    # 12 dB: read noise dithers the 8-bit steps; the dark level is known exactly.
    frame, truth = PointSourceRenderer(camera).render(
        30.3, 33.8, 3e5, 0.05, 12.0, rng=np.random.default_rng(0)
    )
    dark = float(expected_mean_gray(camera, camera.dark_current_e_per_s * 0.05, 12.0))
    window = frame[25:43, 21:40].astype(float) - dark
    assert_allclose(window.sum(), truth.flux_gray, rtol=0.02)
    yy, xx = np.mgrid[25:43, 21:40]
    assert_allclose(
        [(window * xx).sum() / window.sum(), (window * yy).sum() / window.sum()], [30.3, 33.8], atol=0.05
    )
    with pytest.raises(ValueError, match="outside the frame"):
        PointSourceRenderer(camera).render(70.0, 3.0, 1e5, 0.05, 0.0, rng=np.random.default_rng(0))


def test_lab_sets_are_reproducible_and_record_readings_apart_from_truth(tmp_path: Path) -> None:
    values = {"wavelengths_nm": (460,), "distances_m": (5.2, 10.0, 20.0)}
    a = make_lab_set(tmp_path / "a", "air-scan", seed=3, **values)
    make_lab_set(tmp_path / "b", "air-scan", seed=3, **values)
    assert (tmp_path / "a" / "manifest.csv").read_bytes() == (tmp_path / "b" / "manifest.csv").read_bytes()
    for name in ("A_00001.png", "A_00003.png"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()
    assert json.loads((tmp_path / "a" / TRUTH).read_text())["kind"] == "air-scan"
    # The manifest holds the scale readings; the true distances differ by about their 0.1 m error.
    offsets = [f["true_distance_m"] - f["distance_m"] for f in a["frames"]]
    assert 0 < max(abs(o) for o in offsets) < 0.5
    assert a["truth"]["focal_px"] == pytest.approx(SMALL_CAMERA.focal_px)


def test_lab_spec_refuses_unknown_kinds_and_bad_values() -> None:
    with pytest.raises(ValueError, match="unknown lab kind 'sky-scan'"):
        lab_spec("sky-scan")
    with pytest.raises(ValueError, match="repeats must be >= 1"):
        lab_spec("psf", repeats=0)
    with pytest.raises(ValueError, match="psf has no setting distances_m"):
        lab_spec("psf", distances_m=(1.0, 2.0))
    with pytest.raises(ValueError, match="outside the camera's"):
        lab_spec("air-scan", target_gray=1e6).shots()


def test_match_truth_refuses_a_result_missing_a_true_value() -> None:
    doc = {"kind": "psf", "truth": {"psf_sigma_px": 1.2, "wavelength_nm": 460}}
    truth = truth_values(doc)
    measured = [{**t, "err": 0.01} for t in truth]
    assert len(match_truth(measured, truth)) == 4
    with pytest.raises(ValueError, match="0 result values match"):
        match_truth(measured[1:], truth)
