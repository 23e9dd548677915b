"""The camera model: optics, sensor response, noise and defects."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class CameraModel:
    """A monochrome CMOS camera behind a pinhole, as in the T-REX LRMs.

    Defaults: 5 MP (2448 x 2048), 8-bit, ~16° horizontal field of view in
    water (25 mm lens). Gray values follow

        gray = black_level + electrons * gray_per_electron * 10**(gain_db / 20)

    with shot noise on the electrons, read noise, a soft compression of the
    response above ``knee_gray`` (the sensor leaves linearity before the ADC
    clips at 255), quantisation and clipping to 0..255.
    """

    width_px: int = 2448
    height_px: int = 2048
    fov_deg: float = 16.0
    gray_per_electron: float = 0.04
    read_noise_e: float = 3.0
    black_level_gray: float = 2.4
    dark_current_e_per_s: float = 5.0
    psf_sigma_px: float = 1.2
    knee_gray: float = 240.0
    hot_pixel_fraction: float = 2e-5
    exposure_range_s: tuple[float, float] = (1e-4, 2.0)
    gain_range_db: tuple[float, float] = (0.0, 24.0)
    gain_step_db: float = 0.1

    def __post_init__(self) -> None:
        if self.width_px < 16 or self.height_px < 16:
            raise ValueError(f"sensor must be at least 16 x 16 px, got {self.width_px} x {self.height_px}")
        if not (0.5 < self.fov_deg < 120):
            raise ValueError(f"fov_deg must lie in (0.5, 120), got {self.fov_deg}")
        if not (0.0 <= self.black_level_gray < 200.0):
            raise ValueError(f"black_level_gray must lie in [0, 200), got {self.black_level_gray}")
        if not (0.0 <= self.read_noise_e < 1000.0):
            raise ValueError(f"read_noise_e must lie in [0, 1000), got {self.read_noise_e}")

    @property
    def focal_px(self) -> float:
        """Focal length in pixels from the horizontal field of view."""
        return (self.width_px / 2.0) / math.tan(math.radians(self.fov_deg) / 2.0)

    @property
    def center_xy(self) -> tuple[float, float]:
        """Optical axis on the sensor (the centre of the frame)."""
        return ((self.width_px - 1) / 2.0, (self.height_px - 1) / 2.0)

    def gain_factor(self, gain_db: float) -> float:
        return 10.0 ** (gain_db / 20.0)

    def check_setting(self, exposure_s: float, gain_db: float) -> None:
        """Raise `ValueError` naming the setting if the camera cannot take it."""
        lo, hi = self.exposure_range_s
        if not (lo <= exposure_s <= hi):
            raise ValueError(f"exposure_s {exposure_s} outside the camera's range [{lo}, {hi}] s")
        glo, ghi = self.gain_range_db
        if not (glo <= gain_db <= ghi):
            raise ValueError(f"gain_db {gain_db} outside the camera's range [{glo}, {ghi}] dB")

    def respond(self, gray: np.ndarray) -> np.ndarray:
        """Soft compression above the knee: linear below, asymptotic to 255 above."""
        knee = self.knee_gray
        span = 255.5 - knee
        over = gray > knee
        if np.any(over):
            gray = gray.copy()
            gray[over] = knee + span * np.tanh((gray[over] - knee) / span)
        return gray

    def hot_pixels(self, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Fixed hot pixels of this sensor: rows, columns and dark current in e/s.

        They belong to the sensor (seeded by the camera's identity), so they sit
        at the same places in every frame, as real hot pixels do.
        """
        rng = np.random.default_rng(seed)
        n = round(self.hot_pixel_fraction * self.width_px * self.height_px)
        rows = rng.integers(0, self.height_px, n)
        cols = rng.integers(0, self.width_px, n)
        rate = 10.0 ** rng.uniform(4.0, 6.5, n)
        return rows, cols, rate
