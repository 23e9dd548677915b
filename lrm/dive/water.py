"""The water column: optics that change with depth and, slowly, with time.

A rolling λ_att measured during a dive needs a truth that moves. The model:

* **Depth.** Absorption and scattering *coefficients* (1/length) relax from
  those of a turbid upper ocean to those of the deep water with depth:

      c(z) = c_deep + (c_shallow - c_deep) * w(z),   w(z) = exp(-z / turbid_scale_m)

  Particles and dissolved matter are richest near the surface, so the upper
  water attenuates more; below a couple of kilometres ``w`` is below 1 % and
  the column is the ``deep`` water (by default the ``trex`` preset: 20 / 28 /
  21 m attenuation). Coefficients, not lengths, are mixed because they add.
* **Time.** On station the water drifts (the ship drifts, particle clouds
  pass): all coefficients are multiplied by a factor f(t). The ``"sine"``
  drift is

      f(t) = 1 + drift_frac * sin(2π (t - drift_center_s) / drift_period_s)

  which is steepest at ``drift_center_s``; the defaults centre it on the
  default dive's station, where it changes λ_att by ~4 % in 30 minutes. The
  ``"bump"`` drift is a passing cloud of particles,

      f(t) = 1 + drift_frac * cos²(π (t - drift_center_s) / drift_period_s)

  for |t - drift_center_s| < drift_period_s / 2 and 1 outside: λ_att falls
  smoothly to 1 / (1 + drift_frac) of its value at ``drift_center_s`` and
  comes back (e.g. 28 -> 20 -> 28 m with drift_frac = 0.4).
  ``drift_frac = 0`` switches the drift off.

Between the LEM and a camera the light crosses a 20-40 m column; its optics
are taken at the **midpoint depth** of that path (`path_midpoint_depth_m`):
the exponential depth profile is nearly linear over 40 m, so the midpoint
value is the path average to better than 0.1 %.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

from analysis.scattering import WaterOptics
from lrm.dive.profile import STATION, DiveProfile
from lrm.sim.scene import Water, water_preset

#: The shapes of the water's drift in time (see the module docstring).
DRIFT_SHAPES = ("sine", "bump")


@dataclass(frozen=True)
class WaterColumn:
    """Water optics as a function of depth and dive time; see the module docstring."""

    deep: Water = field(default_factory=lambda: water_preset("trex"))
    shallow: Water = field(default_factory=lambda: water_preset("turbid"))
    turbid_scale_m: float = 500.0
    drift_frac: float = 0.05
    drift_period_s: float = 14400.0
    drift_center_s: float = 4620.0
    drift_shape: str = "sine"

    def __post_init__(self) -> None:
        if self.drift_shape not in DRIFT_SHAPES:
            raise ValueError(
                f"drift_shape must be one of {', '.join(DRIFT_SHAPES)}, got {self.drift_shape!r}"
            )
        missing = sorted(set(self.deep.optics) - set(self.shallow.optics))
        if missing:
            raise ValueError(f"shallow water lacks the deep water's wavelengths {missing} nm")
        if not (self.turbid_scale_m > 0 and math.isfinite(self.turbid_scale_m)):
            raise ValueError(f"turbid_scale_m must be > 0, got {self.turbid_scale_m}")
        if not (0 <= self.drift_frac < (1 if self.drift_shape == "sine" else 10)):
            raise ValueError(f"drift_frac must lie in [0, 1) ([0, 10) for a bump), got {self.drift_frac}")
        if not self.drift_period_s > 0:
            raise ValueError(f"drift_period_s must be > 0, got {self.drift_period_s}")

    @classmethod
    def with_station_drift(
        cls,
        profile: DiveProfile,
        change_frac: float = 0.04,
        *,
        deep: Water | None = None,
        shallow: Water | None = None,
        turbid_scale_m: float = 500.0,
    ) -> WaterColumn:
        """A column whose drift is centred on ``profile``'s station.

        The coefficients change by ``change_frac`` from the station's start to
        its end, whatever the station's length: a quarter of the drift's period
        spans the station, centred on the steepest part of the sine.
        """
        t0, t1 = profile.window(STATION)
        duration = max(t1 - t0, 1.0)
        # Over a quarter period centred on the zero crossing, sin goes from -sin(π/4) to +sin(π/4).
        amplitude = change_frac / (2.0 * math.sin(math.pi / 4.0))
        return cls(
            deep=deep or water_preset("trex"),
            shallow=shallow or water_preset("turbid"),
            turbid_scale_m=turbid_scale_m,
            drift_frac=amplitude,
            drift_period_s=4.0 * duration,
            drift_center_s=(t0 + t1) / 2.0,
        )

    @classmethod
    def with_station_bump(
        cls,
        profile: DiveProfile,
        lambda_drop_frac: float = 0.3,
        *,
        deep: Water | None = None,
        shallow: Water | None = None,
        turbid_scale_m: float = 500.0,
    ) -> WaterColumn:
        """A column in which λ_att of every wavelength falls by ``lambda_drop_frac`` and comes back.

        The bump spans the station: λ_att is the deep water's at the
        station's start and end and ``1 - lambda_drop_frac`` of it in the
        middle (0.3: 28 -> 19.6 -> 28 m at 460 nm).
        """
        if not (0 <= lambda_drop_frac < 0.9):
            raise ValueError(f"lambda_drop_frac must lie in [0, 0.9), got {lambda_drop_frac}")
        t0, t1 = profile.window(STATION)
        return cls(
            deep=deep or water_preset("trex"),
            shallow=shallow or water_preset("turbid"),
            turbid_scale_m=turbid_scale_m,
            drift_frac=1.0 / (1.0 - lambda_drop_frac) - 1.0,
            drift_period_s=max(t1 - t0, 1.0),
            drift_center_s=(t0 + t1) / 2.0,
            drift_shape="bump",
        )

    @property
    def wavelengths_nm(self) -> tuple[int, ...]:
        return tuple(sorted(self.deep.optics))

    @staticmethod
    def path_midpoint_depth_m(lem_depth_m: float, distance_m: float) -> float:
        """Depth of the middle of the light path from the LEM up to a camera ``distance_m`` above it."""
        return max(lem_depth_m - distance_m / 2.0, 0.0)

    def depth_weight(self, depth_m: float) -> float:
        """w(z): 1 at the surface, falling to 0 in the deep water."""
        return math.exp(-max(depth_m, 0.0) / self.turbid_scale_m)

    def drift_factor(self, t_s: float) -> float:
        """f(t): the factor on all coefficients at dive time ``t_s``."""
        if self.drift_frac == 0:
            return 1.0
        if self.drift_shape == "bump":
            x = (t_s - self.drift_center_s) / self.drift_period_s
            return 1.0 + self.drift_frac * math.cos(math.pi * x) ** 2 if abs(x) < 0.5 else 1.0
        return 1.0 + self.drift_frac * math.sin(
            2.0 * math.pi * (t_s - self.drift_center_s) / self.drift_period_s
        )

    def water_for(self, depth_weight: float, drift_factor: float) -> Water:
        """The water at a given depth weight ``w`` and drift factor ``f`` (see the module docstring).

        Phase function and refractive index are the deep water's.
        """
        if not (0.0 <= depth_weight <= 1.0):
            raise ValueError(f"depth_weight must lie in [0, 1], got {depth_weight}")
        if not drift_factor > 0:
            raise ValueError(f"drift_factor must be > 0, got {drift_factor}")
        optics: dict[int, WaterOptics] = {}
        for wl, deep in self.deep.optics.items():
            shallow = self.shallow.at(wl)
            c_abs = (
                1.0 / deep.lambda_abs_m
                + (1.0 / shallow.lambda_abs_m - 1.0 / deep.lambda_abs_m) * depth_weight
            )
            c_sca = (
                1.0 / deep.lambda_sca_m
                + (1.0 / shallow.lambda_sca_m - 1.0 / deep.lambda_sca_m) * depth_weight
            )
            optics[wl] = dataclasses.replace(
                deep, lambda_abs_m=1.0 / (c_abs * drift_factor), lambda_sca_m=1.0 / (c_sca * drift_factor)
            )
        return Water(optics, name=f"column(w={depth_weight:.4g}, f={drift_factor:.4g})")

    def water_at(self, depth_m: float, t_s: float) -> Water:
        """The water at ``depth_m`` and dive time ``t_s``."""
        return self.water_for(self.depth_weight(depth_m), self.drift_factor(t_s))

    def lambda_att_at(self, wavelength_nm: int, depth_m: float, t_s: float) -> float:
        """True attenuation length (m) at ``wavelength_nm``, ``depth_m`` and dive time ``t_s``."""
        return self.water_at(depth_m, t_s).at(wavelength_nm).lambda_att_m
