"""Whether a χ² fit describes its frames: χ² per radial band, and the verdicts a scientist needs.

A χ²/ndof far from 1 means the model does not describe the frames; scaling
the errors by √(χ²/ndof) keeps them honest only if the misfit is spread
evenly. When it sits in a few bands (the disk's edge, a double image) those
bands steer the whole fit, and no error scale repairs that. So the χ² is
reported per band of radius (in disk radii, per camera), and a fit is

* **failed** when χ²/ndof exceeds `CHI2_NDOF_FAIL` (its values are shown,
  marked failed, never quoted as a measurement), and
* **concentrated** when one band group holds most of the excess χ² while
  holding few of the bins, or any group's own χ²/bin exceeds
  `BAND_CHI2_FAIL` times the fit's and its excess is a tenth of the whole
  χ² — even with a χ²/ndof near 1 overall.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from analysis.chisq.results import ChiSquareFit, SettingModel
from analysis.transport.disk import disk_radius_px

#: A fit whose χ²/ndof exceeds this has failed: the model does not describe the frames.
CHI2_NDOF_FAIL = 1.5
#: A band group whose own χ² per bin exceeds this times the fit's χ²/ndof (and 1), with at least
#: `MIN_GROUP_BINS` bins and beyond its own statistical spread, fails the fit.
BAND_CHI2_FAIL = 4.0
MIN_GROUP_BINS = 5
#: Share of the whole χ² a group's excess must reach to be said to steer the fit.
STEERING_SHARE = 0.1
#: Share of the excess χ² (χ² - bins) one group may hold when it holds under a fifth of the bins.
CONCENTRATION_SHARE = 0.5
#: Band groups, in disk radii.
BAND_EDGES_DISK = (0.0, 0.5, 0.8, 0.9, 1.0, 1.1, 1.2, 1.5, 2.0, 3.0, 5.0, math.inf)
CAMERAS = ("near", "far")


@dataclass(frozen=True)
class BandChi2:
    """χ² of one camera's bands between ``r_lo_disk`` and ``r_hi_disk`` disk radii, over all settings."""

    camera: str
    r_lo_disk: float
    r_hi_disk: float
    chi2: float
    n_bins: int

    def to_dict(self) -> dict[str, object]:
        return {
            "camera": self.camera,
            "r_lo_disk": self.r_lo_disk,
            "r_hi_disk": None if math.isinf(self.r_hi_disk) else self.r_hi_disk,
            "chi2": round(self.chi2, 2),
            "n_bins": self.n_bins,
        }


@dataclass(frozen=True)
class FitQuality:
    """The verdicts on a fit's χ²: failed, concentrated, and the reason in words ("" when good)."""

    chi2_ndof: float
    bands: tuple[BandChi2, ...]
    failed: bool
    concentrated: bool
    reason: str

    @property
    def ok(self) -> bool:
        return not (self.failed or self.concentrated)


def band_chi2(
    settings: Sequence[SettingModel], disk_radius_px_by_camera: tuple[float, float]
) -> tuple[BandChi2, ...]:
    """χ² per camera and band group from a fit's per-setting models (`SettingModel`)."""
    edges = np.asarray(BAND_EDGES_DISK)
    n_groups = len(edges) - 1
    chi = np.zeros((2, n_groups))
    n = np.zeros((2, n_groups), dtype=np.int64)
    for sm in settings:
        r = np.asarray(sm.radius_px)
        for c in range(2):
            used = np.asarray(sm.used[c], dtype=bool)
            with np.errstate(invalid="ignore", divide="ignore"):
                res = np.where(used, (sm.data[c] - sm.model[c]) / sm.error[c], 0.0)
            idx = np.clip(np.digitize(r / disk_radius_px_by_camera[c], edges) - 1, 0, n_groups - 1)
            np.add.at(chi[c], idx, np.nan_to_num(res) ** 2)
            np.add.at(n[c], idx, used.astype(np.int64))
    return tuple(
        BandChi2(CAMERAS[c], float(edges[i]), float(edges[i + 1]), float(chi[c, i]), int(n[c, i]))
        for c in range(2)
        for i in range(n_groups)
        if n[c, i] > 0
    )


def assess(chi2: float, ndof: int, bands: tuple[BandChi2, ...]) -> FitQuality:
    """The verdicts on χ² and its bands."""
    ratio = chi2 / ndof if ndof > 0 else math.nan
    failed = not math.isfinite(ratio) or ratio > CHI2_NDOF_FAIL
    reasons = []
    if failed:
        reasons.append(
            f"χ²/ndof {ratio:.2f} exceeds {CHI2_NDOF_FAIL:g}: the model does not describe these frames"
        )
    total_bins = sum(b.n_bins for b in bands) or 1
    excess = sum(max(b.chi2 - b.n_bins, 0.0) for b in bands)
    concentrated = False
    for b in sorted(bands, key=lambda b: -(b.chi2 - b.n_bins)):
        where = f"the {b.camera} camera's bands at {_span(b)} disk radii"
        own = b.chi2 / b.n_bins if b.n_bins else 0.0
        share = (b.chi2 - b.n_bins) / excess if excess > 0 else 0.0
        # A group far worse than the fit as a whole, beyond its own statistical spread (5σ of a χ²
        # with n_bins degrees of freedom).
        # It steers the fit only if its excess is a real part of the whole χ² (a tenth).
        outlier = (
            own > BAND_CHI2_FAIL * max(ratio, 1.0)
            and b.chi2 - b.n_bins > 5.0 * math.sqrt(2 * b.n_bins)
            and b.chi2 - b.n_bins > STEERING_SHARE * chi2
        )
        if b.n_bins >= MIN_GROUP_BINS and outlier:
            concentrated = True
            reasons.append(f"{where} hold χ²/bin {own:.1f}")
        elif (
            ratio > 1.2
            and share > CONCENTRATION_SHARE
            and b.n_bins < 0.2 * total_bins
            and b.chi2 - b.n_bins > 0.1 * total_bins
        ):
            concentrated = True
            reasons.append(f"{where} hold {100 * share:.0f} % of the excess χ² with {b.n_bins} bins")
    return FitQuality(ratio, bands, failed, concentrated, "; ".join(reasons))


def fit_quality(fit: ChiSquareFit) -> FitQuality:
    """`assess` of a fit, its disk radii from its geometry and focal length."""
    geo = fit.geometry
    a = fit.templates.lem_radius_m
    focal = fit.focal_px
    radii = (
        disk_radius_px(geo.distance_near_m, a, focal),
        disk_radius_px(geo.distance_far_m, a, focal),
    )
    return assess(fit.chi2, fit.ndof, band_chi2(fit.settings, radii))


def _span(b: BandChi2) -> str:
    return f"{b.r_lo_disk:g}+" if math.isinf(b.r_hi_disk) else f"{b.r_lo_disk:g}-{b.r_hi_disk:g}"
