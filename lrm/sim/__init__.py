"""A physics-faithful stand-in for the LRM camera: it renders frames of the LEM.

This is the part of the system a real camera replaces; everything downstream
sees the same 8-bit frames it would see from the hardware.
"""

from lrm.sim.camera import CameraModel
from lrm.sim.render import FrameRenderer, FrameTruth
from lrm.sim.scene import LEMModel, Placement, Water, water_preset

__all__ = [
    "CameraModel",
    "FrameRenderer",
    "FrameTruth",
    "LEMModel",
    "Placement",
    "Water",
    "water_preset",
]
