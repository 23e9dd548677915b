"""Factories for tests of the simulated dive: a short dive on the small sensor."""

from __future__ import annotations

from lrm.dive import DiveProfile, DiveSimulation, MotionParams, WaterColumn


def short_profile(station_s: float = 600.0) -> DiveProfile:
    """The T-REX depths, with a fast winch and short stops: the station starts at ~99 s."""
    return DiveProfile(
        deck_s=5.0, descent_m_per_s=100.0, test_stop_s=30.0, station_s=station_s, ascent_m_per_s=100.0
    )


def short_dive(
    seed: int = 0, *, motion_params: MotionParams | None = None, **kwargs: object
) -> DiveSimulation:
    """A short dive rendered on a quarter-size sensor (612 x 512 px, T-REX plate scale).

    The water drifts by 4 % over the station, as the default column does over
    the default dive's 30 minutes.
    """
    profile = short_profile()
    return DiveSimulation(
        profile,
        water_column=WaterColumn.with_station_drift(profile, 0.04),
        seed=seed,
        frame_scale=0.25,
        motion_params=motion_params,
        **kwargs,  # type: ignore[arg-type]
    )


#: A module leaning a steady 1° (little wander, no sway): the LEM sits ~150 px off axis.
LEANING = MotionParams(lean_deg_range=(1.0, 1.0), wander_deg_rms=0.05, sway_speed_m_s=0.0)
