"""Inside a module's housing: temperature and humidity through a dive.

Temperature: the housing's air follows the temperature outside with a lag
(a first-order response, time constant ``time_constant_s``: the thick
pressure housing and the air in it), plus the Raspberry Pi's and camera's own
heat (``self_heating_c``). Outside is the deck's air while the module is out
of the water (on deck, and at the start of the descent while the LEM is
already under), else the sea: warm at the surface, cooling through the
thermocline to ~1.6 °C at 3.4 km:

    T_sea(z) = T_deep + (T_surface - T_deep) exp(-z / thermocline_scale_m)

so the housing reads ~20 °C on deck and settles toward ~3 °C on station.

Humidity: the housing is sealed with desiccant, so its relative humidity
stays near ``humidity_pct`` with a slow wobble; after a leak at
``leak_at_s`` it climbs toward 100 % with time constant
``leak_time_constant_s``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from lrm.dive.profile import DiveProfile


@dataclass(frozen=True)
class HousingParams:
    """Temperatures, lags and humidity of a housing; see the module docstring."""

    deck_air_c: float = 18.5
    surface_water_c: float = 26.0
    deep_water_c: float = 1.6
    thermocline_scale_m: float = 400.0
    self_heating_c: float = 1.5
    time_constant_s: float = 900.0
    humidity_pct: float = 30.0
    humidity_wobble_pct: float = 0.5
    leak_time_constant_s: float = 600.0
    temperature_noise_c: float = 0.05
    humidity_noise_pct: float = 0.2

    def __post_init__(self) -> None:
        for name in ("thermocline_scale_m", "time_constant_s", "leak_time_constant_s"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        if not (0 <= self.humidity_pct <= 100):
            raise ValueError(f"humidity_pct must lie in [0, 100], got {self.humidity_pct}")

    def ambient_c(self, module_depth_m: np.ndarray) -> np.ndarray:
        """Temperature outside the housing: deck air above the surface, the sea below."""
        z = np.asarray(module_depth_m, dtype=np.float64)
        sea = self.deep_water_c + (self.surface_water_c - self.deep_water_c) * np.exp(
            -np.maximum(z, 0.0) / self.thermocline_scale_m
        )
        return np.where(z > 0, sea, self.deck_air_c)


class HousingModel:
    """Noise-free housing temperature and humidity of one module through a dive.

    The lagged temperature is integrated once, on a 1 s grid over the whole
    dive (exact for an outside temperature constant within each second), and
    interpolated; after the grid it relaxes toward the deck's air.

    Parameters
    ----------
    profile
        The dive.
    distance_m
        The module's height above the LEM (its depth is the LEM's minus this).
    params
        Temperatures and time constants.
    leak_at_s
        Dive time at which water starts getting in; None for a dry housing.
    """

    def __init__(
        self,
        profile: DiveProfile,
        distance_m: float,
        params: HousingParams | None = None,
        leak_at_s: float | None = None,
    ) -> None:
        self.params = p = params or HousingParams()
        self.leak_at_s = leak_at_s
        step = 1.0
        self._t = np.arange(0.0, profile.duration_s + 2 * step, step)
        depth = profile.lem_depths_m(self._t) - distance_m
        outside = p.ambient_c(depth) + p.self_heating_c
        alpha = 1.0 - math.exp(-step / p.time_constant_s)
        initial = p.deck_air_c + p.self_heating_c
        # y[n] = y[n-1] + alpha (x[n] - y[n-1]), starting in equilibrium on deck.
        temp, _ = lfilter([alpha], [1.0, alpha - 1.0], outside, zi=[(1.0 - alpha) * initial])
        self._temp = temp
        self._end_c = float(temp[-1])
        self._final_c = p.deck_air_c + p.self_heating_c

    def temperature_c(self, t_s: np.ndarray) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        inside = np.interp(t, self._t, self._temp, left=self._final_c)
        after = t > self._t[-1]
        if np.any(after):
            decay = np.exp(-(t[after] - self._t[-1]) / self.params.time_constant_s)
            inside[after] = self._final_c + (self._end_c - self._final_c) * decay
        return inside

    def humidity_pct(self, t_s: np.ndarray) -> np.ndarray:
        p = self.params
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        rh = p.humidity_pct + p.humidity_wobble_pct * np.sin(2 * np.pi * t / 2700.0)
        if self.leak_at_s is not None:
            wet = np.clip(t - self.leak_at_s, 0.0, None)
            rh = rh + (100.0 - rh) * (1.0 - np.exp(-wet / p.leak_time_constant_s))
        return rh
