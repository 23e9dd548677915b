"""The science of camcal: I_center, λ_att, linearity and geometry on numpy arrays.

Pure functions and frozen results: no files, no network, no database. Arrays
in, results out. Conventions are in ``docs/conventions.md``.
"""

from analysis.attenuation import (
    AttenuationResult,
    EmissionRatio,
    Geometry,
    PairResult,
    attenuation_length_m,
    combine_pairs,
    pair_result,
)
from analysis.dataset import (
    FrameRecord,
    LinearityCheck,
    SetResult,
    Setting,
    analyze_records,
    linearity_checks,
    stack_by_setting,
)
from analysis.detect import Detection, FrameFormatError, check_frame, locate_source
from analysis.frame import (
    REASON_HELP,
    FrameAnalysis,
    FrameConfig,
    Reason,
    analyze_frame,
    rejected,
)
from analysis.geometry import PinholeCheck, hough_radius_px, pinhole_check
from analysis.linearity import LinearityResult, gain_factor, linearity_fit
from analysis.profile import BackgroundFit, Crop, RadialProfile
from analysis.stack import StackResult, stack_crops, stack_frames

__all__ = [
    "REASON_HELP",
    "AttenuationResult",
    "BackgroundFit",
    "Crop",
    "Detection",
    "EmissionRatio",
    "FrameAnalysis",
    "FrameConfig",
    "FrameFormatError",
    "FrameRecord",
    "Geometry",
    "LinearityCheck",
    "LinearityResult",
    "PairResult",
    "PinholeCheck",
    "RadialProfile",
    "Reason",
    "SetResult",
    "Setting",
    "StackResult",
    "analyze_frame",
    "analyze_records",
    "attenuation_length_m",
    "check_frame",
    "combine_pairs",
    "gain_factor",
    "hough_radius_px",
    "linearity_checks",
    "linearity_fit",
    "locate_source",
    "pair_result",
    "pinhole_check",
    "rejected",
    "stack_by_setting",
    "stack_crops",
    "stack_frames",
]
