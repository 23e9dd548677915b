"""Failures look like failures: limits instead of grid edges, errors scaled by √(χ²/ndof), budget maths."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from analysis.chisq import LOWER_LIMIT, MEASURED, FitConfig, Nuisance, SettingProfiles, fit_wavelength
from analysis.chisq.limits import error_scale, estimate
from analysis.chisq.posterior import marginal_posterior
from analysis.chisq.results import Estimate, SystematicBudget, SystematicShift, sys_text
from analysis.chisq.systematics import (
    SystematicsConfig,
    nodes_around,
    nodes_covering,
    phase_limits,
    template_sample_mean,
    variation_settings,
)
from analysis.chisq.wavelength import make_objective
from analysis.transport.scene import emission_shares
from analysis.transport.templates import TemplateGrid
from camcal.fitdoc import estimate_text
from camcal.fitset import AttenuationCheck
from tests.analysis.transport_cases import CASES, EMISSION_RATIO, GEOMETRY, WAVELENGTH_NM

QUICK = FitConfig(template_errors=False, contour_points=7)


def test_a_minimum_beyond_the_range_is_a_lower_limit_not_a_value(
    grids: dict[str, TemplateGrid], profiles: dict[str, list]
) -> None:
    # Clear water, λ_abs 100 m, fitted with λ_abs allowed only up to 60 m: the χ² falls all the
    # way to the edge. The fit must say "λ_abs > X", never "λ_abs = 60 ± ...".
    config = replace(QUICK, lambda_abs_range_m=(2.0, 60.0))
    fit = fit_wavelength(WAVELENGTH_NM, profiles["clear"], grids["clear"], GEOMETRY, EMISSION_RATIO, config)
    est = fit.lambda_abs
    assert est.status == LOWER_LIMIT
    assert est.value_m is None and est.err_m is None
    assert est.limit_m is not None and 2.0 < est.limit_m < 60.0
    assert est.cl == pytest.approx(0.95)
    assert "lambda_abs" in fit.at_edge
    assert est.text("λ_abs").startswith("λ_abs > ") and "95 % CL" in est.text("λ_abs")
    # λ_sca is still measured, and the wavelength still gives a result.
    assert fit.lambda_sca.status == MEASURED and fit.has_result
    entry = {"lambda_abs": {"status": est.status, "limit_m": est.limit_m, "cl": est.cl}}
    assert estimate_text(entry, "lambda_abs") == f"> {est.limit_m:.3g} m (95 % CL)"
    # Varying the phase function: a refit that reaches below the limit loosens it (the nominal's
    # limit says nothing of a water with another ⟨cos θ⟩); one that stays above leaves it.
    refits = [np.array([est.limit_m * 0.4, 140.0, 40.0, 0.0]), np.array([60.0, 150.0, 42.0, 0.0])]
    assert phase_limits(fit, refits) == (pytest.approx(est.limit_m * 0.4), None)
    assert phase_limits(fit, refits[1:]) == (None, None)
    loose = fit.with_budget(SystematicBudget((), 0.0, (est.limit_m * 0.4, None)))
    assert loose.lambda_abs.status == LOWER_LIMIT
    assert loose.lambda_abs.limit_m == pytest.approx(est.limit_m * 0.4)
    assert loose.lambda_sca == fit.lambda_sca


def _shrink_errors(settings: list[SettingProfiles], factor: float) -> list[SettingProfiles]:
    out = []
    for s in settings:
        near = replace(s.near, sem_gray=s.near.sem_gray * factor)
        far = replace(s.far, sem_gray=s.far.sem_gray * factor)
        out.append(replace(s, near=near, far=far))
    return out


def test_errors_are_scaled_when_the_model_does_not_describe_the_data(
    grids: dict[str, TemplateGrid], profiles: dict[str, list]
) -> None:
    # The same profiles with errors claimed 2.5x too small (where the floor of 8-bit rounding
    # lets them shrink): χ²/ndof rises, and the fit must widen its intervals to Δχ² = χ²/ndof
    # instead of quoting the Δχ² = 1 ones.
    grid, prof = grids["turbid"], profiles["turbid"]
    honest = fit_wavelength(WAVELENGTH_NM, prof, grid, GEOMETRY, EMISSION_RATIO, QUICK)
    claimed = fit_wavelength(WAVELENGTH_NM, _shrink_errors(prof, 0.4), grid, GEOMETRY, EMISSION_RATIO, QUICK)
    assert honest.error_scale == pytest.approx(max(1.0, math.sqrt(honest.chi2_ndof)))
    assert claimed.chi2_ndof > 1.5
    assert claimed.error_scale == pytest.approx(math.sqrt(claimed.chi2_ndof))
    # The same data's intervals at Δχ² = 1 (unscaled), from the fit's own objective and minimum.
    obj = make_objective(_shrink_errors(prof, 0.4), grid, GEOMETRY, EMISSION_RATIO, QUICK)
    best = obj.minimise(np.log([claimed.lambda_abs_m, claimed.lambda_sca_m]))
    for k, attr in enumerate(("lambda_abs_err_m", "lambda_sca_err_m")):
        raw, _, _ = estimate(obj, best, k, attr, obj(best), 0.05, 1.0)
        assert raw.err_m is not None
        assert getattr(claimed, attr) == pytest.approx(claimed.error_scale * raw.err_m, rel=0.1), attr


def test_a_profile_never_loses_the_best_point_in_a_wide_window(
    grids: dict[str, TemplateGrid], profiles: dict[str, list]
) -> None:
    """A narrow λ_sca valley inside a wide search window: the profile along λ_abs at the best point
    is the best point's χ² (a bounded search that missed the valley once gave a zero-width error)."""
    obj = make_objective(profiles["turbid"], grids["turbid"], GEOMETRY, EMISSION_RATIO, QUICK)
    best = obj.minimise(np.log([25.0, 25.0]))
    assert obj.profiled(best, 0, float(best[0]), 3.0) <= obj(best) + 1e-9
    abs_est, _, _ = estimate(obj, best, 0, "lambda_abs_err_m", obj(best), 0.05, 1.0)
    assert abs_est.err_m is not None and abs_est.err_m > 0


def test_error_scale_is_never_below_one() -> None:
    assert error_scale(50.0, 100) == 1.0
    assert error_scale(400.0, 100) == pytest.approx(2.0)
    assert error_scale(10.0, 0) == 1.0


G = [0.88, 0.90, 0.92, 0.93, 0.94, 0.96]
R = [0.10, 0.17, 0.25]


def test_marginal_posterior_weighs_each_shift_by_what_the_data_allow() -> None:
    """The posterior's mean shift and spread: the prior alone, data that pin, data that move."""
    dx = np.array(G) - 0.93

    def rows(dchi2: np.ndarray, abs_shift: np.ndarray | None = None) -> np.ndarray:
        a = 100 * dx if abs_shift is None else abs_shift
        return np.stack([a, 50 * dx, 10 * dx, dchi2], axis=1)

    # No information in the data: the shift's mean and spread over the uniform prior.
    m = marginal_posterior([G], rows(np.zeros(6)), 1.0)
    uniform_sd = 0.08 / math.sqrt(12)
    assert m.shift_m == pytest.approx([100 * -0.01, 50 * -0.01, 10 * -0.01], rel=1e-2)
    assert m.spread_m == pytest.approx([100 * uniform_sd, 50 * uniform_sd, 10 * uniform_sd], rel=1e-2)
    assert m.mean[0] == pytest.approx(0.92, abs=1e-3) and m.sd[0] == pytest.approx(uniform_sd, rel=1e-2)
    # Data that pin the parameter at the nominal (Δχ² = δ²/0.01²): no shift, slope times the width.
    m = marginal_posterior([G], rows(dx**2 / 0.01**2), 1.0)
    assert m.mean[0] == pytest.approx(0.93, abs=1e-3) and m.sd[0] == pytest.approx(0.01, rel=0.1)
    assert abs(m.shift_m[0]) < 0.1 and m.spread_m[0] == pytest.approx(100 * 0.01, rel=0.1)
    # An error scale of 2 widens the posterior about twofold (the range's ends cut it a little).
    wide = marginal_posterior([G], rows(dx**2 / 0.01**2), 2.0)
    assert 1.6 * m.sd[0] < wide.sd[0] < 2.1 * m.sd[0]
    # A refit that ran away at an end the data exclude (Δχ² 200) does not blow the error up.
    runaway = 100 * dx
    runaway[-1] = 1900.0
    dchi2 = dx**2 / 0.01**2
    dchi2[-1] = 200.0
    assert marginal_posterior([G], rows(dchi2, runaway), 1.0).spread_m[0] < 5.0
    # Data that prefer another value: the lengths move there, and the spread stays the width's.
    m = marginal_posterior([G], rows((dx - 0.02) ** 2 / 0.005**2 - 0.02**2 / 0.005**2), 1.0)
    assert m.mean[0] == pytest.approx(0.95, abs=2e-3)
    assert m.shift_m[1] == pytest.approx(50 * 0.02, rel=0.05)
    assert m.spread_m[1] == pytest.approx(50 * 0.005, rel=0.15)
    assert m.rms_m[1] == pytest.approx(math.hypot(m.shift_m[1], m.spread_m[1]))
    # Upward and downward apart, each the RMS over its own side: the posterior lies upward here.
    assert m.up_m[1] == pytest.approx(m.rms_m[1], rel=1e-3)
    # A length the fit only bounds gets no shift and no spread.
    bounded = rows(np.zeros(6))
    bounded[:, 0] = np.nan
    m = marginal_posterior([G], bounded, 1.0)
    assert math.isnan(m.shift_m[0]) and math.isnan(m.spread_m[0]) and np.isfinite(m.shift_m[1])


def test_a_one_sided_runaway_gives_a_one_sided_systematic_error() -> None:
    """Refits that push λ_abs far up at one end of the prior (λ_sca falling to λ_att there) and a
    little down at the other: the budget says so as +up/−down instead of one symmetric spread."""
    dx = np.array(G) - 0.93
    shifts = np.where(dx < 0, 4000 * dx**2, -60 * dx)  # +10 m at 0.88; −1.8 m at 0.96
    d = np.stack([shifts, 40 * dx, 0 * dx, np.zeros(6)], axis=1)
    m = marginal_posterior([G], d, 1.0)
    assert m.up_m[0] > 4 * m.down_m[0] > 0
    # Over its own side, 0.93-0.96 (60 m per unit): √(∫ (60x)² dx / 0.03) = 60 · 0.03/√3.
    assert m.down_m[0] == pytest.approx(60 * 0.03 / math.sqrt(3), rel=0.03)
    # The sides weighted by their shares of the prior add up to the whole's mean square.
    assert (0.05 * m.up_m[0] ** 2 + 0.03 * m.down_m[0] ** 2) / 0.08 == pytest.approx(
        m.rms_m[0] ** 2, rel=0.03
    )
    # A symmetric spread gives both sides the whole's RMS (so pulls taken toward the truth keep RMS 1).
    x = np.array([-0.04, -0.02, 0.0, 0.02, 0.04])
    sym = marginal_posterior([0.93 + x], np.stack([100 * x, 100 * x, 0 * x, 0 * x], axis=1), 1.0)
    assert sym.up_m[0] == pytest.approx(sym.rms_m[0], rel=0.02)
    assert sym.down_m[0] == pytest.approx(sym.rms_m[0], rel=0.02)
    phase = SystematicShift(
        "phase_function", "phase", ("a", "b"), (0.0, 0.0), (0.0, 0.0), (0.0, 0.0), (0.0, 0.0),
        tuple(m.rms_m), errors_up_m=tuple(m.up_m), errors_down_m=tuple(m.down_m),
    )  # fmt: skip
    other = SystematicShift("emission", "e", ("h",), (1.0,), (0.1,), (0.2,), (0.0,), (1.0, 0.1, 0.2))
    budget = SystematicBudget((phase, other), 0.0)
    # Each side in quadrature on its own, a symmetric line counting on both.
    assert budget.sys_up_m(0) == pytest.approx(math.hypot(m.up_m[0], 1.0))
    assert budget.sys_down_m(0) == pytest.approx(math.hypot(m.down_m[0], 1.0))
    symmetric = SystematicBudget((other,), 0.0)
    assert budget.sys_up_m(0) != budget.sys_down_m(0) and symmetric.sys_up_m(0) == symmetric.sys_down_m(0)
    assert sys_text(budget.sys_up_m(0), budget.sys_down_m(0)).startswith("+")
    assert sys_text(0.304, 0.296) == "± 0.30" and sys_text(float("nan"), 1.0) == "—"


def test_lambda_abs_sides_taken_on_its_coefficient_keep_the_pole_from_ruling_the_upper_side() -> None:
    """Turbid water: 1/λ_att = 0.10/m fixed, the phase refits move 1/λ_sca linearly over the prior
    (0.045-0.088/m), so 1/λ_abs moves linearly the other way (0.012-0.055/m) and λ_abs runs from 18
    to 83 m around 30 m. On λ itself the few refits near the pole rule the upper side; on the
    coefficient the interval's ends are where a uniform spread of the coefficient puts them."""
    g = np.linspace(0.88, 0.96, 9)
    a0, slope = 1 / 30.0, 0.0215 / 0.04  # 1/λ_abs at the nominal, and per unit of ⟨cos θ⟩
    a = a0 - slope * (g - 0.92)
    lam = 1 / a
    d = np.stack([lam - 30.0, 0 * g, 0 * g, 0 * g], axis=1)
    linear = marginal_posterior([g], d, 1.0)
    m = marginal_posterior([g], d, 1.0, coefficient_at=(30.0, None, None))
    # On the coefficient each side is a uniform half: RMS = half-width/√3, mapped back through 1/a.
    rms_a = 0.0215 / math.sqrt(3)
    assert m.up_m[0] == pytest.approx(1 / (a0 - rms_a) - 30.0, rel=0.02)
    assert m.down_m[0] == pytest.approx(30.0 - 1 / (a0 + rms_a), rel=0.02)
    # What the coefficient's RMS says, the length's own RMS overstates upward (the pole) and not below.
    assert linear.up_m[0] > 1.3 * m.up_m[0] and m.down_m[0] == pytest.approx(linear.down_m[0], rel=0.15)
    # The other lengths, and what is not a side, are as before.
    assert m.rms_m[0] == pytest.approx(linear.rms_m[0]) and m.up_m[1] == linear.up_m[1]
    # A refit at the prior's end that ran to the λ range's end (2000 m): on λ it alone sets the upper
    # side (hundreds of metres); on the coefficient it is one more point near 1/λ = 0.
    d[0, 0] = 2000.0 - 30.0
    runaway = marginal_posterior([g], d, 1.0, coefficient_at=(30.0, None, None))
    assert marginal_posterior([g], d, 1.0).up_m[0] > 200.0
    assert m.up_m[0] < runaway.up_m[0] < 1 / (a0 - a0 / math.sqrt(3)) - 30.0


def test_marginal_posterior_over_two_parameters_moves_them_together() -> None:
    """The data fix one combination of ⟨cos θ⟩ and the Rayleigh share: each alone would mislead."""
    g, r = np.meshgrid(np.array(G) - 0.93, np.array(R) - 0.17, indexing="xy")  # shape (r, g)
    # λ_abs shifts with both; the data pin (g, r) at (0.90, 0.22) with widths 0.004 and 0.02.
    d_abs = 300 * g - 40 * r
    dchi2 = ((g + 0.03) / 0.004) ** 2 + ((r - 0.05) / 0.02) ** 2
    dchi2 -= dchi2[1, 3]  # the reference's Δχ² is zero
    d = np.stack([d_abs, 0.5 * d_abs, 0.1 * d_abs, dchi2], axis=-1)
    m = marginal_posterior([R, G], d, 1.0)
    assert m.mean == pytest.approx((0.22, 0.90), abs=3e-3)
    assert m.shift_m[0] == pytest.approx(300 * -0.03 - 40 * 0.05, rel=0.05)
    # The spread: both parameters' widths through their slopes (linear model, independent).
    assert m.spread_m[0] == pytest.approx(math.hypot(300 * 0.004, 40 * 0.02), rel=0.15)
    # With Δχ² depending on ⟨cos θ⟩ alone the Rayleigh axis is the prior's: it adds 40 m × its width.
    flat_r = ((g + 0.03) / 0.004) ** 2 - (0.03 / 0.004) ** 2
    m2 = marginal_posterior([R, G], np.stack([d_abs, d_abs, d_abs, flat_r], axis=-1), 1.0)
    r_sd = 0.15 / math.sqrt(12)
    assert m2.sd[0] == pytest.approx(r_sd, rel=0.02)
    assert m2.spread_m[0] == pytest.approx(math.hypot(300 * 0.004, 40 * r_sd), rel=0.15)


def test_variations_need_templates_only_near_the_fitted_scattering_lengths() -> None:
    nodes = (12.0, 20.0, 33.0, 55.0, 90.0, 150.0, 250.0)
    assert nodes_around(nodes, [40.0]) == (20.0, 33.0, 55.0, 90.0)
    assert nodes_around(nodes, [10.0, 300.0]) == (12.0, 20.0, 150.0, 250.0)
    from tests.analysis.transport_cases import grid_settings

    base = grid_settings(CASES["turbid"])
    v = variation_settings(base, [25.0], SystematicsConfig())
    assert set(v) == {
        "phase:rayleigh=0.1",
        "phase:rayleigh=0.17",
        "phase:rayleigh=0.25",
        "emission=hemispheres",
        "sample=1",
        "sample=2",
        "sample=3",
    }
    # The template samples: the nominal's nodes around the fitted length, other seeds, same photons.
    seeds = {v[f"sample={i}"].seed for i in (1, 2, 3)} | {base.seed}
    assert len(seeds) == 4 and v["sample=1"].n_photons == base.n_photons
    assert v["sample=1"].lambda_sca_nodes_m == v["emission=hemispheres"].lambda_sca_nodes_m
    phase = v["phase:rayleigh=0.1"]
    assert phase.mie_g_nodes == (0.88, 0.9, 0.92, 0.93, 0.94, 0.96)
    assert phase.rayleigh_fraction == 0.1 and v["phase:rayleigh=0.25"].rayleigh_fraction == 0.25
    assert phase.n_photons == 4 * base.n_photons  # the data tell ⟨cos θ⟩ by shapes finer than the fit's MC
    # A refit at ⟨cos θ⟩ 0.96 moves λ_sca 25 m to 25·0.07/0.04 = 44 m, at 0.88 to 15 m: nodes cover both.
    nodes = phase.lambda_sca_nodes_m
    assert nodes[0] <= 15.0 / 1.15 and nodes[-1] >= 44.0 * 1.15
    assert v["emission=hemispheres"].emission_shape == "hemispheres"
    # The emission variant shares the nominal's seed and nodes (correlated Monte Carlo), and only it
    # describes itself differently from a nominal cache entry.
    assert v["emission=hemispheres"].seed == base.seed
    assert "emission_shape" not in base.geometry_description()
    assert v["emission=hemispheres"].geometry_description()["emission_shape"] == "hemispheres"


def test_nodes_covering_extends_the_list_geometrically() -> None:
    assert nodes_covering((12.0, 20.0), 14.0, 18.0) == (12.0, 20.0)
    assert nodes_covering((12.0, 20.0), 13.0, 45.0) == (12.0, 20.0, 33.333, 55.555)
    assert nodes_covering((20.0, 33.0, 55.0, 90.0), 25.0, 40.0) == (20.0, 33.0, 55.0)
    assert nodes_covering((20.0,), 10.0, 20.0) == (7.346, 12.121, 20.0)


def test_emission_shapes_agree_at_the_poles_and_the_equator() -> None:
    mu = np.array([-1.0, 0.0, 1.0, 0.5])
    lin = emission_shares(mu, "linear")
    hemi = emission_shares(mu, "hemispheres")
    assert np.allclose(lin[0][:3], hemi[0][:3]) and np.allclose(lin[0] + lin[1], 1.0)
    assert np.allclose(hemi[0] + hemi[1], 1.0)
    assert hemi[0][3] > lin[0][3]  # flatter near the pole: more of the near side's light at μ = 0.5
    with pytest.raises(ValueError, match="emission shape"):
        emission_shares(mu, "conical")


def test_a_disagreement_beyond_three_sigma_is_flagged_with_what_to_do() -> None:
    far_off = AttenuationCheck(47.5, 1.0, 28.6, 1.0, 13.4)
    assert far_off.flagged and not far_off.agrees
    assert far_off.advice is not None and "do not quote" in far_off.advice and "I0'/I0" in far_off.advice
    near = AttenuationCheck(30.0, 1.0, 28.0, 0.8, 2.5)
    assert not near.flagged and not near.agrees and near.advice is None
    assert AttenuationCheck(30.0, 1.0, None, None, None).flagged is False


def test_a_calibration_pulled_beyond_three_sigma_is_flagged_worst_first(
    grids: dict[str, TemplateGrid], profiles: dict[str, list]
) -> None:
    """The independent station (tests/utils/indepset.py) fitted: I0'/I0 pulled to half its lab value
    (-17σ) while the λ_att check "agreed" (+1.9σ, the fit's λ_att ±12 m of systematics)."""
    fit = fit_wavelength(WAVELENGTH_NM, profiles["clear"], grids["clear"], GEOMETRY, EMISSION_RATIO, QUICK)
    assert fit.strained_nuisances == ()  # the frames follow the model: nothing pulled beyond 3σ
    ratio = Nuisance("emission_ratio", "rel", -0.50291, 0.02885)
    near = Nuisance("distance_near", "m", 0.0676, 0.02)
    far = Nuisance("distance_far", "m", -0.119, 0.04)  # 2.98σ: within
    pulled = replace(fit, nuisances=(far, near, ratio))
    assert pulled.strained_nuisances == (ratio, near)
    chk = AttenuationCheck(39.9, 12.0, 16.8, 0.6, 1.9, pulled.strained_nuisances)
    assert chk.agrees and not chk.flagged and chk.nuisances_flagged
    advice = chk.nuisance_advice or ""
    assert advice.startswith("the fit moved I0'/I0 by -50.3 % (-17.4σ of its ±2.9 %); the near camera's"), (
        advice
    )
    assert "+0.0676 m (+3.4σ of its ±0.02 m)" in advice and "do not quote" in advice
    assert AttenuationCheck(30.0, 1.0, 28.0, 0.8, 2.5).nuisance_advice is None


def test_a_calibration_a_data_allowed_phase_function_relieves_is_not_flagged() -> None:
    """Turbid water, the truth's ⟨cos θ⟩ drawn over the prior (bench study 2): the nominal fit moved
    I0'/I0 by 4.1σ, a refit at ⟨cos θ⟩ 0.95 (Δχ² −0.4) keeps every calibration within 1.2σ."""
    ratio = Nuisance("emission_ratio", "rel", 0.1304, 0.0315)
    relieved = AttenuationCheck(10.4, 0.9, 10.2, 0.3, 0.2, (ratio,), ("0.95/0.17", -0.4, 1.2))
    assert not relieved.nuisances_flagged
    advice = relieved.nuisance_advice or ""
    assert advice.startswith("at the nominal phase function the fit moved I0'/I0 by +13.0 % (+4.1σ"), advice
    assert "⟨cos θ⟩ 0.95, Rayleigh share 0.17 (the data allow it: Δχ² -0.4)" in advice
    assert "within 1.2σ" in advice and "Not flagged" in advice and "do not quote" not in advice
    assert AttenuationCheck(10.4, 0.9, 10.2, 0.3, 0.2, (ratio,)).nuisances_flagged


def test_the_values_quoted_are_the_mean_over_the_template_samples() -> None:
    """Three sample refits moved λ_abs by +4, +2, +6 m: the value moves to the mean over the four
    samples (+3 m) and the line's error is that mean's; a length the fit only bounds (no shifts)
    stays where it was."""
    d = np.array([[4.0, 0.5, np.nan], [2.0, -0.5, np.nan], [6.0, 0.3, np.nan]])
    err, move = template_sample_mean(d)
    one = math.sqrt((16 + 4 + 36) / 3 / 2)
    assert move[0] == pytest.approx(12.0 / 4) and move[1] == pytest.approx(0.3 / 4)
    assert err[0] == pytest.approx(one / 2)
    assert np.isnan(move[2]) and np.isnan(err[2])
    # a refit on the templates' edge only bounds its shift: nothing moves, one sample's error
    err, move = template_sample_mean(d, average=False)
    assert np.isnan(move).all() and err[0] == pytest.approx(one)
    measured = Estimate("λ_abs", MEASURED, 30.0, 2.0, (28.0, 32.5))
    assert measured.moved(3.0) == Estimate("λ_abs", MEASURED, 33.0, 2.0, (31.0, 35.5))
    bound = Estimate("λ_abs", LOWER_LIMIT, None, None, None, limit_m=180.0, cl=0.95)
    assert bound.moved(3.0) is bound
