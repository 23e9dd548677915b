"""Attenuation length from near/far I_center pairs, with its errors.

For the two cameras at distances ``L_near < L_far`` and the LEM's emission
ratio ``r = I0'/I0`` (toward the far camera over toward the near one)::

    I_near = I0  * f * exp(-L_near / lambda_att)
    I_far  = I0' * f * exp(-L_far  / lambda_att)
    lambda_att = (L_far - L_near) / ln( (I_near / I_far) * r )

The transmission ``f`` of the housings cancels. Statistical errors come from
the I values; systematic ones from the two distances and the emission ratio,
which are common to every pair of a wavelength and so are propagated once, at
the combined value.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field


@dataclass(frozen=True)
class Geometry:
    """The two cameras of an attenuation measurement and their LEM distances."""

    near_camera: str
    far_camera: str
    distance_near_m: float
    distance_near_err_m: float
    distance_far_m: float
    distance_far_err_m: float

    def __post_init__(self) -> None:
        if not (0 < self.distance_near_m < self.distance_far_m):
            raise ValueError(
                "distances must satisfy 0 < near < far, got "
                f"{self.distance_near_m} m and {self.distance_far_m} m"
            )
        if self.distance_near_err_m < 0 or self.distance_far_err_m < 0:
            raise ValueError("distance errors must be >= 0")

    @property
    def baseline_m(self) -> float:
        return self.distance_far_m - self.distance_near_m

    @property
    def baseline_err_m(self) -> float:
        return math.hypot(self.distance_near_err_m, self.distance_far_err_m)


@dataclass(frozen=True)
class EmissionRatio:
    """I0'/I0: the LEM's intensity toward the far camera over toward the near one."""

    value: float
    err: float = 0.0

    def __post_init__(self) -> None:
        if not self.value > 0 or self.err < 0:
            raise ValueError(f"emission ratio must be > 0 with err >= 0, got {self.value} ± {self.err}")


def attenuation_length_m(
    i_near: float,
    i_far: float,
    distance_near_m: float,
    distance_far_m: float,
    emission_ratio: float,
) -> float:
    """``(L_far - L_near) / ln((I_near / I_far) * emission_ratio)``.

    Raises `ValueError` when an intensity is not positive or when the log is
    not positive (the far camera sees as much light as the near one: no
    attenuation can be measured).
    """
    if not (i_near > 0 and i_far > 0):
        raise ValueError(f"intensities must be > 0, got I_near={i_near}, I_far={i_far}")
    x = math.log(i_near / i_far * emission_ratio)
    if not x > 0:
        raise ValueError(
            f"ln((I_near/I_far)·ratio) = {x:.4g} <= 0: the far camera is not dimmer, "
            "so no attenuation length follows"
        )
    return (distance_far_m - distance_near_m) / x


@dataclass(frozen=True)
class PairResult:
    """One near/far pair at equal wavelength, exposure and gain."""

    wavelength_nm: int
    exposure_s: float
    gain_db: float
    i_near_gray: float
    i_near_err_gray: float
    i_far_gray: float
    i_far_err_gray: float
    n_near: int
    n_far: int
    log_ratio: float
    log_ratio_err: float
    lambda_att_m: float | None
    stat_err_m: float | None
    sys_err_m: float | None


@dataclass(frozen=True)
class AttenuationResult:
    """λ_att of one wavelength combined over its pairs.

    ``chi2_ndof`` measures how well the pairs agree; when it exceeds 1 the
    statistical error has been scaled by its square root. ``lambda_att_m`` is
    None (with ``note``) when the combined ratio shows no attenuation.
    """

    wavelength_nm: int
    lambda_att_m: float | None
    stat_err_m: float | None
    sys_err_m: float | None
    n_pairs: int
    chi2_ndof: float
    log_ratio: float
    log_ratio_err: float
    emission_ratio: EmissionRatio
    geometry: Geometry
    pairs: tuple[PairResult, ...] = field(repr=False)
    note: str | None = None

    @property
    def total_err_m(self) -> float | None:
        if self.stat_err_m is None or self.sys_err_m is None:
            return None
        return math.hypot(self.stat_err_m, self.sys_err_m)


def not_dimmer_note(log_ratio: float, ratio: EmissionRatio) -> str:
    """Why no λ_att follows when ln(I_near/I_far) + ln(I0'/I0) <= 0, naming both terms: the
    cameras' intensities, or an emission ratio that is wrong (a far camera that is dimmer in the
    frames can still come out "not dimmer" once a too small I0'/I0 is applied)."""
    lead = (
        "the far camera is not dimmer than the near one"
        if log_ratio <= 0
        else f"I0'/I0 = {ratio.value:g} outweighs how much dimmer the far camera is"
    )
    return (
        f"{lead} (ln(I_near/I_far) = {log_ratio:.3g}, ln(I0'/I0) = {math.log(ratio.value):.3g}): "
        "no attenuation measurable; check the emission ratio and which camera is near"
    )


def _lambda_with_errors(
    log_ratio: float, log_ratio_err: float, geometry: Geometry, ratio: EmissionRatio
) -> tuple[float | None, float | None, float | None]:
    x = log_ratio + math.log(ratio.value)
    if not x > 0:
        return None, None, None
    baseline = geometry.baseline_m
    lam = baseline / x
    dlam_dx = lam * lam / baseline  # |d lambda / d x|
    stat = dlam_dx * log_ratio_err
    sys = math.hypot(geometry.baseline_err_m / x, dlam_dx * ratio.err / ratio.value)
    return lam, stat, sys


def pair_result(
    wavelength_nm: int,
    exposure_s: float,
    gain_db: float,
    near: tuple[float, float, int],
    far: tuple[float, float, int],
    geometry: Geometry,
    ratio: EmissionRatio,
) -> PairResult:
    """λ_att from one pair; ``near`` and ``far`` are ``(I, I_err, n_frames)``."""
    (i_n, e_n, n_n), (i_f, e_f, n_f) = near, far
    if i_n > 0 and i_f > 0:
        q = math.log(i_n / i_f)
        q_err = math.hypot(e_n / i_n, e_f / i_f)
        lam, stat, sys = _lambda_with_errors(q, q_err, geometry, ratio)
    else:
        q, q_err, lam, stat, sys = float("nan"), float("nan"), None, None, None
    return PairResult(
        wavelength_nm, exposure_s, gain_db, i_n, e_n, i_f, e_f, n_n, n_f, q, q_err, lam, stat, sys
    )


def combine_pairs(pairs: Sequence[PairResult], geometry: Geometry, ratio: EmissionRatio) -> AttenuationResult:
    """Combine the pairs of one wavelength.

    The log ratios ``ln(I_near/I_far)`` are averaged with inverse-variance
    weights (they are the quantity whose errors are Gaussian), the statistical
    error is scaled by sqrt(chi2/ndof) when the pairs disagree beyond their
    errors, and λ_att with its systematic error follows from the mean.
    """
    usable = [p for p in pairs if math.isfinite(p.log_ratio) and p.log_ratio_err > 0]
    if not usable:
        raise ValueError("no usable near/far pair to combine")
    wavelengths = {p.wavelength_nm for p in usable}
    if len(wavelengths) != 1:
        raise ValueError(f"pairs of one wavelength expected, got {sorted(wavelengths)}")
    weights = [1.0 / p.log_ratio_err**2 for p in usable]
    wsum = sum(weights)
    mean = sum(w * p.log_ratio for w, p in zip(weights, usable, strict=True)) / wsum
    err = 1.0 / math.sqrt(wsum)
    ndof = len(usable) - 1
    chi2 = sum(w * (p.log_ratio - mean) ** 2 for w, p in zip(weights, usable, strict=True))
    chi2_ndof = chi2 / ndof if ndof > 0 else 0.0
    if chi2_ndof > 1.0:
        err *= math.sqrt(chi2_ndof)
    lam, stat, sys = _lambda_with_errors(mean, err, geometry, ratio)
    note = None
    if lam is None:
        note = not_dimmer_note(mean, ratio)
    return AttenuationResult(
        wavelength_nm=usable[0].wavelength_nm,
        lambda_att_m=lam,
        stat_err_m=stat,
        sys_err_m=sys,
        n_pairs=len(usable),
        chi2_ndof=chi2_ndof,
        log_ratio=mean,
        log_ratio_err=err,
        emission_ratio=ratio,
        geometry=geometry,
        pairs=tuple(usable),
        note=note,
    )
