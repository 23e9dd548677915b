"""How a receiver module moves: tilt, heading, the ship's heave, sway.

Attitude convention
-------------------
The module frame has z up along the module's axis (the cable) and x, y across
it. ``tilt_x_deg`` and ``tilt_y_deg`` are defined by what a still
accelerometer reads: ``tan(tilt_x) = a_x / a_z`` and ``tan(tilt_y) = a_y /
a_z``, i.e. world "up" seen from the module is along ``(tan tilt_x, tan
tilt_y, 1)``. The total tilt from the vertical is ``atan(hypot(tan tilt_x,
tan tilt_y))``. ``heading_deg`` is the rotation about the vertical; it moves
nothing in these body-frame angles. Rates (the gyroscope) are, for small
tilts, ``ω_x = d tilt_y/dt``, ``ω_y = -d tilt_x/dt``, ``ω_z = d heading/dt``
(a rotation of the module about its own y axis tips "up" toward -x).

Where the LEM appears
---------------------
The camera looks down the cable at the LEM hanging directly below (the cable
is straight and vertical under its own weight, as in T-REX). Its image x is
the module's x and its image y the module's -y (right-handed, looking down
-z). The direction to the LEM in the module frame is ``-(tan tilt_x + s_x/L,
tan tilt_y + s_y/L, 1)`` with ``s`` the module's sideways displacement
relative to the LEM and ``L`` their distance, so the LEM moves from the
optical axis by

    dx = -f (tan tilt_x + s_x / L),   dy = +f (tan tilt_y + s_y / L)

pixels (f the focal length in pixels): a lean of θ moves it by f·tan θ. A
lean of the whole cable, common to module and LEM, would not move it; the
cable is taken as vertical, so the module's tilt from the vertical is its
tilt from the line of sight.

Motion model (all deterministic from the seed)
----------------------------------------------
* **Lean**: a static lean per module (direction uniform, size drawn in
  ``lean_deg_range``) plus a slow wander (a sum of sinusoids with periods of
  minutes, RMS ``wander_deg_rms``), growing by ``moving_tilt_factor`` while
  the cable moves (drag).
* **Rocking**: a small pendulum oscillation of a few seconds' period, driven
  by the heave, so larger near the surface.
* **Heave**: the ship's vertical motion transmitted down the taut cable; one
  dominant period drawn in 5-10 s (paper, appendix A) with two weaker
  neighbouring components (a narrow sea spectrum). It is the *ship's*, so
  both modules of a dive share it. Its amplitude grows toward the surface
  and while the winch runs.
* **Sway**: sideways motion relative to the LEM, a few cm/s (currents at
  3420 m were < 10 cm/s), more while the cable moves.
* **Heading**: a slow wander plus a torsional oscillation of the cable.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lrm.dive._random import generator
from lrm.dive.profile import DiveProfile

#: Standard gravity (m/s²); the local value at 3 km depth differs by < 0.1 %.
GRAVITY_M_S2 = 9.81
#: Step of the central differences that give the rotation rates.
_RATE_STEP_S = 0.01


@dataclass(frozen=True)
class Attitude:
    """Orientation of a module at one instant; see the module docstring for the axes."""

    tilt_x_deg: float
    tilt_y_deg: float
    heading_deg: float
    rates_dps: tuple[float, float, float]

    @property
    def tilt_deg(self) -> float:
        """Total tilt of the module axis from the vertical."""
        tx, ty = math.radians(self.tilt_x_deg), math.radians(self.tilt_y_deg)
        return math.degrees(math.atan(math.hypot(math.tan(tx), math.tan(ty))))


@dataclass(frozen=True)
class MotionParams:
    """Sizes and time scales of a module's motion (see the module docstring)."""

    lean_deg_range: tuple[float, float] = (0.2, 0.6)
    wander_deg_rms: float = 0.15
    wander_period_s: tuple[float, float] = (60.0, 900.0)
    moving_tilt_factor: float = 2.0
    moving_smooth_s: float = 60.0
    rock_deg: float = 0.03
    rock_period_s: tuple[float, float] = (2.5, 4.5)
    heading_wander_deg: float = 15.0
    heading_period_s: tuple[float, float] = (300.0, 1800.0)
    twist_deg: float = 1.0
    twist_period_s: tuple[float, float] = (20.0, 60.0)
    heave_period_s: tuple[float, float] = (5.0, 10.0)
    heave_station_m_s2: float = 0.08
    heave_surface_m_s2: float = 0.4
    heave_scale_m: float = 800.0
    heave_moving_factor: float = 1.5
    sway_speed_m_s: float = 0.02
    sway_period_s: tuple[float, float] = (15.0, 40.0)
    moving_sway_factor: float = 3.0
    current_m_s: float = 0.05
    current_variation_m_s: float = 0.02
    station_depth_m: float = 3420.0

    def __post_init__(self) -> None:
        for name in (
            "lean_deg_range",
            "wander_period_s",
            "rock_period_s",
            "heading_period_s",
            "twist_period_s",
            "heave_period_s",
            "sway_period_s",
        ):
            lo, hi = getattr(self, name)
            if not (0 <= lo <= hi) or (name != "lean_deg_range" and lo <= 0):
                raise ValueError(
                    f"{name} must be an increasing (low, high) pair of positive values, got {(lo, hi)}"
                )
        for name in (
            "wander_deg_rms",
            "rock_deg",
            "heading_wander_deg",
            "twist_deg",
            "heave_station_m_s2",
            "heave_surface_m_s2",
            "sway_speed_m_s",
            "current_m_s",
            "current_variation_m_s",
        ):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        for name in ("moving_tilt_factor", "heave_moving_factor", "moving_sway_factor"):
            if not getattr(self, name) >= 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if not (self.current_m_s + self.current_variation_m_s < 0.1):
            raise ValueError(
                "current_m_s + current_variation_m_s must stay below 0.1 m/s (T-REX measured < 10 cm/s), "
                f"got {self.current_m_s} + {self.current_variation_m_s}"
            )


@dataclass(frozen=True)
class _Waves:
    """A sum of sinusoids ``Σ a_k sin(ω_k t + φ_k)`` evaluated on arrays of times."""

    amplitude: np.ndarray
    omega: np.ndarray
    phase: np.ndarray

    @classmethod
    def draw(cls, rng: np.random.Generator, n: int, period_s: tuple[float, float], rms: float) -> _Waves:
        """``n`` components, periods log-uniform in ``period_s``, scaled to the given RMS."""
        periods = np.exp(rng.uniform(math.log(period_s[0]), math.log(period_s[1]), n))
        amp = rng.rayleigh(1.0, n)
        norm = math.sqrt(float(np.sum(amp**2)) / 2.0) or 1.0
        return cls(amp * rms / norm, 2.0 * np.pi / periods, rng.uniform(0, 2 * np.pi, n))

    def value(self, t: np.ndarray) -> np.ndarray:
        return np.sin(t[:, None] * self.omega + self.phase) @ self.amplitude

    def integral(self, t: np.ndarray) -> np.ndarray:
        """An antiderivative (zero mean)."""
        return -np.cos(t[:, None] * self.omega + self.phase) @ (self.amplitude / self.omega)

    def second_integral(self, t: np.ndarray) -> np.ndarray:
        return -np.sin(t[:, None] * self.omega + self.phase) @ (self.amplitude / self.omega**2)

    def derivative(self, t: np.ndarray) -> np.ndarray:
        return np.cos(t[:, None] * self.omega + self.phase) @ (self.amplitude * self.omega)


class ModuleMotion:
    """Attitude and motion of one module through a dive; see the module docstring.

    Parameters
    ----------
    module_id
        The module (``"A"``, ``"B"``): seeds its own lean, wander and sway.
    seed
        The dive's seed; the ship's heave is drawn from it alone, so modules of
        the same dive share it.
    profile
        The dive, for the depth and whether the cable is moving. Without one the
        module is on station at ``params.station_depth_m`` throughout.
    tilt_scale
        Multiplies every tilt (lean, wander, rocking): > 1 makes a module lean
        too far, for tests of tilt alarms and of a LEM leaving the view.
    params
        Sizes and time scales.
    """

    def __init__(
        self,
        module_id: str,
        seed: int,
        profile: DiveProfile | None = None,
        *,
        tilt_scale: float = 1.0,
        params: MotionParams | None = None,
    ) -> None:
        if not (tilt_scale >= 0 and math.isfinite(tilt_scale)):
            raise ValueError(f"tilt_scale must be a finite number >= 0, got {tilt_scale}")
        self.module_id = module_id
        self.seed = int(seed)
        self.profile = profile
        self.tilt_scale = float(tilt_scale)
        self.params = p = params or MotionParams()

        rng = generator(seed, "module", module_id)
        lean = rng.uniform(*p.lean_deg_range)
        direction = rng.uniform(0, 2 * np.pi)
        self.lean_deg = (lean * math.cos(direction), lean * math.sin(direction))
        self._wander = (
            _Waves.draw(rng, 6, p.wander_period_s, p.wander_deg_rms),
            _Waves.draw(rng, 6, p.wander_period_s, p.wander_deg_rms),
        )
        self._rock = (
            _Waves.draw(rng, 1, p.rock_period_s, p.rock_deg / math.sqrt(2)),
            _Waves.draw(rng, 1, p.rock_period_s, p.rock_deg / math.sqrt(2)),
        )
        self._heading0_deg = rng.uniform(0, 360)
        self._heading = _Waves.draw(rng, 3, p.heading_period_s, p.heading_wander_deg)
        self._twist = _Waves.draw(rng, 1, p.twist_period_s, p.twist_deg / math.sqrt(2))
        # Sway velocity per axis: two components each, amplitude ~ sway_speed_m_s.
        self._sway = (
            _Waves.draw(rng, 2, p.sway_period_s, p.sway_speed_m_s / math.sqrt(2)),
            _Waves.draw(rng, 2, p.sway_period_s, p.sway_speed_m_s / math.sqrt(2)),
        )
        self._current = _Waves.draw(rng, 3, (600.0, 3600.0), p.current_variation_m_s / math.sqrt(2))
        self._current_dir = _Waves.draw(rng, 2, (900.0, 3600.0), 0.5)

        # The ship's heave: one dominant period and two weaker neighbours.
        ship = generator(seed, "ship")
        self.heave_period_s = float(ship.uniform(*p.heave_period_s))
        omega0 = 2.0 * np.pi / self.heave_period_s
        spread = ship.uniform(0.04, 0.1, 2)
        self._heave = _Waves(
            amplitude=np.array([1.0, 0.3, 0.2]),
            omega=np.array([omega0, omega0 * (1 + spread[0]), omega0 * (1 - spread[1])]),
            phase=ship.uniform(0, 2 * np.pi, 3),
        )

    # -- envelopes ---------------------------------------------------------
    def _moving(self, t: np.ndarray) -> np.ndarray:
        if self.profile is None:
            return np.zeros_like(t)
        return self.profile.moving_fraction(t, self.params.moving_smooth_s)

    def _lem_depth(self, t: np.ndarray) -> np.ndarray:
        if self.profile is None:
            return np.full_like(t, self.params.station_depth_m)
        return self.profile.lem_depths_m(t)

    def heave_amplitude_m_s2(self, t_s: np.ndarray) -> np.ndarray:
        """Amplitude of the dominant heave component: larger near the surface and while moving."""
        p = self.params
        t = np.asarray(t_s, dtype=np.float64)
        depth = self._lem_depth(t)
        base = p.heave_station_m_s2 + (p.heave_surface_m_s2 - p.heave_station_m_s2) * np.exp(
            -depth / p.heave_scale_m
        )
        return base * (1.0 + (p.heave_moving_factor - 1.0) * self._moving(t))

    # -- vectorised state --------------------------------------------------
    def angles_deg(self, t_s: np.ndarray) -> np.ndarray:
        """``(n, 3)`` array of tilt_x, tilt_y, heading (degrees) at dive times ``t_s``."""
        p = self.params
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        moving = self._moving(t)
        lean_env = 1.0 + (p.moving_tilt_factor - 1.0) * moving
        rock_env = self.heave_amplitude_m_s2(t) / max(p.heave_station_m_s2, 1e-9)
        tilts = [
            self.tilt_scale
            * (lean_env * (self.lean_deg[i] + self._wander[i].value(t)) + rock_env * self._rock[i].value(t))
            for i in (0, 1)
        ]
        heading = (self._heading0_deg + self._heading.value(t) + self._twist.value(t)) % 360.0
        return np.stack([tilts[0], tilts[1], heading], axis=1)

    def rates_dps(self, t_s: np.ndarray) -> np.ndarray:
        """``(n, 3)`` body rotation rates (deg/s), from central differences of the angles."""
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        h = _RATE_STEP_S
        diff = self.angles_deg(t + h) - self.angles_deg(t - h)
        diff[:, 2] = (diff[:, 2] + 180.0) % 360.0 - 180.0  # heading wraps at 360°
        d = diff / (2 * h)
        return np.stack([d[:, 1], -d[:, 0], d[:, 2]], axis=1)

    def heave_m_s2(self, t_s: np.ndarray) -> np.ndarray:
        """Vertical acceleration of the module from the ship's heave (m/s², up positive)."""
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        return self.heave_amplitude_m_s2(t) * self._heave.value(t)

    def heave_displacement_m(self, t_s: np.ndarray) -> np.ndarray:
        """Vertical displacement from the heave (m, up positive): the acceleration integrated twice."""
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        return self.heave_amplitude_m_s2(t) * self._heave.second_integral(t)

    def _sway_env(self, t: np.ndarray) -> np.ndarray:
        return 1.0 + (self.params.moving_sway_factor - 1.0) * self._moving(t)

    def sway_m(self, t_s: np.ndarray) -> np.ndarray:
        """``(n, 2)`` sideways displacement (module x, y) relative to the LEM, metres."""
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        env = self._sway_env(t)
        return np.stack([env * self._sway[i].integral(t) for i in (0, 1)], axis=1)

    def sway_acceleration_m_s2(self, t_s: np.ndarray) -> np.ndarray:
        """``(n, 2)`` sideways acceleration (module x, y), m/s²."""
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        env = self._sway_env(t)
        return np.stack([env * self._sway[i].derivative(t) for i in (0, 1)], axis=1)

    def current_m_s(self, t_s: float) -> tuple[float, float]:
        """Horizontal water current (east, north), m/s: below 10 cm/s, slowly turning."""
        t = np.array([t_s], dtype=np.float64)
        speed = self.params.current_m_s + float(self._current.value(t)[0])
        speed = min(max(speed, 0.0), 0.0999)
        angle = float(self._current_dir.value(t)[0]) + 1.0
        return speed * math.cos(angle), speed * math.sin(angle)

    def specific_force_m_s2(self, t_s: np.ndarray) -> np.ndarray:
        """``(n, 3)`` noise-free accelerometer reading in the module frame.

        Gravity's reaction plus the heave act along the vertical, which the
        module sees along ``(tan tilt_x, tan tilt_y, 1)`` normalised; the sway
        adds a small sideways term. The heave thus changes the reading's
        length, not its direction, and tilt from ``atan2`` stays unbiased.
        """
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        ang = np.radians(self.angles_deg(t))
        up = np.stack([np.tan(ang[:, 0]), np.tan(ang[:, 1]), np.ones_like(t)], axis=1)
        up /= np.linalg.norm(up, axis=1, keepdims=True)
        acc = up * (GRAVITY_M_S2 + self.heave_m_s2(t))[:, None]
        acc[:, :2] += self.sway_acceleration_m_s2(t)
        return acc

    # -- scalar API ----------------------------------------------------------
    def attitude_at(self, t_s: float) -> Attitude:
        """Tilt, heading and rotation rates at dive time ``t_s``."""
        t = np.array([t_s], dtype=np.float64)
        tx, ty, heading = self.angles_deg(t)[0]
        rates = self.rates_dps(t)[0]
        return Attitude(
            float(tx), float(ty), float(heading), (float(rates[0]), float(rates[1]), float(rates[2]))
        )

    def pointing_offsets_px(
        self, t_s: np.ndarray, focal_px: float, distance_m: float | None = None
    ) -> np.ndarray:
        """``(n, 2)`` offsets of the LEM from the optical axis, (dx, dy) pixels; see the module docstring."""
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        ang = np.radians(self.angles_deg(t))
        lx, ly = np.tan(ang[:, 0]), np.tan(ang[:, 1])
        if distance_m is not None:
            if not distance_m > 0:
                raise ValueError(f"distance_m must be > 0, got {distance_m}")
            sway = self.sway_m(t)
            lx = lx + sway[:, 0] / distance_m
            ly = ly + sway[:, 1] / distance_m
        return np.stack([-focal_px * lx, focal_px * ly], axis=1)

    def pointing_offset_px(
        self, t_s: float, focal_px: float, distance_m: float | None = None
    ) -> tuple[float, float]:
        """Where the LEM appears relative to the optical axis, (dx, dy) pixels.

        The tilt moves it by ``focal_px * tan(tilt)``; with ``distance_m`` the
        sideways sway relative to the LEM is added (``focal_px * s / L``).
        """
        dx, dy = self.pointing_offsets_px(np.array([t_s]), focal_px, distance_m)[0]
        return float(dx), float(dy)

    def blur_px(
        self, t_s: float, exposure_s: float, focal_px: float, distance_m: float
    ) -> tuple[float, float]:
        """How far the LEM moves on the sensor during an exposure starting at ``t_s``, (bx, by) px.

        The chord of the LEM's track from the start to the end of the exposure,
        from the rotation (tilt rates) and the sway; the renderer smears the
        LEM along it.
        """
        if not exposure_s >= 0:
            raise ValueError(f"exposure_s must be >= 0, got {exposure_s}")
        ends = self.pointing_offsets_px(np.array([t_s, t_s + exposure_s]), focal_px, distance_m)
        bx, by = ends[1] - ends[0]
        return float(bx), float(by)
