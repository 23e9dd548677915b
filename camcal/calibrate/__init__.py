"""Lab calibrations of the camera system on frame sets (``camcal calibrate``).

One module per experiment of the paper's "Calibration" section; each reads
a frame set, runs the per-frame step on all cores, hands the numbers to
the pure functions of `analysis.calibration` and builds the JSON result
(`camcal.calibrate.common.result_document`). Figures are in `plots`.
"""

from camcal.calibrate.common import SCHEMA, CalibrationError, FrameOutcome, Selection
from camcal.calibrate.emission import EmissionRatioCalibration, emission_document, run_emission_ratio
from camcal.calibrate.linearity import LinearityCalibration, linearity_document, run_linearity
from camcal.calibrate.psf import PSFCalibration, psf_document, run_psf
from camcal.calibrate.scans import (
    AirScanCalibration,
    TankScanCalibration,
    air_scan_document,
    run_air_scan,
    run_tank_scan,
    tank_scan_document,
)

__all__ = [
    "SCHEMA",
    "AirScanCalibration",
    "CalibrationError",
    "EmissionRatioCalibration",
    "FrameOutcome",
    "LinearityCalibration",
    "PSFCalibration",
    "Selection",
    "TankScanCalibration",
    "air_scan_document",
    "emission_document",
    "linearity_document",
    "psf_document",
    "run_air_scan",
    "run_emission_ratio",
    "run_linearity",
    "run_psf",
    "run_tank_scan",
    "tank_scan_document",
]
