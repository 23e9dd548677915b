"""λ_att of one LEM visit: stamp, interpolation of non-simultaneous frames, honest errors.

Synthetic I_center values with known truth and Gaussian noise (no
simulator, no images): the pure arithmetic of `analysis.visit`.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from analysis import EmissionRatio, Geometry
from analysis.visit import (
    CameraLevel,
    TrendPrior,
    VisitFrame,
    camera_level,
    camera_trend,
    trend_prior,
    visit_attenuation,
)

GEOMETRY = Geometry("A", "B", 21.56, 0.02, 41.62, 0.04)
RATIO = EmissionRatio(1.27, 0.04)
SETTINGS = ((0.05, 8.0), (0.07, 8.0), (0.11, 8.0))


def frames(
    rng: np.random.Generator,
    *,
    lam_at: callable,
    near_times: np.ndarray,
    far_times: np.ndarray,
    rel_noise: float = 0.003,
    depth_m: float = 3420.0,
) -> list[VisitFrame]:
    """Frames of both cameras whose I follow exp(-L / λ(t)) with the LEM's emission ratio."""
    out = []
    for cam, times, dist, emit in (("A", near_times, 21.56, 1.0), ("B", far_times, 41.62, RATIO.value)):
        for i, t in enumerate(times):
            e, g = SETTINGS[i % len(SETTINGS)]
            true = 4e5 * emit * e * 10 ** (g / 20) * math.exp(-dist / lam_at(t)) / 100
            i_gray = true * (1 + rel_noise * rng.standard_normal())
            out.append(VisitFrame(cam, e, g, float(t), i_gray, rel_noise * true, depth_m - dist))
    return out


def test_a_steady_visit_gives_the_truth_stamped_at_its_frames_mean_time_and_depth() -> None:
    rng = np.random.default_rng(1)
    near, far = np.arange(0.0, 12.0, 1.0), np.arange(0.45, 12.45, 1.0)
    fr = frames(rng, lam_at=lambda t: 28.0, near_times=near, far_times=far)
    res = visit_attenuation(fr, 460, GEOMETRY, RATIO, repeatability=0.0, trend_prior_per_s=0.002)
    assert res is not None and res.n_pairs == 3 and res.n_frames == 24
    assert res.t_s == pytest.approx(np.mean(np.concatenate([near, far])))
    assert res.lem_depth_m == pytest.approx(np.mean([f.lem_depth_m for f in fr]))
    assert res.lambda_att_m == pytest.approx(28.0, abs=3 * res.stat_err_m)
    # Systematic error: the distances and I0'/I0 only, kept apart from the statistical one.
    x = (41.62 - 21.56) / res.lambda_att_m
    sys = math.hypot(math.hypot(0.02, 0.04) / x, res.lambda_att_m**2 / 20.06 * 0.04 / 1.27)
    assert res.sys_err_m == pytest.approx(sys, rel=1e-9)


def test_settings_only_one_camera_took_are_left_out() -> None:
    rng = np.random.default_rng(2)
    fr = frames(rng, lam_at=lambda t: 20.0, near_times=np.arange(6.0), far_times=np.arange(6.0) + 0.4)
    extra = VisitFrame("A", 0.5, 2.0, 100.0, 50.0, 0.1, 3400.0)
    res = visit_attenuation([*fr, extra], 405, GEOMETRY, RATIO, repeatability=0.0, trend_prior_per_s=0.002)
    assert res is not None and res.n_frames == 12 and res.t_last_s < 100.0
    assert (
        visit_attenuation([extra], 405, GEOMETRY, RATIO, repeatability=0.0, trend_prior_per_s=0.002) is None
    )


def test_far_frames_taken_later_than_near_ones_are_interpolated_to_the_stamp() -> None:
    """The water clears by 3 %/min; the far camera shoots 30 s after the near one.

    Without interpolation the ratio mixes two waters (λ ~2 % off at this
    rate); each camera's trend over the visit brings both to the mean time.
    """
    rng = np.random.default_rng(3)

    def lam(t: float) -> float:
        return 25.0 * (1 + 0.03 * t / 60)

    near = np.arange(0.0, 12.0, 1.0)
    far = near + 30.0
    fr = frames(rng, lam_at=lam, near_times=near, far_times=far, rel_noise=0.001)
    res = visit_attenuation(fr, 460, GEOMETRY, RATIO, repeatability=0.0, trend_prior_per_s=0.002)
    truth = lam(res.t_s)
    assert all(t.fitted for t in res.trends.values())
    assert res.lambda_att_m == pytest.approx(truth, abs=2.5 * res.stat_err_m)
    # What ignoring the mismatch would give: far off, many errors away.
    naive = GEOMETRY.baseline_m / (res.log_ratio + sum(p.trend_shift for p in res.pairs) / 3 + math.log(1.27))
    assert abs(naive - truth) > 5 * res.stat_err_m


def test_a_mismatch_the_frames_cannot_resolve_is_carried_in_the_error() -> None:
    """Three frames per camera, 20 s apart: no trend can be fitted; the prior bounds the drift."""
    rng = np.random.default_rng(4)
    fr = frames(
        rng,
        lam_at=lambda t: 25.0,
        near_times=np.array([0.0, 1.0, 2.0]),
        far_times=np.array([20.0, 21.0, 22.0]),
    )
    res = visit_attenuation(fr, 460, GEOMETRY, RATIO, repeatability=0.0, trend_prior_per_s=0.002)
    assert not any(t.fitted for t in res.trends.values())
    assert res.terms["trend"] == pytest.approx(0.002 * math.hypot(10.0, 10.0), rel=0.01)
    assert res.terms["trend"] > 5 * res.terms["frames"]


def test_the_floor_is_added_once_per_visit_whatever_the_number_of_frames() -> None:
    rng = np.random.default_rng(5)
    args = dict(lam_at=lambda t: 25.0, rel_noise=0.0005)
    few = frames(rng, near_times=np.arange(3.0), far_times=np.arange(3.0) + 0.5, **args)
    many = frames(rng, near_times=np.arange(60.0), far_times=np.arange(60.0) + 0.5, **args)
    for fr in (few, many):
        res = visit_attenuation(fr, 460, GEOMETRY, RATIO, repeatability=0.004, trend_prior_per_s=0.002)
        assert res.terms["floor"] == pytest.approx(math.sqrt(2) * 0.004)
        assert res.log_ratio_err >= res.terms["floor"]


@pytest.mark.parametrize("noise", [0.002, 0.01])
def test_pulls_of_many_visits_have_an_rms_near_one(noise: float) -> None:
    """Gaussian frame noise, water changing between and within visits: the errors mean what they say."""
    rng = np.random.default_rng(6)
    pulls = []
    for k in range(400):
        base = 20.0 + 8.0 * math.sin(k / 40)

        def lam(t: float, base: float = base) -> float:
            return base * (1 - 0.003 * t / 60)

        n = int(rng.integers(3, 13))
        near = np.sort(rng.uniform(0, 15, n))
        far = np.sort(rng.uniform(0, 15, n)) + rng.uniform(-5, 5)
        fr = frames(rng, lam_at=lam, near_times=near, far_times=far, rel_noise=noise)
        res = visit_attenuation(fr, 460, GEOMETRY, RATIO, repeatability=0.0, trend_prior_per_s=0.002)
        if res is None:
            continue
        pulls.append((res.lambda_att_m - lam(res.t_s)) / res.stat_err_m)
    rms = math.sqrt(np.mean(np.square(pulls)))
    assert len(pulls) > 300
    assert 0.85 < rms < 1.15, rms


def test_the_trend_fit_recovers_a_slope_and_leans_on_the_prior_without_frames() -> None:
    t = np.arange(12.0)
    exp = np.array([0.05, 0.07, 0.11] * 4)
    i = 100 * exp / 0.05 * np.exp(-0.004 * t)
    fit = camera_trend(t, i, 0.001 * i, exp, np.full(12, 8.0), prior_per_s=0.01)
    assert fit.fitted and fit.slope_per_s == pytest.approx(-0.004, abs=3 * fit.slope_err_per_s)
    lone = camera_trend(t[:2], i[:2], 0.001 * i[:2], exp[:2], np.full(2, 8.0), prior_per_s=0.01)
    assert not lone.fitted and lone.slope_per_s == 0.0 and lone.slope_err_per_s == 0.01


def test_no_attenuation_is_said_instead_of_a_value() -> None:
    fr = [VisitFrame("A", 0.05, 8.0, 0.0, 10.0, 0.1), VisitFrame("B", 0.05, 8.0, 0.5, 30.0, 0.1)]
    res = visit_attenuation(fr, 460, GEOMETRY, RATIO, repeatability=0.0, trend_prior_per_s=0.002)
    assert res.lambda_att_m is None and res.stat_err_m is None and "not dimmer" in res.note


def test_a_water_changing_during_a_long_visit_does_not_pass_for_noise() -> None:
    """λ falling 3 %/min during 90 s visits, each camera cycling its settings frame by frame: a
    setting's frames lie along the trend, and their spread is the water's, not the noise's.

    Before each stack's frames were brought to its mean time along the camera's trend, that
    spread counted as frame noise: errors 2-4 times too large here (pull RMS ~0.3).
    """
    rng = np.random.default_rng(11)
    pulls = []
    for k in range(150):
        base = 20.0 + 8.0 * math.sin(k / 20)

        def lam(t: float, base: float = base) -> float:
            return base * (1 - 0.03 * t / 60)

        near = np.arange(0.0, 90.0, 2.0)
        far = near + 0.7
        fr = frames(rng, lam_at=lam, near_times=near, far_times=far, rel_noise=0.005)
        res = visit_attenuation(fr, 460, GEOMETRY, RATIO, repeatability=0.0, trend_prior_per_s=0.002)
        assert res is not None and res.lambda_att_m is not None and res.stat_err_m is not None
        # the truth of a visit: λ of its mean log ratio (the water is not linear in q over 90 s)
        ts = np.linspace(res.t_first_s, res.t_last_s, 400)
        q_true = np.mean([GEOMETRY.baseline_m / lam(t) for t in ts])
        pulls.append((res.lambda_att_m - GEOMETRY.baseline_m / q_true) / res.stat_err_m)
    rms = math.sqrt(np.mean(np.square(pulls)))
    assert 0.85 < rms < 1.15, rms


def test_a_visit_too_short_for_a_trend_takes_it_from_the_wavelengths_previous_visits() -> None:
    """A lagging module: three frames per camera a visit, the far camera 20 s after the near one,
    so neither can fit a trend; the water's λ falls by 30 % and comes back over 90 minutes.

    With the fixed prior (0.002/s) the mismatch is carried whole in the error: errors several
    times the deviations (pull RMS ~0.2). With each camera's levels in the wavelength's two
    previous visits (every 180 s) the visit is brought to its time along the water's own trend:
    the pulls have an RMS near one (0.89-0.99 over four seeds), and the errors are a tenth of the
    fixed prior's.
    """
    rng = np.random.default_rng(5)
    period_s = 5400.0
    pulls = {"fixed": [], "visits": []}
    errors = {"fixed": [], "visits": []}
    for start in rng.uniform(0, period_s, 12):

        def lam(t: float, start: float = start) -> float:
            return 20.0 * (1 - 0.3 * math.sin(math.pi * (t + start) / period_s) ** 2)

        history: dict[str, list] = {"A": [], "B": []}
        for k in range(30):
            t0 = 180.0 * k
            near = t0 + np.array([0.0, 10.0, 20.0])
            fr = frames(rng, lam_at=lam, near_times=near, far_times=near + 20.0, rel_noise=0.003)
            priors = {}
            for cam in ("A", "B"):
                history[cam].append(camera_level(fr, cam))
                priors[cam] = trend_prior(history[cam][-3:], 0.0, 0.002)
            for how, given in (("fixed", None), ("visits", priors)):
                res = visit_attenuation(
                    fr, 460, GEOMETRY, RATIO, repeatability=0.0, trend_prior_per_s=0.002, trend_priors=given
                )
                assert res is not None and res.lambda_att_m is not None
                if k < 2:
                    assert all(t.prior == "default" for t in res.trends.values())
                    continue
                assert not any(t.fitted for t in res.trends.values())
                assert {t.prior for t in res.trends.values()} == {"default" if given is None else "visits"}
                ts = np.linspace(res.t_first_s, res.t_last_s, 200)
                q_true = np.mean([GEOMETRY.baseline_m / lam(t) for t in ts])
                pulls[how].append((res.lambda_att_m - GEOMETRY.baseline_m / q_true) / res.stat_err_m)
                errors[how].append(res.stat_err_m / res.lambda_att_m)
    rms = {how: math.sqrt(np.mean(np.square(p))) for how, p in pulls.items()}
    assert len(pulls["visits"]) == 12 * 28
    assert rms["fixed"] < 0.5, rms
    assert 0.85 < rms["visits"] < 1.15, rms
    assert np.mean(errors["visits"]) < 0.2 * np.mean(errors["fixed"]), errors


def test_the_trend_prior_of_three_levels_is_the_last_slope_widened_by_its_change() -> None:
    def level(t: float, y: float, err: float = 0.001) -> CameraLevel:
        return CameraLevel(t, y, err, 6)

    straight = trend_prior([level(0, 1.0), level(180, 0.91), level(360, 0.82)], 0.0, 0.002)
    assert straight.source == "visits"
    assert straight.mean_per_s == pytest.approx(-0.0005)
    assert straight.width_per_s == pytest.approx(math.sqrt(2) * 0.001 / 180)  # the slope's own error
    bent = trend_prior([level(0, 1.0), level(180, 0.91), level(360, 0.73)], 0.0, 0.002)
    assert bent.mean_per_s == pytest.approx(-0.001)
    assert bent.width_per_s == pytest.approx(math.hypot(math.sqrt(2) * 0.001 / 180, 0.0005))
    floor = trend_prior([level(0, 1.0), level(180, 0.91), level(360, 0.82)], 0.002, 0.002)
    assert floor.width_per_s == pytest.approx(math.sqrt(2 * 0.001**2 + 2 * 0.002**2) / 180)
    for few in ([], [level(0, 1.0)], [level(0, 1.0), level(180, 0.91)]):
        assert trend_prior(few, 0.0, 0.002) == TrendPrior(0.0, 0.002, "default")


def test_a_cameras_level_normalises_its_settings_out() -> None:
    fr = [
        VisitFrame("A", e, 8.0, float(t), 2e4 * e, 2e4 * e * 0.01) for t, e in enumerate((0.05, 0.07, 0.11))
    ]
    fr.append(VisitFrame("B", 0.05, 8.0, 9.0, 50.0, 0.5))
    lv = camera_level(fr, "A")
    assert lv is not None and lv.n_frames == 3
    assert lv.log_i == pytest.approx(math.log(2e4 / 10 ** (8 / 20)))
    assert lv.t_s == pytest.approx(1.0) and lv.log_i_err == pytest.approx(0.01 / math.sqrt(3))
    assert camera_level(fr, "C") is None
