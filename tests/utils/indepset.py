"""A station frame set drawn without camcal's simulator: its own renderer, LEM, sensor, schedule and water.

What it shares with camcal is only the frame-set format and the geometry
(T-REX distances, emission ratios and plate scale). Everything else is
its own and differs from `lrm.sim`/`lrm.dive` on purpose:

* the water: λ_att of every wavelength steady, then falling linearly to
  65 % over 8 min, steady, and back up to 90 % (the dive simulator's is a
  smooth bump);
* the LEM: a uniform disk whose brightness drifts down 4 % over the run
  and flickers 0.5 % from frame to frame; dark for 6 s between blocks of
  one wavelength (90 s each);
* the optics: a Moffat PSF (β = 3, 2.2 px FWHM; the simulator's is
  Gaussian), a halo of the same share of the disk's radiance for both
  cameras (it cancels in the ratio, so the truth stays exact);
* the sensor: black level 0 (dark noise clipped at zero), 8 e⁻ read noise
  (0.8 gray at 8 dB), shot noise, fixed hot pixels, integer gray values;
* the schedule: each camera cycles three exposures, one frame every 3 s,
  camera B 0.7 s after A; the modules heave (pointing jitter ±4 px).

The truth is λ_att(wavelength, t) of the direct light, exact.
"""

from __future__ import annotations

import csv
import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path

import cv2
import numpy as np

from camcal.core.frameset import TREX_FOCAL_PX

DISTANCES_M = {"A": 21.56, "B": 41.62}
RATIOS = {405: 1.04, 460: 1.27, 525: 1.23}
BASE_LAMBDA_M = {405: 19.5, 460: 28.26, 525: 20.99}
LEM_RADIUS_M = 0.215
WIDTH_PX, HEIGHT_PX = 560, 480
#: Exposures [s] at 8 dB: the near disk ~35-200 gray, the far ~8-150, in the linear range whatever the water.
EXPOSURES_S = (0.01, 0.02, 0.03)
GAIN_DB = 8.0
E_PER_GRAY_0DB = 25.0  # electrons per gray value at 0 dB
READ_NOISE_E = 8.0
#: Electrons per second at 0 dB of the near disk's centre for a clear path (λ → ∞).
CLEAR_RATE_E_PER_S = {405: 2.0e5, 460: 1.41e5, 525: 1.84e5}
DWELL_S, DARK_S, FRAME_EVERY_S, B_LAG_S = 90.0, 6.0, 3.0, 0.7
WAVELENGTHS = (405, 460, 525)


def water_factor(t_s: float) -> float:
    """λ_att(t) / λ_att(0): steady, a linear fall to 0.65, steady, a rise to 0.9."""
    points = [(0.0, 1.0), (320.0, 1.0), (800.0, 0.65), (1120.0, 0.65), (1440.0, 0.9), (1e9, 0.9)]
    for (t0, v0), (t1, v1) in itertools.pairwise(points):
        if t_s <= t1:
            return v0 + (v1 - v0) * (t_s - t0) / (t1 - t0)
    return points[-1][1]


def lambda_truth_m(wavelength_nm: int, t_s: float) -> float:
    return BASE_LAMBDA_M[wavelength_nm] * water_factor(t_s)


def lem_state(t_s: float) -> int | None:
    """The wavelength the LEM shows at ``t_s``, None while it is dark between blocks."""
    k, into = divmod(t_s, DWELL_S + DARK_S)
    return None if into >= DWELL_S else WAVELENGTHS[int(k) % 3]


def moffat_kernel(fwhm_px: float = 2.2, beta: float = 3.0, half_px: int = 12) -> np.ndarray:
    alpha = fwhm_px / (2 * math.sqrt(2 ** (1 / beta) - 1))
    y, x = np.mgrid[-half_px : half_px + 1, -half_px : half_px + 1]
    k = (1 + (x * x + y * y) / alpha**2) ** -beta
    return (k / k.sum()).astype(np.float32)


@dataclass
class Station:
    """Draws the frames; ``seed`` fixes the noise, the jitter, the flicker and the hot pixels."""

    seed: int
    duration_s: float = 1600.0

    def __post_init__(self) -> None:
        self.rng = np.random.default_rng(self.seed)
        self.kernel = moffat_kernel()
        self.hot = {c: self.rng.integers(0, [HEIGHT_PX, WIDTH_PX], size=(15, 2)) for c in DISTANCES_M}
        yy, xx = np.mgrid[0:HEIGHT_PX, 0:WIDTH_PX]
        self.yy, self.xx = yy.astype(np.float32), xx.astype(np.float32)

    def frame(self, camera: str, t_s: float, exposure_s: float) -> np.ndarray:
        wl = lem_state(t_s)
        distance = DISTANCES_M[camera]
        radius_px = TREX_FOCAL_PX * LEM_RADIUS_M / math.sqrt(distance**2 - LEM_RADIUS_M**2)
        cx = WIDTH_PX / 2 + self.rng.uniform(-4, 4)
        cy = HEIGHT_PX / 2 + self.rng.uniform(-4, 4)
        r = np.hypot(self.xx - cx, self.yy - cy)
        electrons = np.zeros((HEIGHT_PX, WIDTH_PX), np.float32)
        if wl is not None:
            lam = lambda_truth_m(wl, t_s)
            toward = 1.0 if camera == "A" else RATIOS[wl]
            lem = (1 - 0.04 * t_s / self.duration_s) * self.rng.normal(1.0, 0.005)
            path = math.exp(-(distance - LEM_RADIUS_M) / lam)
            centre = CLEAR_RATE_E_PER_S[wl] * exposure_s * toward * lem * path
            disk = np.clip(radius_px + 0.5 - r, 0.0, 1.0)
            halo = 0.03 * np.exp(-np.maximum(r - radius_px, 0.0) / (0.8 * radius_px))
            electrons = (centre * (disk + halo * (1 - disk))).astype(np.float32)
            electrons = cv2.filter2D(electrons, -1, self.kernel, borderType=cv2.BORDER_REFLECT)
        gain = 10 ** (GAIN_DB / 20) / E_PER_GRAY_0DB
        # shot noise (Gaussian at these counts) and read noise in one draw
        sigma_e = np.sqrt(np.maximum(electrons, 0.0) + READ_NOISE_E**2)
        signal = electrons + sigma_e * self.rng.standard_normal(electrons.shape, dtype=np.float32)
        gray = np.clip(np.round(signal * gain), 0, 255).astype(np.uint8)
        hot = self.hot[camera]
        gray[hot[:, 0], hot[:, 1]] = 255
        return gray

    def write(self, folder: Path, start: datetime, progress: Callable[[int, int], None] | None = None) -> int:
        """Write the frame set into ``folder``; returns the number of frames."""
        folder.mkdir(parents=True)
        shots = []
        for camera, lag in (("A", 0.0), ("B", B_LAG_S)):
            k = 0
            while k * FRAME_EVERY_S + lag < self.duration_s:
                shots.append((k * FRAME_EVERY_S + lag, camera, k))
                k += 1
        shots.sort()
        columns = ["file", "camera", "wavelength_nm", "exposure_s", "gain_db", "timestamp", "depth_m", "seq"]
        with open(folder / "manifest.csv", "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(columns)
            last = {c: WAVELENGTHS[0] for c in DISTANCES_M}
            for n, (t, camera, k) in enumerate(shots):
                wl = lem_state(t)
                if wl is not None:
                    last[camera] = wl
                wl_row = last[camera]  # the module thinks the last block's wavelength goes on
                exposure = EXPOSURES_S[k % 3]
                name = f"{camera}_{k + 1:05d}.png"
                ok, png = cv2.imencode(".png", self.frame(camera, t, exposure))
                assert ok
                (folder / name).write_bytes(png.tobytes())
                stamp = (start + timedelta(seconds=t)).strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z"
                depth = 3420.0 + 1.5 * math.sin(2 * math.pi * t / 7.0) - (0.0 if camera == "A" else 20.06)
                w.writerow([name, camera, wl_row, exposure, GAIN_DB, stamp, f"{depth:.2f}", k + 1])
                if progress:
                    progress(n + 1, len(shots))
        return len(shots)


START = datetime(2026, 11, 27, 6, 0, tzinfo=UTC)


def visit_truth_m(wavelength_nm: int, t_first_s: float, t_last_s: float) -> float:
    """λ_att a visit measures: of its mean log ratio over its span (the water need not be linear in it)."""
    ts = np.linspace(t_first_s, t_last_s, 200)
    return 1.0 / float(np.mean([1.0 / lambda_truth_m(wavelength_nm, t) for t in ts]))
