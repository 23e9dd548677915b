"""Lab calibrations of the camera system on frame sets (``camcal calibrate``).

One module per experiment of the paper's "Calibration" section; each reads
a frame set, runs the per-frame step on all cores, hands the numbers to
the pure functions of `analysis.calibration` and builds the JSON result
(`camcal.calibrate.common.result_document`). Figures are in `plots`.
"""

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from camcal.calibrate.common import SCHEMA, CalibrationError, FrameOutcome, LabCalibration, Selection
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
from camcal.core.calibrations import LAB_EXPERIMENTS


@dataclass(frozen=True)
class Experiment:
    """One lab experiment: how it is run on a frame set, its JSON document and its figures."""

    name: str
    run: Callable[..., Any]  # run(folder, *, camera=None, workers=None, progress=None, ...) -> a result
    document: Callable[..., dict[str, Any]]  # document(result, command) -> the JSON result
    plot_name: str  # the function of `camcal.calibrate.plots` (imported when plotting: matplotlib)

    def plot(self, result: LabCalibration[Any, Any], out: Path) -> list[Path]:
        """Write the experiment's figures of ``result`` into the folder ``out``."""
        from camcal.calibrate import plots

        return list(getattr(plots, self.plot_name)(result, out))


#: Every lab experiment by its name (`camcal.core.calibrations.LAB_EXPERIMENTS`), in that order.
EXPERIMENTS: dict[str, Experiment] = {
    e.name: e
    for e in (
        Experiment("linearity", run_linearity, linearity_document, "plot_linearity"),
        Experiment("emission-ratio", run_emission_ratio, emission_document, "plot_emission"),
        Experiment("air-scan", run_air_scan, air_scan_document, "plot_air_scan"),
        Experiment("tank-scan", run_tank_scan, tank_scan_document, "plot_tank_scan"),
        Experiment("psf", run_psf, psf_document, "plot_psf"),
    )
}
assert tuple(EXPERIMENTS) == LAB_EXPERIMENTS, "a lab experiment without its analysis"

__all__ = [
    "EXPERIMENTS",
    "SCHEMA",
    "AirScanCalibration",
    "CalibrationError",
    "EmissionRatioCalibration",
    "Experiment",
    "FrameOutcome",
    "LabCalibration",
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
