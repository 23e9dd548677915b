"""A whole T-REX dive in simulated time, deterministic from a seed.

* `DiveProfile`: deck, descent with test stops at 1200 m and 2021 m, ~30 min
  on station at 3420 m, ascent, recovered; the LEM's depth at any time.
* `LEMTimetable`: which wavelength the LEM shows when.
* `WaterColumn`: optics that change with depth and drift slowly on station.
* `ModuleMotion`: tilt, heading, the ship's heave, sway; where the LEM
  appears in the frame and how much it smears.
* `DiveSimulation`: frames and housing-sensor samples of every module at
  any dive time.

Dive time is seconds since the dive's start; ``DiveSimulation.start`` maps
it to UTC, and a `lrm.clock.SimClock` started there runs through it.
"""

from lrm.dive.housing import HousingModel, HousingParams
from lrm.dive.motion import GRAVITY_M_S2, Attitude, ModuleMotion, MotionParams
from lrm.dive.profile import DiveProfile, LEMTimetable, Segment
from lrm.dive.simulation import DEFAULT_START, DiveSimulation, scaled_camera
from lrm.dive.water import WaterColumn
from lrm.sensors import SensorSample, tilt_from_acceleration_deg, tilt_series_deg

__all__ = [
    "DEFAULT_START",
    "GRAVITY_M_S2",
    "Attitude",
    "DiveProfile",
    "DiveSimulation",
    "HousingModel",
    "HousingParams",
    "LEMTimetable",
    "ModuleMotion",
    "MotionParams",
    "Segment",
    "SensorSample",
    "WaterColumn",
    "scaled_camera",
    "tilt_from_acceleration_deg",
    "tilt_series_deg",
]
