"""The rolling λ_att: latest near and far stacks at equal settings, within a time window."""

from __future__ import annotations

import math
from collections import defaultdict, deque
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from analysis import AttenuationResult, EmissionRatio, Geometry, combine_pairs, pair_result


@dataclass(frozen=True)
class Sample:
    t_unix_s: float
    i_center_gray: float
    i_center_err_gray: float
    depth_m: float | None


class RollingAttenuation:
    """λ_att per wavelength from the frames of the last ``window_s`` seconds.

    Every accepted frame joins the stack of its (camera, wavelength,
    exposure, gain). A setting seen by both cameras within the window forms
    a pair; the pairs of a wavelength combine into one point. Points are
    emitted at most every ``min_interval_s`` per wavelength.
    """

    def __init__(
        self,
        geometry: Geometry,
        ratios: Mapping[int, EmissionRatio],
        window_s: float = 300.0,
        min_interval_s: float = 10.0,
        min_frames: int = 2,
    ) -> None:
        self.geometry = geometry
        self.ratios = dict(ratios)
        self.window_s = window_s
        self.min_interval_s = min_interval_s
        self.min_frames = min_frames
        self._stacks: dict[tuple[str, int, float, float], deque[Sample]] = defaultdict(deque)
        self._last_emit: dict[int, float] = {}

    def add(
        self, camera: str, wavelength_nm: int, exposure_s: float, gain_db: float, sample: Sample
    ) -> tuple[AttenuationResult, float, float | None] | None:
        """Add one accepted frame; returns (result, time, depth) when a new point is due."""
        if camera not in (self.geometry.near_camera, self.geometry.far_camera):
            return None
        key = (camera, wavelength_nm, exposure_s, gain_db)
        self._stacks[key].append(sample)
        t = sample.t_unix_s
        if t - self._last_emit.get(wavelength_nm, -math.inf) < self.min_interval_s:
            return None
        result = self.compute(wavelength_nm, t)
        if result is None:
            return None
        self._last_emit[wavelength_nm] = t
        return result

    def compute(
        self, wavelength_nm: int, now_unix_s: float
    ) -> tuple[AttenuationResult, float, float | None] | None:
        """The combined λ_att of a wavelength over the window ending at ``now_unix_s``."""
        ratio = self.ratios.get(wavelength_nm)
        if ratio is None:
            return None
        start = now_unix_s - self.window_s
        pairs, depths = [], []
        g = self.geometry
        for (cam, wl, exp, gain), dq in list(self._stacks.items()):
            while dq and dq[0].t_unix_s < start:
                dq.popleft()
            if cam != g.near_camera or wl != wavelength_nm:
                continue
            far = self._stacks.get((g.far_camera, wl, exp, gain))
            if far is None:
                continue
            while far and far[0].t_unix_s < start:
                far.popleft()
            if len(dq) < self.min_frames or len(far) < self.min_frames:
                continue
            near_stats, far_stats = _stack(dq), _stack(far)
            pairs.append(pair_result(wl, exp, gain, near_stats, far_stats, g, ratio))
            depths += [s.depth_m for s in (*dq, *far) if s.depth_m is not None]
        usable = [p for p in pairs if math.isfinite(p.log_ratio) and p.log_ratio_err > 0]
        if not usable:
            return None
        depth = float(np.mean(depths)) if depths else None
        return combine_pairs(usable, g, ratio), now_unix_s, depth


def _stack(samples: deque[Sample]) -> tuple[float, float, int]:
    """Mean I_center of a stack with its error: scatter over sqrt(n), or propagated if larger."""
    values = np.array([s.i_center_gray for s in samples])
    errors = np.array([s.i_center_err_gray for s in samples])
    n = len(values)
    propagated = float(np.sqrt(np.sum(errors**2)) / n)
    scatter = float(values.std(ddof=1) / math.sqrt(n)) if n >= 3 else 0.0
    return float(values.mean()), max(scatter, propagated), n
