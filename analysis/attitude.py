"""Attitude of a module from its accelerometer and gyroscope.

The module hangs on a vertical cable with its camera looking along it. At
rest the accelerometer reads gravity along the module's axis (z); a tilt
from vertical moves part of gravity into x and y. The ship's heave shakes
the cable and shows as a periodic vertical acceleration (5-10 s at T-REX).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class AttitudeEstimate:
    """Tilt from vertical (total and about each axis), rotation rate and heave.

    ``heave_period_s`` is the period of the strongest oscillation of the
    vertical acceleration between 2 and 30 s (None without enough data);
    ``heave_amplitude_m_s2`` its amplitude.
    """

    tilt_deg: float
    tilt_x_deg: float
    tilt_y_deg: float
    rotation_rate_dps: float
    heave_period_s: float | None
    heave_amplitude_m_s2: float | None


def tilt_from_acceleration(acc_m_s2: np.ndarray) -> tuple[float, float, float]:
    """Tilt (total, about x, about y) in degrees from mean accelerations ``[..., 3]``.

    Averaging first removes the heave and the noise; the direction of the
    mean is the direction of gravity in the module's frame.
    """
    a = np.asarray(acc_m_s2, dtype=np.float64).reshape(-1, 3).mean(axis=0)
    ax, ay, az = (float(v) for v in a)
    total = math.degrees(math.atan2(math.hypot(ax, ay), az))
    return total, math.degrees(math.atan2(ax, az)), math.degrees(math.atan2(ay, az))


def heave(
    t_s: np.ndarray, acc_z_m_s2: np.ndarray, min_period_s: float = 2.0, max_period_s: float = 30.0
) -> tuple[float | None, float | None]:
    """Dominant period and amplitude of the vertical acceleration, by FFT.

    The samples are resampled onto a uniform grid (the sensor clock jitters
    and packets may be missing), detrended, windowed (Hann), and the peak
    of the amplitude spectrum between ``1/max_period_s`` and
    ``1/min_period_s`` is refined by a parabola through its neighbours.
    Needs at least three periods of data.
    """
    t = np.asarray(t_s, dtype=np.float64)
    z = np.asarray(acc_z_m_s2, dtype=np.float64)
    ok = np.isfinite(t) & np.isfinite(z)
    t, z = t[ok], z[ok]
    if t.size < 16 or t[-1] - t[0] < 3 * min_period_s:
        return None, None
    order = np.argsort(t)
    t, z = t[order], z[order]
    dt = float(np.median(np.diff(t)))
    if not dt > 0:
        return None, None
    n = int((t[-1] - t[0]) / dt) + 1
    grid = t[0] + np.arange(n) * dt
    zi = np.interp(grid, t, z)
    zi = zi - np.polyval(np.polyfit(grid - grid[0], zi, 1), grid - grid[0])
    window = np.hanning(n)
    spec = np.abs(np.fft.rfft(zi * window))
    freq = np.fft.rfftfreq(n, dt)
    band = (freq >= 1.0 / max_period_s) & (freq <= 1.0 / min_period_s)
    if not band.any() or freq[band][0] * (t[-1] - t[0]) < 1.0:
        return None, None
    idx = np.flatnonzero(band)
    k = int(idx[np.argmax(spec[idx])])
    f = float(freq[k])
    if 0 < k < len(spec) - 1:
        a, b, c = spec[k - 1], spec[k], spec[k + 1]
        denom = a - 2 * b + c
        if denom != 0:
            f = float(freq[k] + 0.5 * (a - c) / denom * (freq[1] - freq[0]))
    amplitude = float(2.0 * spec[k] / window.sum())
    return (1.0 / f if f > 0 else None), amplitude


def attitude_from_samples(
    t_s: np.ndarray, acc_m_s2: np.ndarray, gyro_dps: np.ndarray, tilt_window_s: float = 2.0
) -> AttitudeEstimate:
    """Tilt over the last ``tilt_window_s``, rotation rate, and heave over all samples given."""
    t = np.asarray(t_s, dtype=np.float64)
    acc = np.asarray(acc_m_s2, dtype=np.float64).reshape(-1, 3)
    gyro = np.asarray(gyro_dps, dtype=np.float64).reshape(-1, 3)
    if t.size == 0:
        raise ValueError("attitude needs at least one sample")
    recent = t >= t.max() - tilt_window_s
    total, tx, ty = tilt_from_acceleration(acc[recent])
    rate = float(np.linalg.norm(gyro[recent], axis=1).mean()) if gyro.size else 0.0
    period, amp = heave(t, acc[:, 2])
    return AttitudeEstimate(total, tx, ty, rate, period, amp)
