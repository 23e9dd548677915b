"""The searches of the χ² fit in (ln λ_abs, ln λ_sca): minimum, profiled crossings, curvature, map."""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import brentq, minimize, minimize_scalar

from analysis.chisq.model import OutsideTemplates, Problem
from analysis.chisq.results import ContourMap

#: What the objective returns where the templates give no halo (far above any real χ²).
OUTSIDE_CHI2 = 1e12


class Objective:
    """χ² of (ln λ_abs, ln λ_sca) within bounds, with the searches of `fit_wavelength`."""

    def __init__(self, prob: Problem, bounds: np.ndarray) -> None:
        self.prob = prob
        self.bounds = bounds

    def __call__(self, p: np.ndarray) -> float:
        q = np.clip(p, self.bounds[:, 0], self.bounds[:, 1])
        penalty = 1e6 * float(np.sum((p - q) ** 2))  # keeps Nelder-Mead inside
        try:
            return self.prob.chi2(math.exp(q[0]), math.exp(q[1]))[0] + penalty
        except OutsideTemplates:
            # A water the templates do not reach (an attenuation length shorter than they were made
            # for): no χ² there, and the searches keep away.
            return OUTSIDE_CHI2 + penalty

    def on_edge(self, x: float, k: int) -> bool:
        return bool(min(abs(x - self.bounds[k, 0]), abs(x - self.bounds[k, 1])) < 1e-3)

    def coarse_start(self) -> np.ndarray:
        """The best node of a coarse scan over the whole allowed range."""
        la = np.linspace(self.bounds[0, 0], self.bounds[0, 1], 15)
        ls = np.linspace(self.bounds[1, 0], self.bounds[1, 1], 9)
        scan = np.array([[self(np.array([a, s])) for a in la] for s in ls])
        j, i = np.unravel_index(int(np.argmin(scan)), scan.shape)
        return np.array([la[i], ls[j]])

    def minimise(
        self, start: np.ndarray | None = None, *, near: bool = False, refreeze: bool = True
    ) -> np.ndarray:
        """The minimum: from ``start`` (ln λ_abs, ln λ_sca), or from a coarse scan when None.

        ``near``: the start is already close (a refit of the same data with one input
        changed): a small first simplex, and no second pass when the first stayed put.
        ``refreeze=False`` keeps the templates' errors frozen where they are (the phase map:
        its points compare only with the same weights).
        """
        best = self.coarse_start() if start is None else np.clip(start, self.bounds[:, 0], self.bounds[:, 1])
        prob = self.prob
        step = np.array([0.02, 0.01]) if near else np.array([0.1, 0.05])
        for _ in range(2):  # the template errors held at the current best water
            if refreeze or prob.frozen_halo_err is None:
                prob.freeze_template_errors(math.exp(best[0]), math.exp(best[1]))
            before = best
            best = self._nelder_mead(best, step)
            # A refit that stayed put is done; one that moved (another ⟨cos θ⟩ moves λ_sca by tens of
            # per cent) holds the errors again at its own water: held at the start's, the templates'
            # errors there would weigh its χ², and χ² of different refits would not compare.
            if near and float(np.max(np.abs(best - before))) < 1e-3:
                break
        for _ in range(2):
            _, info = prob.chi2(math.exp(best[0]), math.exp(best[1]), detail=True)
            shifts = np.asarray(info["shifts"])
            work = prob.work.copy()
            for k in (3, 4):  # PSF width, image scale
                if prob.prior_sigma[k] > 0 and abs(shifts[k] - work[k]) > prob.prior_sigma[k] / 3:
                    work[k] = shifts[k]
            if np.array_equal(work, prob.work):
                break
            prob.set_working_point(work)
            best = self._nelder_mead(best, step)
        return best

    def newton(self, start: np.ndarray, *, max_iter: int = 8, h: float = 0.01) -> np.ndarray | None:
        """A local minimum from a start already near it, by Newton steps on the finite-difference
        Hessian (9 χ² evaluations a step; the phase map's refits: a few steps where Nelder-Mead takes
        a hundred evaluations). None when a step fails to lower χ² (the caller falls back).
        """
        x = np.clip(np.asarray(start, dtype=np.float64), self.bounds[:, 0], self.bounds[:, 1])
        f0 = self(x)
        e = np.eye(2) * h
        for _ in range(max_iter):
            fp = np.array([self(x + e[i]) for i in range(2)])
            fm = np.array([self(x - e[i]) for i in range(2)])
            grad = (fp - fm) / (2 * h)
            hess = np.diag((fp - 2 * f0 + fm) / h**2)
            hess[0, 1] = hess[1, 0] = (
                self(x + e[0] + e[1]) - self(x + e[0] - e[1]) - self(x - e[0] + e[1]) + self(x - e[0] - e[1])
            ) / (4 * h * h)
            if not np.all(np.isfinite(hess)) or np.linalg.det(hess) <= 0 or hess[0, 0] <= 0:
                return None
            step = -np.linalg.solve(hess, grad)
            step *= min(1.0, 0.5 / max(float(np.max(np.abs(step))), 1e-12))  # at most 0.5 in ln λ
            for _ in range(6):  # backtrack until χ² falls
                trial = np.clip(x + step, self.bounds[:, 0], self.bounds[:, 1])
                f1 = self(trial)
                if f1 <= f0:
                    break
                step *= 0.5
            else:
                return None
            moved = float(np.max(np.abs(trial - x)))
            x, f0 = trial, f1
            if moved < 2e-4:
                return x
        return x

    def _nelder_mead(self, start: np.ndarray, step: np.ndarray) -> np.ndarray:
        simplex = np.array([start, start + np.array([step[0], 0.0]), start + np.array([0.0, step[1]])])
        res = minimize(
            self,
            start,
            method="Nelder-Mead",
            options={"xatol": 1e-4, "fatol": 1e-3, "initial_simplex": simplex},
        )
        # Nelder-Mead may end a hair outside the range when the minimum sits on its edge (the
        # penalty is tiny there): the model is only defined inside.
        return np.clip(np.asarray(res.x), self.bounds[:, 0], self.bounds[:, 1])

    def profiled(self, best: np.ndarray, k: int, value: float, width: float) -> float:
        """χ² at parameter ``k`` = ``value``, minimised over the other around its best value."""
        other = 1 - k
        lo, hi = self.bounds[other]
        centre = float(np.clip(best[other], lo, hi))

        def g(v: float) -> float:
            p = np.empty(2)
            p[k], p[other] = value, v
            return self(p)

        res = minimize_scalar(
            g,
            bounds=(max(lo, centre - width), min(hi, centre + width)),
            method="bounded",
            options={"xatol": 1e-4},
        )
        # The bounded search can miss a valley much narrower than its window (a well-measured
        # λ_sca profiled along λ_abs): the best point's own value stays a candidate.
        return min(float(res.fun), g(centre))

    def crossing(
        self, best: np.ndarray, k: int, direction: float, target: float, sigma: float
    ) -> tuple[float, bool]:
        """Where the profiled χ² reaches ``target`` on one side of ``best``; True if at the range's edge."""
        limit = self.bounds[k, 0] if direction < 0 else self.bounds[k, 1]
        width = max(6.0 * sigma, 0.05)
        step = max(sigma, 1e-3)
        x0 = x1 = float(best[k])
        while True:
            x1 = x0 + direction * step
            if (x1 - limit) * direction >= 0:
                x1 = float(limit)
                if self.profiled(best, k, x1, width) < target:
                    return x1, True
                break
            if self.profiled(best, k, x1, width) >= target:
                break
            x0 = x1
            step *= 1.6
        lo, hi = sorted((x0, x1))
        root = brentq(lambda v: self.profiled(best, k, v, width) - target, lo, hi, xtol=1e-4)
        return float(root), False

    def contour(self, best: np.ndarray, span: np.ndarray, chi2_min: float, n: int) -> ContourMap:
        ga = np.clip(np.linspace(best[0] - span[0], best[0] + span[0], n), *self.bounds[0])
        gs = np.clip(np.linspace(best[1] - span[1], best[1] + span[1], n), *self.bounds[1])
        dmap = np.array([[self(np.array([a, s])) - chi2_min for a in ga] for s in gs])
        return ContourMap(np.exp(ga), np.exp(gs), dmap)


def curvature_covariance(obj: Objective, best: np.ndarray) -> np.ndarray:
    """Covariance of (ln λ_abs, ln λ_sca): 2 H⁻¹, H the χ² Hessian by central differences.

    The step adapts: it starts at 0.02 and shrinks until the diagonal
    second differences rise by no more than a few units of χ².
    """
    f0 = obj(best)
    h = np.array([0.02, 0.02])
    hess = np.zeros((2, 2))
    for i in range(2):
        e = np.zeros(2)
        for _ in range(8):
            e[i] = h[i]
            up, down = obj(best + e), obj(best - e)
            if max(up, down) - f0 < 4.0 or h[i] < 1e-4:
                break
            h[i] /= 3.0
        hess[i, i] = (up - 2 * f0 + down) / h[i] ** 2
    e0, e1 = np.array([h[0], 0.0]), np.array([0.0, h[1]])
    hess[0, 1] = hess[1, 0] = (
        obj(best + e0 + e1) - obj(best + e0 - e1) - obj(best - e0 + e1) + obj(best - e0 - e1)
    ) / (4 * h[0] * h[1])
    try:
        cov = 2.0 * np.linalg.inv(hess)
    except np.linalg.LinAlgError:
        cov = np.diag(2.0 / np.maximum(np.diag(hess), 1e-12))
    if np.any(np.diag(cov) <= 0):
        cov = np.diag(2.0 / np.maximum(np.diag(hess), 1e-12))
    return cov
