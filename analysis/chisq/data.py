"""The χ² fit's input: the stacked radial profiles of both cameras per setting, and their checks."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from analysis.stack import StackResult
from analysis.transport.disk import BandPixels


class FitInputError(ValueError):
    """The data cannot be fitted (too few frames, a camera missing, nothing unsaturated...)."""


@dataclass(frozen=True)
class ProfileData:
    """One camera's stacked radial profile at one setting.

    ``mean_gray``/``sem_gray``/``count`` are the band means of the stacked
    crop after rejecting outlying pixels per band (hot pixels and specks,
    see `BandPixels.clipped_profile`), ``background_gray`` the constant of the
    stack's exponential + constant fit, ``pixels`` the geometry of its bands
    (for averaging the model the same way).
    """

    camera: str
    mean_gray: np.ndarray = field(repr=False)
    sem_gray: np.ndarray = field(repr=False)
    count: np.ndarray = field(repr=False)
    background_gray: float
    n_frames: int
    pixels: BandPixels = field(repr=False)

    @classmethod
    def from_stack(cls, camera: str, stack: StackResult) -> ProfileData:
        """From `analysis.stack.stack_frames` output (needs its measurement, pixels and centre)."""
        if stack.measurement is None or stack.stacked_pixels is None or stack.center_xy is None:
            raise FitInputError(f"camera {camera}: the stack carries no profile to fit")
        n = len(stack.measurement.profile.mean_gray)
        img = stack.stacked_pixels
        pixels = BandPixels.from_crop(img.shape, stack.center_xy, n, valid=np.isfinite(img))
        mean, sem, count = pixels.clipped_profile(img.ravel()[pixels.flat_index].astype(np.float64))
        return cls(
            camera=camera,
            mean_gray=mean,
            sem_gray=sem,
            count=count,
            background_gray=float(stack.background_gray),
            n_frames=stack.n_frames,
            pixels=pixels,
        )


@dataclass(frozen=True)
class SettingProfiles:
    """Near and far profiles taken at one exposure and gain."""

    exposure_s: float
    gain_db: float
    near: ProfileData
    far: ProfileData


def quantisation_bias_gray(sem_gray: np.ndarray, count: np.ndarray, n_frames: np.ndarray) -> np.ndarray:
    """Bound on the bias of a band mean from the 8-bit rounding of faint, little-noisy pixels.

    Rounding is linear on average only when the pixel noise dithers it: for
    Gaussian noise σ (gray) the mean of rounded values departs from the true
    level by up to exp(-2π²σ²)/π (the first term of its Fourier series),
    0.03 gray at σ = 0.3 (low gain) but 3·10⁻⁴ at σ = 0.6. σ is the
    single-frame pixel noise, sem·sqrt(count·n_frames) of the stacked band.
    The bias changes with the level and is alike in neighbouring bands, so
    it is neither subtracted nor treated as noise: bands where it could
    exceed a fraction of the statistical error are left out of the fit
    (`FitConfig.max_quantisation_bias`).
    """
    sigma = np.nan_to_num(sem_gray) * np.sqrt(np.maximum(count, 1.0) * n_frames)
    return np.exp(-2.0 * math.pi**2 * sigma * sigma) / math.pi


def collect_settings(
    stacks: Mapping[tuple[str, Any], StackResult],
    wavelength_nm: int,
    near_camera: str,
    far_camera: str,
    min_frames: int = 3,
) -> list[SettingProfiles]:
    """The settings of one wavelength where both cameras have stacked, unsaturated frames.

    ``stacks`` maps ``(camera, setting)`` to stacks (`analysis.dataset.stack_by_setting`),
    settings having ``wavelength_nm``, ``exposure_s`` and ``gain_db``. Raises
    `FitInputError` with the reason when nothing can be fitted: a camera
    without accepted frames, fewer than ``min_frames`` accepted frames from a
    camera, or no setting shared by both.
    """
    by_cam: dict[str, dict[tuple[float, float], StackResult]] = {near_camera: {}, far_camera: {}}
    for (camera, setting), stack in stacks.items():
        if getattr(setting, "wavelength_nm", None) != wavelength_nm or camera not in by_cam:
            continue
        by_cam[camera][(setting.exposure_s, setting.gain_db)] = stack  # type: ignore[attr-defined]
    for cam, role in ((near_camera, "near"), (far_camera, "far")):
        n = sum(s.n_frames for s in by_cam[cam].values())
        if n == 0:
            raise FitInputError(
                f"{wavelength_nm} nm: no accepted (unsaturated) frame from the {role} camera {cam}"
            )
        if n < min_frames:
            raise FitInputError(
                f"{wavelength_nm} nm: only {n} accepted frame(s) from the {role} camera {cam}; "
                f"the χ² fit needs at least {min_frames}"
            )
    shared = sorted(set(by_cam[near_camera]) & set(by_cam[far_camera]))
    if not shared:
        raise FitInputError(
            f"{wavelength_nm} nm: no exposure/gain setting with accepted frames from both cameras "
            f"{near_camera} and {far_camera}"
        )
    return [
        SettingProfiles(
            e,
            g,
            ProfileData.from_stack(near_camera, by_cam[near_camera][(e, g)]),
            ProfileData.from_stack(far_camera, by_cam[far_camera][(e, g)]),
        )
        for e, g in shared
    ]
