"""Lab scenes for the calibrations of the camera system.

What the lab adds to the deep-sea simulator (`lrm.sim.render`):

* media other than seawater: `air` (Rayleigh scattering only, attenuation
  lengths of tens of kilometres) and the `tap_water` of a test tank;
* a LEM whose brightness and emission ratio depend on temperature
  (`TemperatureModel`), for the cold-room calibration;
* a point-like source imaged through the PSF (`PointSourceRenderer`), for
  the focus check;
* the camera's mean response including noise (`expected_mean_gray`), the
  truth a linearity calibration is compared with.

Extended sources (the LEM, the tank's Teflon ball) are drawn by
`lrm.sim.render.FrameRenderer` in these media, so the lab and the sea share
one renderer.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.special import ndtr

from analysis.scattering import WaterOptics
from lrm.sim.camera import CameraModel
from lrm.sim.scene import LEMModel, Water

#: Rayleigh scattering length of sea-level air at 550 nm (optical depth ~0.097
#: over an 8 km scale height); it scales as wavelength**4.
AIR_RAYLEIGH_LENGTH_550_M = 82_000.0
#: Absorption of clean air in the visible is negligible: a length no scan can see.
AIR_ABSORPTION_LENGTH_M = 1.0e9

#: (absorption, scattering) lengths of the test tank's tap water, in metres:
#: attenuation 5.2 / 7.5 / 7.1 m, the few metres typical of tap water.
TAP_WATER_LENGTHS_M: dict[int, tuple[float, float]] = {
    405: (8.0, 15.0),
    460: (12.0, 20.0),
    525: (10.0, 25.0),
}


def air(wavelengths_nm: tuple[int, ...] = (405, 460, 525)) -> Water:
    """Air: pure Rayleigh scattering, λ_sca = 82 km (λ/550 nm)^4, no absorption.

    Over a 41 m scan the centre gray falls by ~0.1 % at 405 nm: the
    "negligible attenuation of air" of the long-distance test, but not zero.
    """
    optics = {
        wl: WaterOptics(
            AIR_ABSORPTION_LENGTH_M,
            AIR_RAYLEIGH_LENGTH_550_M * (wl / 550.0) ** 4,
            mie_g=0.0,
            rayleigh_fraction=1.0,
            refractive_index=1.0003,
        )
        for wl in wavelengths_nm
    }
    return Water(optics, name="air")


def tap_water() -> Water:
    """The test tank's tap water (`TAP_WATER_LENGTHS_M`), Mie-dominated like seawater."""
    return Water({wl: WaterOptics(a, s) for wl, (a, s) in TAP_WATER_LENGTHS_M.items()}, name="tap")


@dataclass(frozen=True)
class TemperatureModel:
    """How the LEM changes with temperature, relative to ``reference_c``.

    ``brightness_per_c``: relative change of the LEDs' output per °C (LEDs
    dim as they warm). ``ratio_per_c``: relative change of I0'/I0 per °C;
    the T-REX lab saw < 1 % between 2 °C and 19 °C, so the defaults move the
    ratio by 0.5-0.8 % over that span. The LEM's nominal values hold at the
    reference temperature (2 °C, the deep sea).
    """

    reference_c: float = 2.0
    brightness_per_c: Mapping[int, float] = field(
        default_factory=lambda: {405: -0.004, 460: -0.003, 525: -0.005}
    )
    ratio_per_c: Mapping[int, float] = field(default_factory=lambda: {405: 3e-4, 460: 4e-4, 525: 5e-4})

    def ratio_factor(self, wavelength_nm: int, temperature_c: float) -> float:
        return 1.0 + self.ratio_per_c.get(wavelength_nm, 0.0) * (temperature_c - self.reference_c)

    def brightness_factor(self, wavelength_nm: int, temperature_c: float) -> float:
        return 1.0 + self.brightness_per_c.get(wavelength_nm, 0.0) * (temperature_c - self.reference_c)

    def lem_at(self, lem: LEMModel, temperature_c: float) -> LEMModel:
        """The LEM as it shines at ``temperature_c``."""
        if not (-50.0 < temperature_c < 80.0):
            raise ValueError(f"temperature_c must lie in (-50, 80), got {temperature_c}")
        radiance = {
            wl: b * self.brightness_factor(wl, temperature_c) for wl, b in lem.radiance_e_per_s.items()
        }
        ratio = {wl: r * self.ratio_factor(wl, temperature_c) for wl, r in lem.emission_ratio.items()}
        return replace(lem, radiance_e_per_s=radiance, emission_ratio=ratio)


def expose(
    camera: CameraModel,
    electrons: np.ndarray,
    exposure_s: float,
    gain_db: float,
    rng: np.random.Generator,
    hot: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """Turn the source electrons of one exposure into an 8-bit frame.

    The sensor chain of `CameraModel`: dark current and hot pixels add
    electrons, shot and read noise, gain, black level, the soft knee above
    ``knee_gray``, clipping to 0..255 and rounding. ``electrons`` is not modified.
    """
    camera.check_setting(exposure_s, gain_db)
    e = electrons.astype(np.float64) + camera.dark_current_e_per_s * exposure_s
    if hot is not None:
        rows, cols, rate = hot
        e[rows, cols] += rate * exposure_s
    gain_total = camera.gray_per_electron * camera.gain_factor(gain_db)
    noisy = e + np.sqrt(e + camera.read_noise_e**2) * rng.standard_normal(e.shape)
    gray = camera.respond(noisy * gain_total + camera.black_level_gray)
    return (np.clip(gray, 0.0, 255.0) + 0.5).astype(np.uint8)


def _inverse_response(camera: CameraModel, gray: np.ndarray) -> np.ndarray:
    """The gray a linear sensor would have given for each ``gray`` after the soft knee."""
    knee, span = camera.knee_gray, 255.5 - camera.knee_gray
    over = gray > knee
    out = gray.astype(np.float64).copy()
    out[over] = knee + span * np.arctanh(np.minimum((gray[over] - knee) / span, 1 - 1e-15))
    return out


def expected_mean_gray(
    camera: CameraModel, electrons: float | np.ndarray, gain_db: float | np.ndarray
) -> np.ndarray:
    """Mean gray of a pixel collecting ``electrons`` (dark current included): noise, knee and 8 bits included.

    The sensor reports ``k = floor(clip(respond(v), 0, 255) + 0.5)`` of a
    Gaussian ``v`` (shot and read noise), so its mean is
    ``sum over k = 1..255 of P(respond(v) >= k - 0.5)``, each term a normal
    tail beyond the knee's inverse of ``k - 0.5``. Exact for the simulated
    sensor, where quadrature would not be: with little noise the 8-bit
    steps bias the mean (the dark level of 2.4 gray reads ~2.2 at 0 dB),
    and near the knee the noise compresses it. ``electrons`` and ``gain_db``
    broadcast against each other.
    """
    e, g = np.broadcast_arrays(np.asarray(electrons, dtype=np.float64), np.asarray(gain_db, dtype=np.float64))
    gain_total = camera.gray_per_electron * 10.0 ** (g / 20.0)
    mean = e * gain_total + camera.black_level_gray
    sigma = np.sqrt(np.maximum(e, 0.0) + camera.read_noise_e**2) * gain_total
    thresholds = _inverse_response(camera, np.arange(1, 256) - 0.5)
    z = (thresholds - mean[..., None]) / sigma[..., None]
    return np.sum(ndtr(-z), axis=-1)


def departure_gray(
    camera: CameraModel, electrons: np.ndarray | float, gain_db: np.ndarray | float, tolerance: float
) -> float:
    """The mean gray at which the expected response first falls ``tolerance`` below the line.

    ``electrons`` and ``gain_db`` trace a sweep finely in increasing light
    (exposures at a fixed gain, or gains at a fixed exposure). At each
    step the signal above the black level is compared with what a linear
    sensor would give; the first step where the shortfall reaches
    ``tolerance`` of the signal is returned, as the gray a frame shows there.
    """
    e, g = np.broadcast_arrays(np.asarray(electrons, dtype=np.float64), np.asarray(gain_db, dtype=np.float64))
    signal = e * camera.gray_per_electron * 10.0 ** (g / 20.0)
    mean = expected_mean_gray(camera, e, g)
    short = (signal - (mean - camera.black_level_gray)) / np.maximum(signal, 1e-12) >= tolerance
    short &= signal > 1.0
    if not short.any():
        raise ValueError(f"the response never leaves linearity by {tolerance} along this sweep")
    return float(mean[int(np.argmax(short))])


@dataclass(frozen=True)
class PointSourceTruth:
    """What the simulator knows about a point-source frame."""

    x_px: float
    y_px: float
    psf_sigma_px: float
    flux_gray: float
    peak_gray: float

    def to_dict(self) -> dict[str, float]:
        return {
            "x_px": self.x_px,
            "y_px": self.y_px,
            "psf_sigma_px": self.psf_sigma_px,
            "flux_gray": self.flux_gray,
            "peak_gray": self.peak_gray,
        }


class PointSourceRenderer:
    """Frames of a source far smaller than a pixel's field of view: the PSF itself.

    The PSF is a Gaussian of the camera's ``psf_sigma_px``. Each pixel
    collects the Gaussian over its area, computed by supersampling the pixel
    ``oversample``² times (independent of the erf model the analysis fits).
    """

    def __init__(self, camera: CameraModel, *, seed: int = 0, oversample: int = 10) -> None:
        if camera.psf_sigma_px <= 0:
            raise ValueError(f"a point source needs psf_sigma_px > 0, got {camera.psf_sigma_px}")
        if oversample < 2:
            raise ValueError(f"oversample must be >= 2, got {oversample}")
        self.camera = camera
        self.oversample = oversample
        self._hot = camera.hot_pixels(seed=seed)

    def psf_image(self, x_px: float, y_px: float, reach_px: int) -> tuple[np.ndarray, int, int]:
        """Fraction of the light on each pixel of a window around (x, y), and the window's origin."""
        cam, k = self.camera, self.oversample
        c0, r0 = math.floor(x_px) - reach_px, math.floor(y_px) - reach_px
        size = 2 * reach_px + 2
        sub = (np.arange(size * k) + 0.5) / k - 0.5  # sub-pixel centres, pixel units
        gx = np.exp(-0.5 * ((c0 + sub - x_px) / cam.psf_sigma_px) ** 2)
        gy = np.exp(-0.5 * ((r0 + sub - y_px) / cam.psf_sigma_px) ** 2)
        fx = gx.reshape(size, k).sum(axis=1)
        fy = gy.reshape(size, k).sum(axis=1)
        norm = 2.0 * math.pi * cam.psf_sigma_px**2 * k * k
        return fy[:, None] * fx[None, :] / norm, c0, r0

    def render(
        self,
        x_px: float,
        y_px: float,
        flux_e_per_s: float,
        exposure_s: float,
        gain_db: float,
        *,
        rng: np.random.Generator,
    ) -> tuple[np.ndarray, PointSourceTruth]:
        """One frame with the point source at ``(x_px, y_px)`` (frame coordinates)."""
        cam = self.camera
        if not (0 <= x_px <= cam.width_px - 1 and 0 <= y_px <= cam.height_px - 1):
            raise ValueError(f"point source at ({x_px}, {y_px}) lies outside the frame")
        electrons = np.zeros((cam.height_px, cam.width_px))
        reach = math.ceil(6 * cam.psf_sigma_px) + 1
        psf, c0, r0 = self.psf_image(x_px, y_px, reach)
        total = flux_e_per_s * exposure_s
        y0, x0 = max(r0, 0), max(c0, 0)
        y1, x1 = min(r0 + psf.shape[0], cam.height_px), min(c0 + psf.shape[1], cam.width_px)
        electrons[y0:y1, x0:x1] = total * psf[y0 - r0 : y1 - r0, x0 - c0 : x1 - c0]
        frame = expose(cam, electrons, exposure_s, gain_db, rng, self._hot)
        gain_total = cam.gray_per_electron * cam.gain_factor(gain_db)
        truth = PointSourceTruth(
            x_px=float(x_px),
            y_px=float(y_px),
            psf_sigma_px=cam.psf_sigma_px,
            flux_gray=total * gain_total,
            peak_gray=float(total * psf.max() * gain_total + cam.black_level_gray),
        )
        return frame, truth
