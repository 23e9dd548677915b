"""The science of the lab calibrations of the camera system (paper, section "Calibration").

Pure functions and frozen results, like the rest of `analysis`: arrays and
numbers in, results out. Reading frame sets and writing reports is
`camcal.calibrate`'s job.

* `linearity` — the linear response range from darkroom sweeps;
* `emission` — I0'/I0 of the LEM's hemispheres and its temperature effect;
* `scan` — distance scans: constant centre gray in air, 1/L² total, the
  pinhole law, exponential decay in water;
* `psf` — the PSF width from a point-like source;
* `measure` — what each of these measures on a frame;
* `fit` — the weighted line fits they share.
"""

from analysis.calibration.emission import (
    DEEP_SEA_TEMPERATURE_C,
    EmissionRatioResult,
    HemisphereValue,
    RatioAtTemperature,
    TemperatureEffect,
    emission_ratios,
    group_temperatures,
)
from analysis.calibration.fit import Combined, LineFit, WeightedMean, combine_repeats, fit_line, weighted_mean
from analysis.calibration.linearity import ResponseCurve, response_linearity
from analysis.calibration.measure import (
    ApertureSum,
    SourceMeasurement,
    aperture_radius_px,
    aperture_sum,
    gray_at,
    measure_source,
)
from analysis.calibration.psf import (
    FWHM_PER_SIGMA,
    PointSourceFit,
    PSFResult,
    fit_point_source,
    pixel_integrated_gaussian,
    psf_width,
    psf_width_of,
)
from analysis.calibration.scan import (
    MIN_DISTANCES,
    DecayFit,
    MediumComparison,
    PinholeFit,
    PowerLawFit,
    ScanPoint,
    compare_media,
    decay_fit,
    pinhole_fit,
    power_law_fit,
    reduce_scan,
)

__all__ = [
    "DEEP_SEA_TEMPERATURE_C",
    "FWHM_PER_SIGMA",
    "MIN_DISTANCES",
    "ApertureSum",
    "Combined",
    "DecayFit",
    "EmissionRatioResult",
    "HemisphereValue",
    "LineFit",
    "MediumComparison",
    "PSFResult",
    "PinholeFit",
    "PointSourceFit",
    "PowerLawFit",
    "RatioAtTemperature",
    "ResponseCurve",
    "ScanPoint",
    "SourceMeasurement",
    "TemperatureEffect",
    "WeightedMean",
    "aperture_radius_px",
    "aperture_sum",
    "combine_repeats",
    "compare_media",
    "decay_fit",
    "emission_ratios",
    "fit_line",
    "fit_point_source",
    "gray_at",
    "group_temperatures",
    "measure_source",
    "pinhole_fit",
    "pixel_integrated_gaussian",
    "power_law_fit",
    "psf_width",
    "psf_width_of",
    "reduce_scan",
    "response_linearity",
    "weighted_mean",
]
