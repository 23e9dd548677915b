"""camcal: camera-based optical calibration for deep-sea neutrino telescopes.

This package holds the command line and what the module side and the ship
side share: the frame-set format, the wire protocol and the schedule model.
"""

__version__ = "0.1.0"
