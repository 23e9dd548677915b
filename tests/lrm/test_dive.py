"""The simulated dive: timeline, LEM colours, water column, motion, sensors, frames."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from analysis import locate_source
from camcal.core.frameset import TREX_FOCAL_PX
from lrm.dive import (
    DiveProfile,
    DiveSimulation,
    LEMTimetable,
    ModuleMotion,
    MotionParams,
    WaterColumn,
    tilt_from_acceleration_deg,
    tilt_series_deg,
)
from lrm.sim import FrameRenderer
from lrm.sim.scene import water_preset
from tests.utils.dive import LEANING, short_dive, short_profile

# -- the dive's timeline ---------------------------------------------------------------


def test_default_profile_follows_the_trex_dive() -> None:
    p = DiveProfile()
    expected = [
        (30, "deck", 0.0),
        (60 + 600, "descent", 600.0),
        (60 + 1200 + 60, "test-1200", 1200.0),
        (60 + 1200 + 120 + 400, "descent", 1600.0),
        (60 + 2021 + 120 + 60, "test-2021", 2021.0),
        (60 + 3420 + 240 + 900, "station", 3420.0),
        (60 + 3420 + 240 + 1800 + 420, "ascent", 3000.0),
        (p.duration_s + 10, "recovered", 0.0),
        (-5, "deck", 0.0),
    ]
    for t, phase, depth in expected:
        assert p.phase_at(t) == phase, t
        assert p.lem_depth_at(t) == pytest.approx(depth), t
    assert p.duration_s == pytest.approx(60 + 3420 + 240 + 1800 + 3420)
    assert p.window("station") == pytest.approx((3720.0, 5520.0))
    assert p.phases == ("deck", "descent", "test-1200", "test-2021", "station", "ascent", "recovered")


def test_cameras_run_at_the_stops_and_on_station_only() -> None:
    p = short_profile()
    enabled = {
        phase: p.captures_enabled(sum(p.window(phase)) / 2) for phase in p.phases if phase != "recovered"
    }
    assert enabled == {
        "deck": False,
        "descent": False,
        "test-1200": True,
        "test-2021": True,
        "station": True,
        "ascent": False,
    }
    assert not p.captures_enabled(p.duration_s + 1)


def test_moving_fraction_rises_while_the_cable_moves_and_fades_after() -> None:
    p = DiveProfile()
    t0, _ = p.window("station")
    m = p.moving_fraction(np.array([30.0, 1000.0, t0 + 30.0, t0 + 61.0]), smooth_s=60.0)
    assert_allclose(m, [0.0, 1.0, 0.5, 0.0], atol=1e-9)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"test_stops_m": (1200.0, 4000.0)}, "test_stops_m"),
        ({"test_stops_m": (2021.0, 1200.0)}, "test_stops_m"),
        ({"descent_m_per_s": 0.0}, "descent_m_per_s"),
        ({"station_s": -1.0}, "station_s"),
    ],
)
def test_bad_profiles_name_the_parameter(kwargs: dict[str, object], name: str) -> None:
    with pytest.raises(ValueError, match=name):
        DiveProfile(**kwargs)  # type: ignore[arg-type]


def test_modules_hang_above_the_lem() -> None:
    sim = short_dive()
    t = sum(sim.profile.window("station")) / 2
    assert sim.module_depth_m("A", t) == pytest.approx(3420 - 21.56, abs=0.5)  # heave moves it ~0.1 m
    assert sim.module_depth_m("B", t) == pytest.approx(3420 - 41.62, abs=0.5)
    assert sim.module_depth_m("B", 1.0) == 0.0  # on deck
    sample = sim.sensor_sample("B", t)
    assert sample.depth_m == pytest.approx(3420 - 41.62, abs=0.5)
    assert sample.pressure_dbar == pytest.approx(1.0104 * sample.depth_m, rel=1e-3)


# -- the LEM's colours -------------------------------------------------------------------


def test_timetable_cycles_the_three_wavelengths() -> None:
    tt = LEMTimetable(dwell_s=60.0, start_s=10.0)
    assert [tt.wavelength_at(t) for t in (10, 69.9, 70, 130, 190, 250)] == [405, 405, 460, 525, 405, 460]
    assert tt.wavelength_at(5.0) == 525  # the cycle extends before start_s
    assert tt.next_change_after(10.0) == 70.0
    assert tt.next_change_after(69.99) == 70.0
    assert tt.next_change_after(70.0) == 130.0
    assert tt.next_start_of(525, 0.0) == 130.0
    assert tt.next_start_of(405, 130.0) == 190.0
    assert tt.next_start_of(460, 70.0) == 70.0  # at or after
    assert tt.next_start_of(405, 10.0 + 180.0 * 1000) == pytest.approx(10.0 + 180.0 * 1000)
    assert tt.describe() == {"wavelengths_nm": [405, 460, 525], "dwell_s": 60.0, "start_s": 10.0}
    with pytest.raises(ValueError, match="wavelength_nm 600"):
        tt.next_start_of(600, 0.0)
    with pytest.raises(ValueError, match="dwell_s"):
        LEMTimetable(dwell_s=0.0)


# -- the water column --------------------------------------------------------------------


def test_water_clears_with_depth_and_converges_to_the_deep_preset() -> None:
    column = WaterColumn(drift_frac=0.0)
    trex = water_preset("trex").lambda_att_m()
    for wl in (405, 460, 525):
        shallow, mid, deep = (column.lambda_att_at(wl, z, 0.0) for z in (1200.0, 2021.0, 3400.0))
        assert shallow < mid < deep
        assert shallow < 0.95 * trex[wl]  # the 1200 m stop sees measurably murkier water
        assert deep == pytest.approx(trex[wl], rel=3e-3)


def test_water_drifts_a_few_percent_over_the_station() -> None:
    profile = DiveProfile()
    column = WaterColumn()  # the default drift is centred on the default dive's station
    t0, t1 = profile.window("station")
    for wl in (405, 460, 525):
        a, b = column.lambda_att_at(wl, 3400.0, t0), column.lambda_att_at(wl, 3400.0, t1)
        assert 0.02 < abs(b - a) / a < 0.06
    short = short_profile()
    s0, s1 = short.window("station")
    fitted = WaterColumn.with_station_drift(short, 0.04)
    assert fitted.drift_factor(s1) / fitted.drift_factor(s0) == pytest.approx(1.04, abs=2e-3)


def test_rendered_frames_use_the_column_truth() -> None:
    sim = short_dive()
    for phase in ("test-1200", "station"):
        t0, t1 = sim.profile.window(phase)
        t = t0 + 0.7 * (t1 - t0)
        for module in ("A", "B"):
            _, meta = sim.render(module, t, 0.05, 8.0)
            wl = sim.timetable.wavelength_at(t)
            truth = sim.lambda_att_truth_m(module, wl, t)
            assert meta["wavelength_nm"] == wl
            assert meta["phase"] == phase
            assert meta["lambda_att_column_m"] == pytest.approx(truth)
            assert meta["lambda_att_m"] == pytest.approx(truth, rel=2.5e-3)  # quantised renderer state
            # An independent renderer in the exact column water predicts the same centre gray.
            exact = FrameRenderer(sim.camera, sim.placement(module), sim.water_truth(module, t), sim.lem)
            assert meta["expected_center_gray"] == pytest.approx(
                exact.expected_center_gray(wl, 0.05, 8.0), rel=5e-3
            )
            assert meta["water_depth_m"] == pytest.approx(
                sim.profile.lem_depth_at(t) - sim.placement(module).distance_m / 2
            )
    # The murkier water at 1200 m makes the far camera's LEM dimmer than on station.
    t_stop, t_station = sim.profile.window("test-1200")[0] + 5, sim.profile.window("station")[0] + 5
    wl = sim.timetable.wavelength_at(t_stop)
    t_station = sim.timetable.next_start_of(wl, t_station) + 1
    _, stop = sim.render("B", t_stop, 0.05, 8.0)
    _, station = sim.render("B", t_station, 0.05, 8.0)
    assert float(stop["direct_center_gray"]) < 0.95 * float(station["direct_center_gray"])


def test_a_dive_needs_a_few_dozen_renderers_and_keeps_few() -> None:
    sim = DiveSimulation(frame_scale=0.25)
    states = {
        sim.water_state(module, float(t))
        for phase in ("test-1200", "test-2021", "station")
        for t in np.arange(*sim.profile.window(phase), 2.0)
        for module in ("A", "B")
    }
    assert 6 <= len(states) <= 36
    small = short_dive(renderer_cache_size=2)
    t0, t1 = small.profile.window("station")
    times = (t0, (t0 + t1) / 2, t1 - 1, t0 + 1)
    assert len({small.water_state("A", t) for t in times}) == 3
    for t in times:
        small.render("A", t, 0.02, 2.0)
    assert small.renderers_built == 4  # the first was dropped, then needed again
    assert len(small._renderers) == 2


# -- motion and sensors ------------------------------------------------------------------


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_heave_period_from_the_vertical_acceleration(seed: int) -> None:
    sim = short_dive(seed)
    assert 5.0 <= sim.heave_period_s <= 10.0
    t0, t1 = sim.profile.window("station")
    periods = []
    for module in ("A", "B"):
        s = sim.sensor_series(module, t0 + 60, t1)
        az = s["acc_m_s2"][:, 2] - s["acc_m_s2"][:, 2].mean()
        spectrum = np.abs(np.fft.rfft(az * np.hanning(az.size)))
        freq = np.fft.rfftfreq(az.size, 1.0 / sim.sensor_rate_hz)
        k = int(np.argmax(spectrum[1:])) + 1
        periods.append(1.0 / freq[k])
        resolution = 1.0 / freq[k] - 1.0 / freq[k + 1]
        assert 5.0 <= periods[-1] <= 10.0
        assert periods[-1] == pytest.approx(sim.heave_period_s, abs=resolution)
    assert periods[0] == periods[1]  # the ship's heave, shared along the cable


def test_heave_is_stronger_near_the_surface() -> None:
    sim = short_dive()
    motion = sim.motions["A"]
    t_deck, t_station = 2.0, sum(sim.profile.window("station")) / 2
    amp = motion.heave_amplitude_m_s2(np.array([t_deck, t_station]))
    assert amp[0] > 3 * amp[1]


def test_tilt_from_the_accelerometer_matches_the_attitude() -> None:
    sim = short_dive(4)
    t0, _ = sim.profile.window("station")
    s = sim.sensor_series("A", t0 + 100, t0 + 160)
    assert s["t_s"].size == 600  # 10 Hz
    truth = sim.motions["A"].angles_deg(s["t_s"])
    measured = tilt_series_deg(s["acc_m_s2"])
    noise_deg = math.degrees(sim.acc_noise_m_s2 / 9.81)
    residual = measured[:, :2] - truth[:, :2]
    assert_allclose(residual.std(axis=0), noise_deg, rtol=0.15)
    assert np.all(np.abs(residual.mean(axis=0)) < 4 * noise_deg / math.sqrt(s["t_s"].size) + 0.005)
    # One sample, through SensorSample.
    sample = sim.sensor_sample("A", t0 + 100.05)
    attitude = sim.attitude("A", (sample.t - sim.start).total_seconds())
    assert sample.tilt_deg == pytest.approx(attitude.tilt_deg, abs=5 * noise_deg)
    tx, ty, _ = tilt_from_acceleration_deg(sample.acc_m_s2)
    assert (tx, ty) == pytest.approx((attitude.tilt_x_deg, attitude.tilt_y_deg), abs=5 * noise_deg)


def test_tilt_stays_modest_and_tilt_scale_makes_a_module_lean() -> None:
    sim = short_dive(5, tilt_scale={"B": 4.0})
    t = np.linspace(*sim.profile.window("station"), 200)
    for module, lo, hi in (("A", 0.05, 1.2), ("B", 0.6, 4.8)):
        ang = np.radians(sim.motions[module].angles_deg(t))
        tilt = np.degrees(np.arctan(np.hypot(np.tan(ang[:, 0]), np.tan(ang[:, 1]))))
        assert lo < tilt.mean() < hi, module
    with pytest.raises(ValueError, match="tilt_scale"):
        short_dive(tilt_scale={"C": 2.0})


def test_gyroscope_reads_the_rotation_rates() -> None:
    sim = short_dive(6)
    t0, _ = sim.profile.window("station")
    s = sim.sensor_series("A", t0 + 100, t0 + 400)
    angles = sim.motions["A"].angles_deg(s["t_s"])
    d_tx = np.gradient(angles[:, 0], s["t_s"])
    # A rotation about the module's y axis tips "up" toward -x.
    assert np.corrcoef(-d_tx, s["gyro_dps"][:, 1])[0, 1] > 0.5


def test_housing_cools_on_the_way_down_and_humidity_rises_after_a_leak() -> None:
    sim = DiveSimulation(frame_scale=0.25, leak_at_s={"B": 5000.0})
    _, t1 = sim.profile.window("station")
    on_deck = sim.sensor_sample("A", 30.0)
    on_station = sim.sensor_sample("A", t1 - 1)
    assert on_deck.temperature_c == pytest.approx(20.0, abs=0.5)
    assert 2.0 < on_station.temperature_c < 4.5
    assert on_station.humidity_pct == pytest.approx(30.0, abs=2.0)
    assert sim.sensor_sample("B", 4990.0).humidity_pct == pytest.approx(30.0, abs=2.0)
    assert sim.sensor_sample("B", 5000.0 + 1800.0).humidity_pct > 90.0
    recovered = sim.sensor_sample("A", sim.profile.duration_s + 3600.0)
    assert recovered.temperature_c > 15.0


def test_sensor_samples_are_deterministic_and_on_a_grid() -> None:
    sim, again = short_dive(7), short_dive(7)
    t0, _ = sim.profile.window("station")
    one = sim.sensor_sample("A", t0 + 12.3456)
    assert one == again.sensor_sample("A", t0 + 12.3456)
    assert one == sim.sensor_sample("A", t0 + 12.35)  # same 10 Hz tick
    assert one.t == sim.time_at(math.floor((t0 + 12.3456) * 10) / 10)
    series = sim.sensor_series("A", t0 + 12.0, t0 + 13.0)
    k = int(np.flatnonzero(np.isclose(series["t_s"], (one.t - sim.start).total_seconds()))[0])
    assert one.acc_m_s2 == pytest.approx(tuple(series["acc_m_s2"][k]))
    assert one.gyro_dps == pytest.approx(tuple(series["gyro_dps"][k]))
    assert short_dive(8).sensor_sample("A", t0 + 12.3456) != one


# -- frames ------------------------------------------------------------------------------


def test_a_leaning_module_moves_the_lem_by_focal_tan_tilt() -> None:
    sim = short_dive(3, motion_params=LEANING)
    cx, cy = sim.camera.center_xy
    focal = sim.camera.focal_px
    assert focal == pytest.approx(sim.full_camera.focal_px)  # frame_scale keeps the plate scale
    assert (sim.camera.width_px, sim.camera.height_px) == (612, 512)
    t0, _ = sim.profile.window("station")
    for t in (t0 + 200.0, t0 + 400.0):
        frame, meta = sim.render("B", t, 0.05, 8.0)
        found = locate_source(frame)
        assert found.found
        shift = (found.x_px - cx, found.y_px - cy)
        expected = focal * math.tan(math.radians(float(meta["tilt_deg"])))  # type: ignore[arg-type]
        assert expected > 100.0
        assert math.hypot(*shift) == pytest.approx(expected, abs=1.0)
        assert shift == pytest.approx(meta["offset_px"], abs=1.0)
        # ... and the direction follows the axes: the LEM moves against tilt_x, with tilt_y.
        attitude = sim.attitude("B", t + 0.025)
        assert shift[0] == pytest.approx(-focal * math.tan(math.radians(attitude.tilt_x_deg)), abs=1.0)
        assert shift[1] == pytest.approx(focal * math.tan(math.radians(attitude.tilt_y_deg)), abs=1.0)


def test_a_module_leaning_far_loses_the_lem_from_the_small_frame() -> None:
    sim = short_dive(3, motion_params=LEANING, tilt_scale={"B": 3.0})
    t = sim.profile.window("station")[0] + 200.0
    _, meta = sim.render("B", t, 0.05, 8.0)
    assert float(meta["tilt_deg"]) > 2.5  # type: ignore[arg-type]
    assert meta["lem_in_view"] is False


def test_motion_blur_follows_the_track_during_the_exposure() -> None:
    motion = ModuleMotion("A", seed=1, params=MotionParams(rock_deg=0.2))
    focal, distance = TREX_FOCAL_PX, 21.56
    for t in (10.0, 50.0, 333.0):
        bx, by = motion.blur_px(t, 0.02, focal, distance)
        a = motion.pointing_offset_px(t, focal, distance)
        b = motion.pointing_offset_px(t + 0.02, focal, distance)
        assert (bx, by) == pytest.approx((b[0] - a[0], b[1] - a[1]))
        rates = motion.attitude_at(t + 0.01).rates_dps
        # Rotation dominates at short exposures: |blur| ≈ focal * angular rate * exposure.
        rate_blur = focal * math.radians(math.hypot(rates[0], rates[1])) * 0.02
        sway_blur = focal * 0.02 * 2 * motion.params.sway_speed_m_s / distance
        assert math.hypot(bx, by) <= rate_blur * 1.05 + sway_blur
    # On station the T-REX bound holds: < 0.7 px at 0.02 s with the default motion.
    quiet = ModuleMotion("A", seed=1)
    assert max(math.hypot(*quiet.blur_px(t, 0.02, focal, distance)) for t in np.linspace(0, 600, 50)) < 0.7


def test_frames_are_deterministic_and_report_the_exposure_straddling_a_colour_change() -> None:
    sim = short_dive(2)
    t0, _ = sim.profile.window("station")
    t = sim.timetable.next_change_after(t0) - 0.01
    a, meta = sim.render("A", t, 0.05, 8.0)
    b, _ = sim.render("A", t, 0.05, 8.0)
    assert np.array_equal(a, b)
    assert meta["lem_changed_during_exposure"] is True
    _, meta = sim.render("A", t + 1.0, 0.05, 8.0)
    assert meta["lem_changed_during_exposure"] is False
    assert meta["module"] == "A" and meta["captures_enabled"] is True
