"""Option defaults and choices of the command line, as plain constants.

``camcal --help`` reads every command's options; a default computed by the
module that owns it (the simulator's camera, the calibration's constants)
would import SciPy, OpenCV and the simulator only to print a number. The
values live here instead, and ``tests/cli/test_startup.py`` checks each one
against its owner, so they cannot drift apart.
"""

from __future__ import annotations

import math

#: T-REX camera focal length [px]: 16° over 2448 px in water (`lrm.sim.camera.CameraModel.focal_px`).
TREX_FOCAL_PX = (2448 / 2.0) / math.tan(math.radians(16.0) / 2.0)
#: Deep-sea water temperature of the emission-ratio run [°C] (`analysis.calibration`).
DEEP_SEA_TEMPERATURE_C = 2.0
#: Diameter of the LEM's glowing sphere [m] (`camcal.calibrate.scans`).
LEM_DIAMETER_M = 0.43
#: The lab experiments `camcal simulate-lab` can render (`lrm.labset.LAB_KINDS`).
LAB_KINDS = ("linearity", "emission-ratio", "air-scan", "tank-scan", "psf")
#: The data folder when neither ``--data``, ``CAMCAL_DATA_DIR`` nor the config file names one
#: (`camcal.core.settings.Settings.data_dir`).
DATA_DIR = "camcal-data"
