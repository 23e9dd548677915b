"""The blur of the LEM's image: a motion streak (a line kernel) and a Gaussian PSF, per frame.

`blur_image` is what `lrm.sim.render.FrameRenderer.render` applies to the
disk; `PsfJitter` draws a blur that changes from frame to frame, as sway and
focus make real frames' (σ ~0.8-2 px, some frames with a streak of a few
pixels): the disk's edge such frames show is what a fit must describe.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class PsfJitter:
    """A blur that changes from frame to frame, as sway and focus make real frames' (issue 35).

    Per frame a Gaussian PSF σ drawn uniformly in ``sigma_px`` and, on a
    share ``streak_fraction`` of the frames, a motion streak of length drawn
    uniformly in ``streak_px`` in a random direction (on top of the sway's).
    """

    sigma_px: tuple[float, float] = (0.8, 2.0)
    streak_fraction: float = 1.0 / 3.0
    streak_px: tuple[float, float] = (2.0, 6.0)

    def __post_init__(self) -> None:
        lo, hi = self.sigma_px
        if not 0 <= lo <= hi <= 20:
            raise ValueError(f"PSF σ range must satisfy 0 <= low <= high <= 20 px, got {self.sigma_px}")
        if not 0 <= self.streak_fraction <= 1:
            raise ValueError(f"streak fraction must lie in [0, 1], got {self.streak_fraction}")
        if not 0 <= self.streak_px[0] <= self.streak_px[1] <= 50:
            raise ValueError(
                f"streak length range must satisfy 0 <= low <= high <= 50 px, got {self.streak_px}"
            )

    def draw(self, rng: np.random.Generator) -> tuple[float, tuple[float, float]]:
        """One frame's PSF σ [px] and streak (dx, dy) [px]."""
        sigma = float(rng.uniform(*self.sigma_px))
        streak = (0.0, 0.0)
        if rng.random() < self.streak_fraction:
            length, angle = rng.uniform(*self.streak_px), rng.uniform(0.0, math.pi)
            streak = (float(length * math.cos(angle)), float(length * math.sin(angle)))
        return sigma, streak


def blur_image(image: np.ndarray, blur_px: tuple[float, float], psf_sigma_px: float) -> np.ndarray:
    """Motion blur along ``blur_px`` (a line kernel), then the Gaussian PSF."""
    length = math.hypot(*blur_px)
    if length >= 0.5:
        size = math.ceil(length) | 1
        size += 2
        kernel = np.zeros((size, size), dtype=np.float32)
        c = size // 2
        dx, dy = blur_px[0] / 2.0, blur_px[1] / 2.0
        n = max(math.ceil(length * 4), 2)
        for t in np.linspace(-1.0, 1.0, n):
            px, py = c + t * dx, c + t * dy
            ix, iy = math.floor(px), math.floor(py)
            fx, fy = px - ix, py - iy
            for ox, oy, w in (
                (0, 0, (1 - fx) * (1 - fy)),
                (1, 0, fx * (1 - fy)),
                (0, 1, (1 - fx) * fy),
                (1, 1, fx * fy),
            ):
                if 0 <= iy + oy < size and 0 <= ix + ox < size:
                    kernel[iy + oy, ix + ox] += w
        kernel /= kernel.sum()
        image = cv2.filter2D(image, -1, kernel, borderType=cv2.BORDER_CONSTANT)
    if psf_sigma_px > 0:
        image = cv2.GaussianBlur(image, (0, 0), psf_sigma_px, borderType=cv2.BORDER_CONSTANT)
    return image
