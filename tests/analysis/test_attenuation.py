"""The λ_att formula, its error propagation and the combination of pairs."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from analysis import EmissionRatio, Geometry, attenuation_length_m, combine_pairs, pair_result

TREX = Geometry("A", "B", 21.56, 0.02, 41.62, 0.04)


@given(
    lam=st.floats(3, 200),
    near=st.floats(1, 50),
    gap=st.floats(1, 80),
    ratio=st.floats(0.5, 2.0),
    i0=st.floats(10, 1e4),
)
def test_formula_inverts_the_exponential_model(lam, near, gap, ratio, i0) -> None:
    far = near + gap
    i_near = i0 * math.exp(-near / lam)
    i_far = i0 * ratio * math.exp(-far / lam)
    assert attenuation_length_m(i_near, i_far, near, far, ratio) == pytest.approx(lam, rel=1e-9)


@given(i_near=st.floats(1, 200), i_far=st.floats(1, 200), ratio=st.floats(0.5, 2.0))
def test_formula_refuses_what_has_no_attenuation(i_near, i_far, ratio) -> None:
    x = math.log(i_near / i_far * ratio)
    if x > 1e-9:
        assert attenuation_length_m(i_near, i_far, 21.56, 41.62, ratio) > 0
    elif x <= 0:
        with pytest.raises(ValueError, match="no attenuation"):
            attenuation_length_m(i_near, i_far, 21.56, 41.62, ratio)


def test_nonpositive_intensity_is_refused() -> None:
    with pytest.raises(ValueError, match="intensities"):
        attenuation_length_m(0.0, 10.0, 21.56, 41.62, 1.0)


def _numeric_derivative(f, x, h):
    return (f(x + h) - f(x - h)) / (2 * h)


def test_errors_match_numerical_propagation() -> None:
    i_n, i_f, ratio = 150.0, 90.0, EmissionRatio(1.27, 0.04)
    p = pair_result(460, 0.05, 8.0, (i_n, 0.5, 20), (i_f, 0.4, 20), TREX, ratio)

    def lam(i_near=i_n, i_far=i_f, r=1.27, ln=21.56, lf=41.62):
        return attenuation_length_m(i_near, i_far, ln, lf, r)

    stat = math.hypot(
        _numeric_derivative(lambda v: lam(i_near=v), i_n, 1e-3) * 0.5,
        _numeric_derivative(lambda v: lam(i_far=v), i_f, 1e-3) * 0.4,
    )
    sys = math.sqrt(
        (_numeric_derivative(lambda v: lam(r=v), 1.27, 1e-5) * 0.04) ** 2
        + (_numeric_derivative(lambda v: lam(ln=v), 21.56, 1e-4) * 0.02) ** 2
        + (_numeric_derivative(lambda v: lam(lf=v), 41.62, 1e-4) * 0.04) ** 2
    )
    assert p.lambda_att_m == pytest.approx(lam(), rel=1e-12)
    assert p.stat_err_m == pytest.approx(stat, rel=1e-3)
    assert p.sys_err_m == pytest.approx(sys, rel=1e-3)


def test_trex_like_systematic_error_is_about_a_metre() -> None:
    # λ ≈ 27 m at 460 nm: the 3 % error of I0'/I0 dominates, ~1.1-1.3 m (paper's scale).
    lam = 27.0
    i_near = 150.0
    i_far = i_near * 1.27 * math.exp(-(41.62 - 21.56) / lam)
    p = pair_result(460, 0.05, 8, (i_near, 0.3, 20), (i_far, 0.3, 20), TREX, EmissionRatio(1.27, 0.04))
    assert 0.9 < p.sys_err_m < 1.4


def test_combination_is_the_weighted_mean_of_log_ratios() -> None:
    ratio = EmissionRatio(1.0, 0.0)
    good = pair_result(460, 0.05, 8, (100.0, 0.1, 10), (50.0, 0.1, 10), TREX, ratio)
    poor = pair_result(460, 0.07, 8, (100.0, 5.0, 10), (40.0, 5.0, 10), TREX, ratio)
    res = combine_pairs([good, poor], TREX, ratio)
    assert res.n_pairs == 2
    # dominated by the precise pair
    assert abs(res.lambda_att_m - good.lambda_att_m) < abs(res.lambda_att_m - poor.lambda_att_m)
    w1, w2 = 1 / good.log_ratio_err**2, 1 / poor.log_ratio_err**2
    expected_q = (w1 * good.log_ratio + w2 * poor.log_ratio) / (w1 + w2)
    assert res.log_ratio == pytest.approx(expected_q)


def test_disagreeing_pairs_inflate_the_statistical_error() -> None:
    ratio = EmissionRatio(1.0, 0.0)
    a = pair_result(460, 0.05, 8, (100.0, 0.1, 10), (50.0, 0.1, 10), TREX, ratio)
    b = pair_result(460, 0.07, 8, (100.0, 0.1, 10), (40.0, 0.1, 10), TREX, ratio)
    res = combine_pairs([a, b], TREX, ratio)
    assert res.chi2_ndof > 10
    assert res.log_ratio_err == pytest.approx(
        math.sqrt(res.chi2_ndof) / math.sqrt(1 / a.log_ratio_err**2 + 1 / b.log_ratio_err**2)
    )


def test_geometry_and_ratio_validation() -> None:
    with pytest.raises(ValueError, match="near < far"):
        Geometry("A", "B", 41.0, 0.1, 21.0, 0.1)
    with pytest.raises(ValueError, match="emission ratio"):
        EmissionRatio(-1.0)


def test_a_ratio_that_outweighs_the_dimming_is_named_not_the_cameras() -> None:
    """The far camera 20 % dimmer and I0'/I0 typed 0.3: the note blamed the cameras ("the far camera
    is not dimmer than the near one"); it names the emission ratio."""
    from analysis.attenuation import EmissionRatio, not_dimmer_note

    note = not_dimmer_note(math.log(1.25), EmissionRatio(0.3, 0.01))
    assert note.startswith("I0'/I0 = 0.3 outweighs how much dimmer the far camera is"), note
    assert "not dimmer" in not_dimmer_note(-0.1, EmissionRatio(1.0, 0.01))
