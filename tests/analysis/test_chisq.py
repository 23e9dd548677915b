"""The χ² fit recovers the water of simulated frames, and refuses what it cannot fit."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from transport_cases import CASES, EMISSION_RATIO, GEOMETRY, WAVELENGTH_NM, small_camera

from analysis import FrameRecord, Setting, analyze_frame, stack_by_setting
from analysis.chisq import (
    DCHI2_2D_68,
    ChiSquareFit,
    FitConfig,
    FitInputError,
    collect_settings,
    fit_wavelength,
    quantisation_bias_gray,
)
from analysis.transport.templates import TemplateGrid
from lrm.sim import FrameRenderer
from lrm.sim.scene import TREX_PLACEMENTS, Water


@pytest.fixture(scope="module")
def fits(grids: dict[str, TemplateGrid], profiles: dict[str, list]) -> dict[str, ChiSquareFit]:
    # The frames' halo comes from the same template grid: its Monte Carlo noise is in the data
    # too, so it is no independent error (FitConfig.template_errors).
    config = FitConfig(template_errors=False)
    return {
        name: fit_wavelength(WAVELENGTH_NM, profiles[name], grids[name], GEOMETRY, EMISSION_RATIO, config)
        for name in CASES
    }


@pytest.mark.parametrize("name", sorted(CASES))
def test_fit_recovers_absorption_and_scattering_lengths(fits: dict[str, ChiSquareFit], name: str) -> None:
    fit, truth = fits[name], CASES[name].optics
    pull_abs = (fit.lambda_abs_m - truth.lambda_abs_m) / fit.lambda_abs_err_m
    pull_sca = (fit.lambda_sca_m - truth.lambda_sca_m) / fit.lambda_sca_total_err_m
    assert abs(pull_abs) < 3, (
        f"λ_abs {fit.lambda_abs_m:.1f} ± {fit.lambda_abs_err_m:.1f}, true {truth.lambda_abs_m}"
    )
    assert abs(pull_sca) < 3, (
        f"λ_sca {fit.lambda_sca_m:.2f} ± {fit.lambda_sca_err_m:.2f}, true {truth.lambda_sca_m}"
    )
    # The errors are informative, not merely wide.
    assert fit.lambda_abs_err_m < 0.3 * truth.lambda_abs_m
    assert fit.lambda_sca_err_m < 0.05 * truth.lambda_sca_m
    # 1/λ_abs + 1/λ_sca is the attenuation length.
    assert abs(fit.lambda_att_m - truth.lambda_att_m) < 3 * fit.lambda_att_err_m
    assert not fit.at_edge


@pytest.mark.parametrize("name", sorted(CASES))
def test_fit_is_consistent(fits: dict[str, ChiSquareFit], name: str) -> None:
    fit = fits[name]
    # A model that describes the data: χ²/ndof near one (the errors are honest).
    assert 0.5 < fit.chi2_ndof < 1.3
    # Nuisances stay within their priors.
    assert all(abs(n.pull) < 3 for n in fit.nuisances)
    # The profiled intervals bracket the estimate, and the minimum of the Δχ² map is the fit.
    lo, hi = fit.lambda_abs_interval_m
    assert lo < fit.lambda_abs_m < hi
    lo, hi = fit.lambda_sca_interval_m
    assert lo < fit.lambda_sca_m < hi
    assert fit.contour.delta_chi2.min() > -1e-3
    assert fit.contour.delta_chi2.min() < 0.2
    assert (fit.contour.delta_chi2 < DCHI2_2D_68).any()


def test_truth_lies_inside_the_joint_95_percent_region(fits: dict[str, ChiSquareFit]) -> None:
    for name, fit in fits.items():
        truth = CASES[name].optics
        c = fit.contour
        i = int(np.argmin(np.abs(np.log(c.lambda_abs_m / truth.lambda_abs_m))))
        j = int(np.argmin(np.abs(np.log(c.lambda_sca_m / truth.lambda_sca_m))))
        assert c.delta_chi2[j, i] < 11.8, name  # 3σ joint region of two parameters


def test_profiles_keep_both_cameras_and_all_settings(profiles: dict[str, list]) -> None:
    for name, settings in profiles.items():
        assert [(s.exposure_s, s.gain_db) for s in settings] == sorted(CASES[name].settings)
        for s in settings:
            assert s.near.n_frames == 5 and s.far.n_frames == 5
            # The near camera's disk (87 px) is larger than the far one's (45 px).
            near_edge = int(np.argmax(s.near.mean_gray < 0.5 * s.near.mean_gray[5]))
            far_edge = int(np.argmax(s.far.mean_gray < 0.5 * s.far.mean_gray[5]))
            assert 84 <= near_edge <= 90 and 42 <= far_edge <= 48


def test_quantisation_bias_bound() -> None:
    # Noise of 0.3 gray leaves rounding biases of a few hundredths; 0.6 gray dithers them away.
    sem = np.array([0.3, 0.6]) / math.sqrt(100 * 4)
    bias = quantisation_bias_gray(sem, np.array([100, 100]), np.array([4, 4]))
    assert bias[0] == pytest.approx(math.exp(-2 * math.pi**2 * 0.09) / math.pi)
    assert 0.02 < bias[0] < 0.06
    assert bias[1] < 5e-4


def _records(exposure: float, gain: float, cameras: tuple[str, ...], repeats: int) -> list[FrameRecord]:
    water = Water({WAVELENGTH_NM: CASES["clear"].optics})
    rng = np.random.default_rng(3)
    out = []
    for p in TREX_PLACEMENTS:
        if p.camera not in cameras:
            continue
        r = FrameRenderer(small_camera(), p, water, seed=3)
        for _ in range(repeats):
            frame, _ = r.render(WAVELENGTH_NM, exposure, gain, rng=rng)
            out.append(FrameRecord(p.camera, Setting(WAVELENGTH_NM, exposure, gain), analyze_frame(frame)))
    return out


def test_missing_camera_is_named() -> None:
    stacks = stack_by_setting(_records(0.02, 14.0, ("A",), 3))
    with pytest.raises(FitInputError, match=r"no accepted .* frame from the far camera B"):
        collect_settings(stacks, WAVELENGTH_NM, "A", "B")


def test_too_few_frames_is_named() -> None:
    stacks = stack_by_setting(_records(0.02, 14.0, ("A", "B"), 1))
    with pytest.raises(
        FitInputError, match=r"only 1 accepted frame\(s\) from the near camera A; .* at least 3"
    ):
        collect_settings(stacks, WAVELENGTH_NM, "A", "B")


def test_only_saturated_frames_are_refused() -> None:
    records = _records(1.0, 20.0, ("A", "B"), 2)
    assert all(r.analysis.reason == "saturated" for r in records)
    with pytest.raises(FitInputError, match=r"no accepted \(unsaturated\) frame from the near camera A"):
        collect_settings(stack_by_setting(records), WAVELENGTH_NM, "A", "B")


def test_no_shared_setting_is_refused() -> None:
    stacks = stack_by_setting(_records(0.01, 14.0, ("A",), 3) + _records(0.01, 18.0, ("B",), 3))
    with pytest.raises(
        FitInputError, match="no exposure/gain setting with accepted frames from both cameras"
    ):
        collect_settings(stacks, WAVELENGTH_NM, "A", "B")


def test_empty_settings_are_refused(grids: dict[str, TemplateGrid]) -> None:
    with pytest.raises(FitInputError, match="460 nm: no setting"):
        fit_wavelength(WAVELENGTH_NM, [], grids["clear"], GEOMETRY, EMISSION_RATIO)


def test_dark_near_profile_is_refused(grids: dict[str, TemplateGrid], profiles: dict[str, list]) -> None:
    s = profiles["clear"][0]
    dark = replace(s, near=replace(s.near, mean_gray=np.full_like(s.near.mean_gray, s.near.background_gray)))
    with pytest.raises(FitInputError, match="near camera's profile holds no light"):
        fit_wavelength(WAVELENGTH_NM, [dark], grids["clear"], GEOMETRY, EMISSION_RATIO)
