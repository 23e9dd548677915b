"""Reading a phase map: measured, bounded or degenerate; the lengths' envelope; χ² per band.

Synthetic maps with a known shape (a bowl, a valley the data cannot resolve,
a slope toward the range's end) test what `phase_estimates` concludes from
them; synthetic profiles test `analysis.chisq.quality`. The fit that makes
real maps is tested on frames in `test_phase_fit.py`.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from analysis.chisq.phase import phase_estimates
from analysis.chisq.phase_results import (
    PHASE_DEGENERATE,
    PHASE_LIMIT,
    PHASE_MEASURED,
    PhaseConfig,
    PhaseMap,
)
from analysis.chisq.quality import CHI2_NDOF_FAIL, assess, band_chi2
from analysis.chisq.results import LOWER_LIMIT, MEASURED, UNCONSTRAINED, SettingModel

G = np.linspace(0.84, 0.98, 8)
F = np.linspace(0.0, 0.40, 5)
CFG = PhaseConfig(model_dchi2=0.0)  # the reading itself; the templates' tolerance is tested apart


def _map(chi2_of, ln_sca_of) -> PhaseMap:
    gg, ff = np.meshgrid(G, F)
    chi2 = chi2_of(gg, ff) + 900.0
    ln_abs = np.full_like(gg, math.log(40.0))
    return PhaseMap(G, F, chi2, np.stack([ln_abs, ln_sca_of(gg, ff)]))


def valley_sca(gg: np.ndarray, ff: np.ndarray) -> np.ndarray:
    """λ_sca along the halo's valley: λ_sca(1 - ⟨cos θ⟩) constant at 50 m for 0.93 / 0.17."""
    mean = (1 - ff) * gg
    return np.log(50.0 * (1 - 0.93 * 0.83) / (1 - mean))


def test_a_bowl_is_a_measurement_with_its_curvature_as_the_error() -> None:
    sg, sf = 0.005, 0.04  # Δχ² = 1 at these distances from (0.93, 0.17)
    pmap = _map(lambda g, f: ((g - 0.93) / sg) ** 2 + ((f - 0.17) / sf) ** 2, valley_sca)
    fit, _ = phase_estimates(pmap, 1.0, (0.005, 0.01), CFG)
    assert fit.case == PHASE_MEASURED
    assert fit.mie_g.status == MEASURED and fit.rayleigh_share.status == MEASURED
    assert fit.mie_g.value == pytest.approx(0.93, abs=0.002)
    assert fit.mie_g.err == pytest.approx(sg, rel=0.25)
    assert fit.rayleigh_share.value == pytest.approx(0.17, abs=0.01)
    assert fit.rayleigh_share.err == pytest.approx(sf, rel=0.25)
    assert fit.mean_cos_theta.value == pytest.approx(0.93 * 0.83, abs=0.003)
    # λ_sca's envelope: the valley moves it with the phase function within the 68 % region.
    lo, hi = fit.lambda_envelope_m[1]  # type: ignore[misc]
    assert lo < 50.0 < hi
    # λ_sca follows the mean cosine: up with ⟨cos θ⟩, down with the Rayleigh share (here the wider).
    assert fit.corr_lambda_sca[0] > 0.05 and fit.corr_lambda_sca[1] < -0.9


def test_an_error_scale_widens_the_intervals() -> None:
    pmap = _map(lambda g, f: ((g - 0.93) / 0.005) ** 2 + ((f - 0.17) / 0.04) ** 2, valley_sca)
    one, _ = phase_estimates(pmap, 1.0, (0.005, 0.01), CFG)
    two, _ = phase_estimates(pmap, 2.0, (0.005, 0.01), CFG)
    assert two.mie_g.err == pytest.approx(2.0 * one.mie_g.err, rel=0.2)  # type: ignore[operator]


def test_a_flat_valley_is_degenerate_and_the_length_spans_the_range() -> None:
    pmap = _map(lambda g, f: 0.05 * (g - 0.9) + 0.0 * f, valley_sca)
    fit, _ = phase_estimates(pmap, 1.0, (0.005, 0.01), CFG)
    assert fit.case == PHASE_DEGENERATE
    assert fit.mie_g.status == UNCONSTRAINED and fit.mie_g.value is None
    lo, hi = fit.lambda_envelope_m[1]  # type: ignore[misc]
    truth_range = np.exp(valley_sca(*np.meshgrid(G, F)))
    assert lo <= truth_range.min() * 1.001 and hi >= truth_range.max() * 0.999
    assert "does not tell" in fit.case_text


def test_a_slope_toward_the_range_end_is_a_limit() -> None:
    # χ² falls toward a large ⟨cos θ⟩: only a lower limit.
    pmap = _map(lambda g, f: 400.0 * (0.98 - g) ** 2 / 0.01 + ((f - 0.17) / 0.04) ** 2, valley_sca)
    fit, _ = phase_estimates(pmap, 1.0, (0.005, 0.01), CFG)
    assert fit.case == PHASE_LIMIT
    assert fit.mie_g.status == LOWER_LIMIT
    assert fit.mie_g.limit is not None and 0.9 < fit.mie_g.limit < 0.98
    assert "> " in fit.case_text


def _setting(resid_sigma: np.ndarray, n: int = 120) -> SettingModel:
    r = np.arange(n) + 0.5
    model = np.ones((2, n))
    err = np.full((2, n), 0.01)
    data = model + resid_sigma * err
    return SettingModel(0.05, 10.0, r, data, err, model, np.zeros((2, n)), np.ones((2, n), dtype=bool))


def test_chi2_per_band_finds_a_misfit_concentrated_at_the_edge() -> None:
    rng = np.random.default_rng(4)
    res = rng.normal(size=(2, 120))
    res[0, 38:42] += 12.0  # the near disk's edge (radius 40 px) missed
    bands = band_chi2([_setting(res)], (40.0, 20.0))
    edge = [b for b in bands if b.camera == "near" and b.r_lo_disk in (0.9, 1.0)]
    assert sum(b.chi2 for b in edge) > 400
    q = assess(sum(b.chi2 for b in bands), sum(b.n_bins for b in bands) - 3, bands)
    assert q.concentrated and not q.ok
    assert "near camera's bands at 1-1.1 disk radii" in q.reason


def test_an_even_misfit_fails_on_chi2_alone_and_a_good_fit_passes() -> None:
    rng = np.random.default_rng(5)
    even = rng.normal(size=(2, 120)) * 1.6
    bands = band_chi2([_setting(even)], (40.0, 20.0))
    chi2 = sum(b.chi2 for b in bands)
    q = assess(chi2, 237, bands)
    assert chi2 / 237 > CHI2_NDOF_FAIL and q.failed and not q.concentrated
    good = band_chi2([_setting(rng.normal(size=(2, 120)))], (40.0, 20.0))
    assert assess(sum(b.chi2 for b in good), 237, good).ok


def test_wavelengths_that_share_the_mie_cosine_narrow_it_together() -> None:
    """Three wavelengths each bounding ⟨cos θ⟩ loosely around 0.93 (and one of them skewed): the
    combined maps measure it, each wavelength keeps its own Rayleigh share, and the text says so."""
    from analysis.chisq.phase import combine_maps

    def loose(centre: float, share: float) -> PhaseMap:
        return _map(lambda g, f: ((g - centre) / 0.03) ** 2 + ((f - share) / 0.05) ** 2, valley_sca)

    maps = {405: loose(0.92, 0.25), 460: loose(0.935, 0.17), 525: loose(0.94, 0.10)}
    alone = {wl: phase_estimates(m, 1.0, (0.005, 0.01), CFG)[0] for wl, m in maps.items()}
    joint = {wl: phase_estimates(m, 1.0, (0.005, 0.01), CFG)[0] for wl, m in combine_maps(maps).items()}
    for wl in maps:
        assert joint[wl].mie_g.err < 0.7 * alone[wl].mie_g.err  # type: ignore[operator]
        assert joint[wl].mie_g.value == pytest.approx(0.932, abs=0.004)
        assert joint[wl].rayleigh_share.value == pytest.approx(alone[wl].rayleigh_share.value, abs=0.01)
        assert "shared with" in joint[wl].case_text
    # The sum of three parabolas of width 0.03: width 0.03/√3.
    assert joint[460].mie_g.err == pytest.approx(0.03 / math.sqrt(3), rel=0.25)


def test_the_templates_tolerance_widens_what_the_map_allows_but_keeps_its_best_point() -> None:
    """A bowl 60 deep at the range's ends: read as the data say, a measurement; with the templates'
    tolerance (Δχ²/s² 20 by default) a wider interval around the same best point, and the lengths'
    envelope wider too (every phase function within the tolerance is allowed)."""
    pmap = _map(lambda gg, ff: 60.0 * ((gg - 0.91) / 0.07) ** 2 + 40.0 * ((ff - 0.2) / 0.2) ** 2, valley_sca)
    tight, _ = phase_estimates(pmap, 1.0, (0.01, 0.01), CFG)
    wide, _ = phase_estimates(pmap, 1.0, (0.01, 0.01), PhaseConfig())
    assert PhaseConfig().model_dchi2 == 20.0
    assert tight.best == pytest.approx(wide.best, abs=1e-3)
    assert tight.mie_g.status == MEASURED and wide.mie_g.status == MEASURED
    assert wide.mie_g.err > 3 * tight.mie_g.err
    (t_lo, t_hi), (w_lo, w_hi) = tight.lambda_envelope_m[1], wide.lambda_envelope_m[1]
    assert w_lo < t_lo and w_hi > t_hi
    assert "templates' accuracy" in wide.case_text and "templates' accuracy" not in tight.case_text
    with pytest.raises(ValueError, match="model_dchi2"):
        PhaseConfig(model_dchi2=-1.0)
