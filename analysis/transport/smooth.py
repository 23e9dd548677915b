"""Halo templates that are smooth functions of all four optical parameters.

``halo(λ_abs, λ_sca, g, f)`` (Mie ⟨cos θ⟩ g, Rayleigh share f) is assembled from
noise-free pieces, so it has no Monte Carlo noise and no seams between nodes:

* **first order, exact**: the line-of-sight quadrature of `analysis.transport.single`
  is linear in the phase function, so p = (1 - f)·HG_g + f·Rayleigh gives
  (1 - f)·L₁[HG_g] + f·L₁[Rayleigh]. L₁[HG_g] is tabulated on nodes uniform in
  x = ln(1 - g), and both on nodes uniform in ln(1/λ_att + k₀) (absorption and
  scattering enter the first order only through 1/λ_att, and 1/λ_sca in
  front); natural cubic splines interpolate (twice continuously
  differentiable);
* **orders ≥ 2, small-angle approximation** (`analysis.transport.smallangle`):
  e^{-(L - 2a/3)/λ_att} Σ_{n≥2} (L/λ_sca)ⁿ/n! Σ_m C(n,m)(1 - f)ⁿ⁻ᵐ fᵐ Q_{n,m}(g),
  with Q on the same nodes in x. The pairs holding Rayleigh scatterings
  (m ≥ 1) are the halo's broad pedestal, and the planar geometry of the
  small-angle approximation misses much of it (light scattered behind the
  LEM and at wide angles near it: the exact once-Rayleigh-scattered light is
  1.3-1.6 times the small-angle one): they are multiplied, band by band, by
  that ratio r_R(ψ, 1/λ_att) of the exact first order to the small-angle
  one, both noise-free (without it the higher orders were up to 10 % low at
  a Rayleigh share of 0.30-0.35 against Mitsuba). Light scattered by
  Rayleigh at a wide angle may have left the LEM in any direction: of the
  pair (n, m) the share m/(2n) is counted toward the other emission
  component (the first of n scatterings is a Rayleigh one with probability
  m/n, and such light left the far side half the time).

The stated error per band is 0.2 % of the first order (its quadrature) and,
of the light scattered n ≥ 2 times, 3 % at n = 2 and 1 % more per further
order (`HIGHER_ORDER_REL_ERR`, `..._STEP`), added linearly over the orders
(one approximation, correlated between them): against six Mitsuba halo
tables (⟨cos θ⟩ 0.85-0.97, Rayleigh share 0.05-0.35, λ_sca 8-50 m) the
higher orders deviate by RMS 4 %, 1-3 % at two scattering lengths or less
and up to 5 % beyond four disk radii of the far camera at λ_sca 8 m
(docs/transport.md). It is a systematic error, the same in every build and
smooth across bands, not noise.

`SmoothTemplates.halo` returns a `HaloTemplate` like `TemplateGrid.halo` (same
shapes and units) with the Rayleigh share as a fourth parameter;
`halo_gradient` adds the derivatives in all four.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import BSpline, make_interp_spline

from analysis.transport.single import FirstOrderLines
from analysis.transport.smallangle import order_pairs
from analysis.transport.template_settings import (
    EmissionProfile,
    HaloTemplate,
    TemplateSettings,
    band_centres_px,
)

#: 1/λ_att nodes: uniform in ln(k + K0) from 0 to the grid's largest k.
K0_PER_M = 2.0e-3
#: The stated model errors, relative: the first order's quadrature (`analysis.transport.reference`
#: checks it to 0.2 %) and the small-angle orders (see docs/transport.md).
FIRST_ORDER_REL_ERR = 0.002
HIGHER_ORDER_REL_ERR = 0.03
#: ... growing by this much per further order (the approximation degrades as wide angles add up),
#: up to `HIGHER_ORDER_REL_ERR_MAX`.
HIGHER_ORDER_REL_ERR_STEP = 0.01
HIGHER_ORDER_REL_ERR_MAX = 0.10


@dataclass(frozen=True)
class SmoothGrid:
    """Where the smooth templates' tables lie: the parameters' ranges and the nodes' numbers.

    ⟨cos θ⟩ nodes are uniform in ln(1 - g) over ``mie_g_range``; 1/λ_att nodes
    uniform in ln(k + K0) from 0 to ``k_max_per_m`` (λ_att down to 2.5 m by
    default); the orders' series is summed to ``n_orders``, enough for L/λ_sca
    up to ~7 at 24 (the far T-REX camera at 6 m).
    """

    mie_g_range: tuple[float, float] = (0.80, 0.985)
    n_g: int = 28
    rayleigh_share_range: tuple[float, float] = (0.0, 0.5)
    lambda_sca_range_m: tuple[float, float] = (6.0, 5000.0)
    n_orders: int = 24
    k_max_per_m: float = 0.4
    n_k: int = 40

    def __post_init__(self) -> None:
        lo, hi = self.mie_g_range
        if not 0 < lo < hi < 1 or self.n_g < 4:
            raise ValueError(
                f"mie_g_range must lie in (0, 1) with >= 4 nodes, got {self.mie_g_range}, {self.n_g}"
            )
        if not 0 <= self.rayleigh_share_range[0] < self.rayleigh_share_range[1] <= 1:
            raise ValueError(f"rayleigh_share_range must lie in [0, 1], got {self.rayleigh_share_range}")
        if not 0 < self.lambda_sca_range_m[0] < self.lambda_sca_range_m[1]:
            raise ValueError(
                f"lambda_sca_range_m must be positive and increasing, got {self.lambda_sca_range_m}"
            )
        if self.n_orders < 2 or self.n_k < 4 or not self.k_max_per_m > 0:
            raise ValueError("n_orders >= 2, n_k >= 4 and k_max_per_m > 0 are needed")

    def x_nodes(self) -> np.ndarray:
        """Nodes in x = ln(1 - g), increasing (⟨cos θ⟩ decreases along them)."""
        lo, hi = self.mie_g_range
        return np.linspace(math.log(1.0 - hi), math.log(1.0 - lo), self.n_g)

    def k_nodes(self) -> np.ndarray:
        """1/λ_att nodes (1/m), the first at 0."""
        t = np.linspace(math.log(K0_PER_M), math.log(self.k_max_per_m + K0_PER_M), self.n_k)
        out = np.exp(t) - K0_PER_M
        out[0] = 0.0
        return out

    def description(self) -> dict[str, object]:
        return {
            "mie_g_range": list(self.mie_g_range),
            "n_g": self.n_g,
            "n_orders": self.n_orders,
            "k_max_per_m": self.k_max_per_m,
            "n_k": self.n_k,
        }


@dataclass(frozen=True)
class _Basis:
    """The cubic B-spline basis of a natural interpolating spline on given nodes.

    Tables are turned into B-spline coefficients once (`coefficients`); a value
    at x then takes the four basis functions that do not vanish there
    (`weights`), so an evaluation reads 4 slices of a table, not all of them.
    """

    knots: np.ndarray
    nodes: np.ndarray
    value: BSpline = field(repr=False)
    slope: BSpline = field(repr=False)

    @classmethod
    def on(cls, nodes: np.ndarray) -> _Basis:
        probe = make_interp_spline(nodes, np.zeros(len(nodes)), k=3, bc_type=None)
        n_coef = len(probe.c)
        spline = BSpline(probe.t, np.eye(n_coef), 3, extrapolate=False)
        return cls(probe.t, np.asarray(nodes), spline, spline.derivative())

    def coefficients(self, table: np.ndarray, axis: int = 0) -> np.ndarray:
        """B-spline coefficients of the natural cubic spline through ``table`` along ``axis``."""
        c = make_interp_spline(self.nodes, table, k=3, bc_type=None, axis=axis).c
        return np.ascontiguousarray(np.moveaxis(np.asarray(c), 0, axis))

    def weights(self, x: float) -> tuple[slice, np.ndarray, np.ndarray]:
        """The basis functions alive at ``x`` (a slice of the coefficients) and their values and
        slopes d/dx."""
        x = min(max(x, float(self.nodes[0])), float(self.nodes[-1]))
        i = int(np.clip(np.searchsorted(self.knots, x, side="right") - 1, 3, len(self.knots) - 5))
        idx = slice(i - 3, i + 1)
        return idx, np.asarray(self.value(x))[idx], np.asarray(self.slope(x))[idx]


@dataclass(frozen=True)
class _Pairs:
    """The (n, m) pairs of the orders >= 2 and their binomial coefficients, as arrays."""

    index: np.ndarray
    n: np.ndarray
    m: np.ndarray
    binom: np.ndarray
    log_fact: np.ndarray

    @classmethod
    def up_to(cls, n_max: int) -> _Pairs:
        pairs = order_pairs(n_max)
        idx = np.array([i for i, (n, _) in enumerate(pairs) if n >= 2])
        n = np.array([pairs[i][0] for i in idx], dtype=np.float64)
        m = np.array([pairs[i][1] for i in idx], dtype=np.float64)
        binom = np.array([math.comb(int(a), int(b)) for a, b in zip(n, m, strict=True)], dtype=np.float64)
        log_fact = np.array([math.lgamma(a + 1.0) for a in n])
        return cls(idx, n, m, binom, log_fact)

    def mix(self, f: float) -> tuple[np.ndarray, np.ndarray]:
        """C(n,m)(1-f)ⁿ⁻ᵐ fᵐ and its derivative in f."""
        n, m = self.n, self.m
        val = self.binom * (1.0 - f) ** (n - m) * f**m
        with np.errstate(divide="ignore", invalid="ignore"):
            up = np.where(m > 0, m * f ** np.maximum(m - 1.0, 0.0), 0.0) * (1.0 - f) ** (n - m)
            down = np.where(n > m, (n - m) * (1.0 - f) ** np.maximum(n - m - 1.0, 0.0), 0.0) * f**m
        return val, self.binom * (up - down)


@dataclass(frozen=True)
class SmoothTemplates:
    """The tabulated pieces of one geometry, evaluated at any (λ_abs, λ_sca, g, f) in range.

    ``first_hg[j, i, c, k, b]``: the once-scattered light of Henyey-Greenstein
    at x = ln(1 - g) = ``grid.x_nodes()[j]`` and 1/λ_att = ``grid.k_nodes()[i]``, per camera,
    emission component and band, times λ_sca e^{k(L_c - a)};
    ``first_rayleigh[i, c, k, b]`` the same for Rayleigh; ``orders[j, c, p, b]``
    the small-angle Q of pair ``order_pairs(grid.n_orders)[p]``.
    """

    settings: TemplateSettings
    grid: SmoothGrid
    first_hg: np.ndarray = field(repr=False)
    first_rayleigh: np.ndarray = field(repr=False)
    orders: np.ndarray = field(repr=False)
    _g_basis: _Basis = field(init=False, repr=False)
    _k_basis: _Basis = field(init=False, repr=False)
    _pairs: _Pairs = field(init=False, repr=False)
    _first_hg_c: np.ndarray = field(init=False, repr=False)
    _first_rayleigh_c: np.ndarray = field(init=False, repr=False)
    _orders_c: np.ndarray = field(init=False, repr=False)
    _q11: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        gb = _Basis.on(self.grid.x_nodes())
        kb = _Basis.on(np.log(self.grid.k_nodes() + K0_PER_M))
        pairs = _Pairs.up_to(self.grid.n_orders)
        fields = {
            "_g_basis": gb,
            "_k_basis": kb,
            "_pairs": pairs,
            "_first_hg_c": kb.coefficients(gb.coefficients(self.first_hg, 0), 1),
            "_first_rayleigh_c": kb.coefficients(self.first_rayleigh, 0),
            "_orders_c": gb.coefficients(np.ascontiguousarray(self.orders[:, :, pairs.index]), 0),
            "_q11": np.ascontiguousarray(self.orders[0, :, 1]),  # pair (1, 1): no Mie, the same at every g
        }
        for name, value in fields.items():
            object.__setattr__(self, name, value)

    @property
    def lambda_sca_range_m(self) -> tuple[float, float]:
        return self.grid.lambda_sca_range_m

    @property
    def mie_g_range(self) -> tuple[float, float]:
        return self.grid.mie_g_range

    @property
    def rayleigh_share_range(self) -> tuple[float, float]:
        return self.grid.rayleigh_share_range

    # -- evaluation ---------------------------------------------------------
    def _check(self, lambda_abs_m: float, lambda_sca_m: float, mie_g: float, share: float) -> None:
        for name, value, (lo, hi) in (
            ("lambda_sca_m", lambda_sca_m, self.lambda_sca_range_m),
            ("mie_g", mie_g, self.mie_g_range),
            ("rayleigh_share", share, self.rayleigh_share_range),
        ):
            if not lo - 1e-9 * abs(lo) <= value <= hi + 1e-9 * abs(hi):
                raise ValueError(
                    f"{name} {value:.6g} outside the smooth templates' range [{lo:.6g}, {hi:.6g}]"
                )
        if not lambda_abs_m > 0:
            raise ValueError(f"lambda_abs_m must be > 0, got {lambda_abs_m}")
        k = 1.0 / lambda_abs_m + 1.0 / lambda_sca_m
        if k > self.grid.k_max_per_m * (1 + 1e-9):
            raise ValueError(
                f"1/lambda_abs + 1/lambda_sca = {k:.4g} /m: the smooth templates stop at lambda_att "
                f"{1.0 / self.grid.k_max_per_m:.3g} m"
            )

    def _evaluate(
        self, lambda_abs_m: float, lambda_sca_m: float, mie_g: float, share: float, *, gradient: bool
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        """First order, higher orders, the stated error (camera, component, band) and, with
        ``gradient``, the derivatives of the halo in (λ_abs, λ_sca, g, f)."""
        s = self.settings
        a = s.lem_radius_m
        dist = np.array([c.distance_m for c in s.cameras])
        toward = np.array([0 if c.side > 0 else 1 for c in s.cameras])
        b = 1.0 / lambda_sca_m
        k = 1.0 / lambda_abs_m + b
        ig, wg, dwg = self._g_basis.weights(math.log(1.0 - mie_g))
        ik, wk, dwk = self._k_basis.weights(math.log(min(k, self.grid.k_max_per_m) + K0_PER_M))
        dwk = dwk / (k + K0_PER_M)
        # First order: b e^{-k(L - a)} ((1 - f) HG + f Rayleigh).
        hg_g = np.tensordot(wg, self._first_hg_c[ig, ik], axes=(0, 0))  # (k, cam, comp, band)
        hg = np.tensordot(wk, hg_g, axes=(0, 0))
        ray_c = self._first_rayleigh_c[ik]
        ray = np.tensordot(wk, ray_c, axes=(0, 0))
        front = (b * np.exp(-k * (dist - a)))[:, None, None]
        mixed = (1.0 - share) * hg + share * ray
        first = front * mixed
        # Orders >= 2.
        pr = self._pairs
        orders_c = self._orders_c[ig]
        # Rayleigh scatterings in the exact geometry: the pairs holding one or more take the ratio of
        # the exact once-Rayleigh-scattered light to the small-angle one (same 1/λ_att).
        ray_sum = ray.sum(axis=1)  # (cam, band)
        r_ray = ray_sum * math.exp(k * a / 3.0) / (dist[:, None] * self._q11)
        has_r = (pr.m > 0)[None, :, None]
        factor = np.where(has_r, r_ray[:, None, :], 1.0)  # (cam, pair, band)
        q = np.tensordot(wg, orders_c, axes=(0, 0)) * factor  # (cam, pair, band)
        mix, dmix = pr.mix(share)
        coef = np.exp(pr.n[None, :] * np.log(dist[:, None] * b) - pr.log_fact[None, :])  # (cam, pair)
        att = np.exp(-k * (dist - 2.0 * a / 3.0))
        off = pr.m / (2.0 * pr.n)
        split = np.empty((len(dist), 2, len(pr.n)))
        split[np.arange(len(dist)), toward] = 1.0 - off
        split[np.arange(len(dist)), 1 - toward] = off
        wts = (coef * att[:, None])[:, None, :] * split  # (cam, comp, pair), times mix below
        higher = np.einsum("ckp,cpb->ckb", wts * mix, q)
        eps = np.minimum(
            HIGHER_ORDER_REL_ERR + HIGHER_ORDER_REL_ERR_STEP * (pr.n - 2), HIGHER_ORDER_REL_ERR_MAX
        )
        err = np.hypot(FIRST_ORDER_REL_ERR * first, np.einsum("ckp,cpb->ckb", wts * mix * eps, q))
        if not gradient:
            return first, higher, err, None
        # d/dk at fixed b, d/db at fixed k, d/dx (x = ln(1 - g)), d/df.
        hg_dk = np.tensordot(dwk, hg_g, axes=(0, 0))
        ray_dk = np.tensordot(dwk, ray_c, axes=(0, 0))
        hg_dx = np.tensordot(wk, np.tensordot(dwg, self._first_hg_c[ig, ik], axes=(0, 0)), axes=(0, 0))
        d_first_k = front * ((1.0 - share) * hg_dk + share * ray_dk) - (dist - a)[:, None, None] * first
        d_first_b = first / b
        d_first_x = front * (1.0 - share) * hg_dx
        d_first_f = front * (ray - hg)
        q_dx = np.tensordot(dwg, orders_c, axes=(0, 0)) * factor
        dlog_r = ray_dk.sum(axis=1) / ray_sum + a / 3.0  # d ln r_ray / dk, (cam, band)
        d_hi_k = -(dist - 2.0 * a / 3.0)[:, None, None] * higher + np.einsum(
            "ckp,cpb->ckb", wts * mix * (pr.m > 0), q * dlog_r[:, None, :]
        )
        d_hi_b = np.einsum("ckp,cpb->ckb", wts * mix * (pr.n / b), q)
        d_hi_x = np.einsum("ckp,cpb->ckb", wts * mix, q_dx)
        d_hi_f = np.einsum("ckp,cpb->ckb", wts * dmix, q)
        dk = d_first_k + d_hi_k
        db = d_first_b + d_hi_b
        dx_dg = -1.0 / (1.0 - mie_g)
        grad = np.stack(
            [
                -dk / lambda_abs_m**2,  # k = 1/λ_abs + b
                -(dk + db) / lambda_sca_m**2,
                (d_first_x + d_hi_x) * dx_dg,
                d_first_f + d_hi_f,
            ]
        )
        return first, higher, err, grad

    def _defaults(self, mie_g: float | None, rayleigh_share: float | None) -> tuple[float, float]:
        g = self.settings.mie_g_nodes[0] if mie_g is None else float(mie_g)
        f = self.settings.rayleigh_fraction if rayleigh_share is None else float(rayleigh_share)
        return g, f

    def halo(
        self,
        lambda_abs_m: float,
        lambda_sca_m: float,
        mie_g: float | None = None,
        rayleigh_share: float | None = None,
    ) -> HaloTemplate:
        """The scattered-light template at one water (`ValueError` naming a parameter out of range).

        ``mie_g`` and ``rayleigh_share`` default to the settings' nominal values
        (``mie_g_nodes[0]``, ``rayleigh_fraction``).
        """
        g, f = self._defaults(mie_g, rayleigh_share)
        self._check(lambda_abs_m, lambda_sca_m, g, f)
        first, higher, err, _ = self._evaluate(lambda_abs_m, lambda_sca_m, g, f, gradient=False)
        return HaloTemplate(lambda_abs_m, lambda_sca_m, g, first + higher, err)

    def parts(
        self,
        lambda_abs_m: float,
        lambda_sca_m: float,
        mie_g: float | None = None,
        rayleigh_share: float | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """The first order and the orders >= 2 apart, per (camera, component, band)."""
        g, f = self._defaults(mie_g, rayleigh_share)
        self._check(lambda_abs_m, lambda_sca_m, g, f)
        first, higher, _, _ = self._evaluate(lambda_abs_m, lambda_sca_m, g, f, gradient=False)
        return first, higher

    def halo_gradient(
        self, lambda_abs_m: float, lambda_sca_m: float, mie_g: float, rayleigh_share: float
    ) -> tuple[HaloTemplate, np.ndarray]:
        """The template and its derivatives, shape (4, camera, component, band): ∂/∂λ_abs and
        ∂/∂λ_sca (per metre), ∂/∂g, ∂/∂f."""
        self._check(lambda_abs_m, lambda_sca_m, mie_g, rayleigh_share)
        first, higher, err, grad = self._evaluate(
            lambda_abs_m, lambda_sca_m, mie_g, rayleigh_share, gradient=True
        )
        assert grad is not None
        return HaloTemplate(lambda_abs_m, lambda_sca_m, mie_g, first + higher, err), grad

    def halo_at_psi(
        self,
        psi_rad: np.ndarray,
        camera: int,
        lambda_abs_m: float,
        lambda_sca_m: float,
        mie_g: float | None,
        emission: EmissionProfile,
        rayleigh_share: float | None = None,
    ) -> np.ndarray:
        """One camera's scattered-light radiance at angles ``psi_rad`` (interpolated between bands).

        As `TemplateGrid.halo_at_psi`: band values at the bands' area centroids,
        ψ beyond the last band raises `ValueError`.
        """
        psi = np.asarray(psi_rad, dtype=np.float64)
        edges = np.asarray(self.settings.scene().band_edges_px)
        reach = math.atan(edges[-1] / self.settings.focal_px)
        if psi.size and float(psi.max()) > reach * (1 + 1e-9):
            raise ValueError(
                f"psi_rad reaches {float(psi.max()):.4g} rad but the templates' bands end at "
                f"{edges[-1]:.0f} px ({reach:.4g} rad); build them with a larger outer_px"
            )
        value, _ = self.halo(lambda_abs_m, lambda_sca_m, mie_g, rayleigh_share).total(emission)
        return np.interp(psi, np.arctan(band_centres_px(edges) / self.settings.focal_px), value[camera])

    def camera_index(self, distance_m: float, side: int) -> int:
        """The index of the camera at ``distance_m`` on ``side``; `ValueError` if none."""
        for i, c in enumerate(self.settings.cameras):
            if c.side == side and abs(c.distance_m - distance_m) < 1e-6:
                return i
        have = ", ".join(f"{c.distance_m} m side {c.side:+d}" for c in self.settings.cameras)
        raise ValueError(f"no template camera at {distance_m} m on side {side:+d} (templates have: {have})")


def first_order_k_table(
    lines: FirstOrderLines, distances_m: np.ndarray, lem_radius_m: float, ks: np.ndarray
) -> np.ndarray:
    """Σ weight·e^{-k(path - (L - a))}(1 + k² spread/2) per k node, camera, component and band."""
    excess = lines.path_m - (np.asarray(distances_m) - lem_radius_m)[:, None, None]
    out = np.empty((len(ks), *lines.weight.shape[:3]))
    for i, k in enumerate(ks):
        factor = np.exp(-k * excess) * (1.0 + 0.5 * k * k * lines.spread_m2)
        out[i] = np.einsum("ckbj,cbj->ckb", lines.weight, factor)
    return out
