"""λ_att of one LEM visit: the near/far pairs of one run of a wavelength's frames.

A *visit* is a run of frames both cameras took while the LEM showed one
wavelength (a block of its timetable). Within a visit the frames of each
camera are stacked per setting (exposure, gain); a setting both cameras took
is a pair. The visit gives one λ_att, stamped at the mean time and mean LEM
depth of the frames its pairs used.

Near and far frames are not simultaneous, and the water may change during a
visit. Each camera's trend is fitted over the visit and its stacks are
interpolated to the visit's mean time (`camera_trend`); the trend's
uncertainty times the offset between the camera's frames and that time
enters the statistical error. When a camera's frames cannot show a trend
(too few, or all at one moment), a prior on how fast a camera's signal can
change bounds the mismatch instead: the correction is then ~0 and the
mismatch is carried in the error. That prior is sharpened by the
wavelength's earlier visits where there are two of them (`trend_prior`):
the change of each camera's level from one visit to the next is the
water's own trend (and the LEM's), so a visit whose frames are too few to
show a trend (a module lagging behind its schedule) is brought to its time
along it, with the change of that trend between the visits as its width.

Errors (one standard deviation, on the log ratio ``q = ln(I_near/I_far)``):

* **statistical**: per stack, the frames' scatter over sqrt(n) or the
  propagated per-frame errors (photon and read noise of the centre pixels
  and the background fit), whichever is larger; pairs combined by inverse
  variance; plus the trend term above; plus the **repeatability floor**:
  how well I_center repeats from visit to visit beyond the frames' own noise
  (the LEM's place in the frame, the background fit's reach and the residual
  scattered light change for every setting of a visit together, so this
  floor does not shrink with the number of frames or pairs);
* **systematic**: the two distances and I0'/I0, common to every visit of a
  wavelength, kept apart (`VisitResult.sys_err_m`).

Pure: arrays and numbers in, a frozen result out.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from analysis.attenuation import EmissionRatio, Geometry, not_dimmer_note


@dataclass(frozen=True)
class VisitFrame:
    """An accepted frame of a visit: its camera, setting, time, I_center and LEM depth."""

    camera: str
    exposure_s: float
    gain_db: float
    t_s: float
    i_gray: float
    i_err_gray: float
    lem_depth_m: float | None = None


@dataclass(frozen=True)
class CameraTrend:
    """d ln I / dt of one camera over a visit, from its frames and a prior.

    ``slope_per_s`` is the posterior mean of a fit of ``ln(I / (exposure ×
    linear gain))`` against time (the setting normalised out by the
    camera's linearity) combined with a zero-mean prior of width
    ``prior_per_s``; ``slope_err_per_s`` its error. ``fitted`` says whether
    the frames constrained the slope at all; ``prior`` where the prior came
    from (`TrendPrior.source`).
    """

    slope_per_s: float
    slope_err_per_s: float
    n_frames: int
    fitted: bool
    prior: str = "default"


@dataclass(frozen=True)
class CameraLevel:
    """A camera's mean ``ln(I / (exposure × linear gain))`` over a visit, at its frames' mean time.

    ``log_i_err`` is the frames' error alone (the scatter or the propagated
    errors, whichever is larger); visit-to-visit repeatability comes on top
    (`trend_prior`).
    """

    t_s: float
    log_i: float
    log_i_err: float
    n_frames: int


@dataclass(frozen=True)
class TrendPrior:
    """The prior on a camera's d ln I / dt in a visit: centre, width, and where it came from.

    ``source`` is ``"default"`` (zero, the setup's width) or ``"visits"``
    (the level's change over the wavelength's two previous visits and this one).
    """

    mean_per_s: float
    width_per_s: float
    source: str = "default"


@dataclass(frozen=True)
class VisitPair:
    """One setting both cameras took in a visit, interpolated to the visit's time."""

    exposure_s: float
    gain_db: float
    i_near_gray: float
    i_near_err_gray: float
    i_far_gray: float
    i_far_err_gray: float
    n_near: int
    n_far: int
    t_near_s: float
    t_far_s: float
    log_ratio: float
    log_ratio_err: float
    trend_shift: float


@dataclass(frozen=True)
class VisitResult:
    """λ_att of one visit with its errors and where and when its light was measured.

    ``t_s`` and ``lem_depth_m`` are the means over the frames used.
    ``stat_err_m`` holds every statistical term (frames, trend, floor);
    ``terms`` gives them on the log ratio. ``lambda_att_m`` is None (with
    ``note``) when the far camera is not dimmer than the near one.
    """

    wavelength_nm: int
    lambda_att_m: float | None
    stat_err_m: float | None
    sys_err_m: float | None
    log_ratio: float
    log_ratio_err: float
    t_s: float
    t_first_s: float
    t_last_s: float
    lem_depth_m: float | None
    n_frames: int
    n_pairs: int
    chi2_ndof: float
    terms: dict[str, float]
    pairs: tuple[VisitPair, ...]
    trends: dict[str, CameraTrend]
    note: str | None = None

    @property
    def total_err_m(self) -> float | None:
        if self.stat_err_m is None or self.sys_err_m is None:
            return None
        return math.hypot(self.stat_err_m, self.sys_err_m)


def stack_value(values: np.ndarray, errors: np.ndarray) -> tuple[float, float]:
    """Mean of a stack with its error: the scatter over sqrt(n) (n >= 3) or the propagated
    per-frame errors, whichever is larger."""
    n = values.size
    propagated = float(math.sqrt(float(np.sum(errors**2))) / n)
    scatter = float(values.std(ddof=1) / math.sqrt(n)) if n >= 3 else 0.0
    return float(values.mean()), max(scatter, propagated)


def _log_per_setting(i_gray: np.ndarray, exposure_s: np.ndarray, gain_db: np.ndarray) -> np.ndarray:
    """ln(I / (exposure × linear gain)): a camera's signal with its setting normalised out."""
    return np.log(i_gray / (exposure_s * 10.0 ** (gain_db / 20.0)))


def camera_level(frames: Sequence[VisitFrame], camera: str) -> CameraLevel | None:
    """``camera``'s level over a visit's frames (None: it has no usable frame)."""
    mine = [f for f in frames if f.camera == camera and f.i_gray > 0 and f.i_err_gray > 0]
    if not mine:
        return None
    i = np.array([f.i_gray for f in mine])
    rel = np.array([f.i_err_gray for f in mine]) / i
    y = _log_per_setting(i, np.array([f.exposure_s for f in mine]), np.array([f.gain_db for f in mine]))
    w = 1.0 / rel**2
    level = float(np.average(y, weights=w))
    propagated = 1.0 / math.sqrt(float(w.sum()))
    scatter = float(y.std(ddof=1) / math.sqrt(y.size)) if y.size >= 3 else 0.0
    t = float(np.average(np.array([f.t_s for f in mine]), weights=w))
    return CameraLevel(t, level, max(propagated, scatter), len(mine))


def trend_prior(levels: Sequence[CameraLevel], repeatability: float, default_per_s: float) -> TrendPrior:
    """A camera's trend prior in a visit from its levels in the wavelength's visits, oldest first.

    With three levels (the two previous visits and this one) the prior's
    centre is the slope from the previous visit's level to this one's, and
    its width how much that slope changed from the interval before (the
    curvature of the water's change) with both slopes' errors (each level's
    frames error and the repeatability between visits). Fewer levels: zero
    with ``default_per_s``.
    """
    if len(levels) < 3:
        return TrendPrior(0.0, default_per_s)
    a, b, c = levels[-3:]

    def slope(p: CameraLevel, q: CameraLevel) -> tuple[float, float]:
        dt = q.t_s - p.t_s
        err = math.sqrt(p.log_i_err**2 + q.log_i_err**2 + 2.0 * repeatability**2) / dt
        return (q.log_i - p.log_i) / dt, err

    if not (a.t_s < b.t_s < c.t_s):
        return TrendPrior(0.0, default_per_s)
    s0, _ = slope(a, b)  # its error is in how far s1 differs from it
    s1, e1 = slope(b, c)
    return TrendPrior(s1, math.sqrt(e1**2 + (s1 - s0) ** 2), "visits")


def camera_trend(
    t_s: np.ndarray,
    i_gray: np.ndarray,
    i_err_gray: np.ndarray,
    exposure_s: np.ndarray,
    gain_db: np.ndarray,
    prior_per_s: float,
    prior_mean_per_s: float = 0.0,
) -> CameraTrend:
    """The slope of ln(I / (exposure × gain factor)) against time, combined with a prior.

    A weighted straight line (weights from the per-frame errors) whose slope
    error comes from the residual scatter, so that settings whose gains are
    not exactly what they say widen it rather than bias it unseen. With
    fewer than four frames or no spread in time the prior (centre
    ``prior_mean_per_s``, width ``prior_per_s``) alone speaks.
    """
    n = t_s.size
    prior_var = prior_per_s**2
    if n >= 4 and prior_per_s > 0:
        y = _log_per_setting(i_gray, exposure_s, gain_db)
        w = (i_gray / np.maximum(i_err_gray, 1e-9)) ** 2
        x = t_s - np.average(t_s, weights=w)
        sxx = float(np.sum(w * x * x))
        if sxx > 0 and float(np.ptp(t_s)) > 0:
            ybar = float(np.average(y, weights=w))
            slope = float(np.sum(w * x * (y - ybar)) / sxx)
            resid = y - ybar - slope * x
            s2 = float(np.sum(w * resid * resid)) / (n - 2)
            var = max(s2, 1.0) / sxx  # never tighter than the frames' own errors allow
            post_var = 1.0 / (1.0 / var + 1.0 / prior_var)
            post_mean = (slope / var + prior_mean_per_s / prior_var) * post_var
            return CameraTrend(post_mean, math.sqrt(post_var), n, True)
    return CameraTrend(prior_mean_per_s, prior_per_s, n, False)


def visit_attenuation(
    frames: Sequence[VisitFrame],
    wavelength_nm: int,
    geometry: Geometry,
    ratio: EmissionRatio,
    *,
    repeatability: float,
    trend_prior_per_s: float,
    trend_priors: Mapping[str, TrendPrior] | None = None,
) -> VisitResult | None:
    """λ_att of one visit from its accepted frames (any cameras; the geometry's two are used).

    ``repeatability`` is the relative I_center repeatability of one camera
    between visits beyond the frames' noise (the floor; applied to both
    cameras, once per visit); ``trend_prior_per_s`` the width of the prior
    on a camera's d ln I / dt, unless ``trend_priors`` gives a camera its
    own (`trend_prior`). Returns None when no setting was taken by
    both cameras with a positive I_center.
    """
    near_cam, far_cam = geometry.near_camera, geometry.far_camera
    stacks: dict[tuple[str, float, float], list[VisitFrame]] = defaultdict(list)
    for f in frames:
        if f.camera in (near_cam, far_cam) and f.i_gray > 0 and f.i_err_gray > 0:
            stacks[(f.camera, f.exposure_s, f.gain_db)].append(f)
    settings = sorted({(e, g) for (c, e, g) in stacks if c == near_cam and (far_cam, e, g) in stacks})
    if not settings:
        return None
    used = [f for (e, g) in settings for c in (near_cam, far_cam) for f in stacks[(c, e, g)]]
    used.sort(key=lambda f: (f.t_s, f.camera, f.exposure_s, f.gain_db, f.i_gray))
    times = np.array([f.t_s for f in used])
    t_mean = float(times.mean())
    depths = [f.lem_depth_m for f in used if f.lem_depth_m is not None]

    trends = {}
    for cam in (near_cam, far_cam):
        mine = [f for f in used if f.camera == cam]
        prior = (trend_priors or {}).get(cam) or TrendPrior(0.0, trend_prior_per_s)
        trends[cam] = camera_trend(
            np.array([f.t_s for f in mine]),
            np.array([f.i_gray for f in mine]),
            np.array([f.i_err_gray for f in mine]),
            np.array([f.exposure_s for f in mine]),
            np.array([f.gain_db for f in mine]),
            prior.width_per_s,
            prior.mean_per_s,
        )
        trends[cam] = replace(trends[cam], prior=prior.source)

    pairs = []
    for e, g in settings:
        sides = []
        for cam in (near_cam, far_cam):
            st = stacks[(cam, e, g)]
            t = np.array([f.t_s for f in st])
            t_stack = float(t.mean())
            # Each frame brought to the stack's mean time along the camera's trend: a water that
            # changes during the visit moves the stack's frames apart, and that is no noise.
            along = np.exp(-trends[cam].slope_per_s * (t - t_stack))
            values = np.array([f.i_gray for f in st]) * along
            errors = np.array([f.i_err_gray for f in st]) * along
            mean, err = stack_value(values, errors)
            sides.append((mean, err, len(st), t_stack))
        (i_n, e_n, n_n, t_n), (i_f, e_f, n_f, t_f) = sides
        shift = -trends[near_cam].slope_per_s * (t_mean - t_n) + trends[far_cam].slope_per_s * (t_mean - t_f)
        q = math.log(i_n / i_f) - shift
        q_err = math.hypot(e_n / i_n, e_f / i_f)
        pairs.append(VisitPair(e, g, i_n, e_n, i_f, e_f, n_n, n_f, t_n, t_f, q, q_err, shift))

    weights = np.array([1.0 / p.log_ratio_err**2 for p in pairs])
    qs = np.array([p.log_ratio for p in pairs])
    wsum = float(weights.sum())
    q_mean = float(weights @ qs / wsum)
    frames_err = 1.0 / math.sqrt(wsum)
    ndof = len(pairs) - 1
    chi2_ndof = float(weights @ (qs - q_mean) ** 2) / ndof if ndof > 0 else 0.0
    # The trend term: how far, weighted as the pairs are, each camera's frames sit from the stamp.
    dt_near = float(weights @ np.array([p.t_near_s - t_mean for p in pairs]) / wsum)
    dt_far = float(weights @ np.array([p.t_far_s - t_mean for p in pairs]) / wsum)
    trend_err = math.hypot(
        trends[near_cam].slope_err_per_s * dt_near, trends[far_cam].slope_err_per_s * dt_far
    )
    floor = math.sqrt(2.0) * repeatability
    q_err = math.sqrt(frames_err**2 + trend_err**2 + floor**2)
    terms = {"frames": frames_err, "trend": trend_err, "floor": floor}

    x = q_mean + math.log(ratio.value)
    lam = stat = sys = None
    note = None
    if x > 0:
        baseline = geometry.baseline_m
        lam = baseline / x
        dlam_dx = lam * lam / baseline
        stat = dlam_dx * q_err
        sys = math.hypot(geometry.baseline_err_m / x, dlam_dx * ratio.err / ratio.value)
    else:
        note = not_dimmer_note(q_mean, ratio)
    return VisitResult(
        wavelength_nm=int(wavelength_nm),
        lambda_att_m=lam,
        stat_err_m=stat,
        sys_err_m=sys,
        log_ratio=q_mean,
        log_ratio_err=q_err,
        t_s=t_mean,
        t_first_s=float(times.min()),
        t_last_s=float(times.max()),
        lem_depth_m=float(np.mean(depths)) if depths else None,
        n_frames=len(used),
        n_pairs=len(pairs),
        chi2_ndof=chi2_ndof,
        terms=terms,
        pairs=tuple(pairs),
        trends=trends,
        note=note,
    )
