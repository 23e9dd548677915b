"""λ_abs and λ_sca from the radial profiles of both cameras: the paper's χ² method.

Data
----
Per setting (wavelength, exposure, gain) with stacked frames of both cameras:
the band means of the stacked crops (`analysis.stack.StackResult`) minus
their fitted background, both divided by the near camera's Σ G_i (the sum of
the background-subtracted gray values over the fitted region), so that the
far/near brightness ratio survives the normalisation.

Model
-----
T = direct disk + scattered-light halo for each camera. The disk
(`analysis.transport.disk`) has radiance exp(-L/λ_att) toward the near
camera and (I0'/I0)·exp(-L/λ_att) toward the far one and is blurred by a
Gaussian PSF; the halo comes from the transport templates
(`analysis.transport.templates`), weighted by the same emission profile.
T is normalised like the data, by its own near-camera sum.

χ²
--
::

    χ² = Σ_i [M_i - s·T_i(ε) - β_c]² / (σ_Mi² + σ_Ti²) + Σ_k ε_k² / σ_k²

The paper writes the nuisance terms as T_i(1 + Σ ε_k); here each nuisance
acts on the bins it physically changes, linearised: T_i(ε) = T_i + Σ_k ε_k
∂T_i/∂ε_k. The nuisances are the two distances, I0'/I0 (the far camera's
disk and both halos' far-side light), the PSF width (the disk's edge), the
image scale (focal length: the disk's radius and the halo's radial scale)
and the halo's overall level (the templates' own accuracy, ±0.5 %).
Per setting, a scale s (≈ 1: it takes up the normalisation's own error) and a
constant β per camera are free: the exponential + constant background fit
takes part of the faint, nearly flat wide-angle halo for background (half a
gray value in the T-REX demo frames), and β gives it back instead of biasing
λ_sca. All these enter linearly and are solved exactly at every (λ_abs,
λ_sca) (profiled). σ_T is the templates' Monte Carlo error plus a relative
model uncertainty.

The minimum over (λ_abs, λ_sca) gives the estimates; one-parameter errors are
where the profiled χ² rises by 1, the joint 68 % region where it rises by
2.30.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import brentq, minimize, minimize_scalar

from analysis.attenuation import EmissionRatio, Geometry
from analysis.stack import StackResult
from analysis.transport.disk import BandPixels, disk_radius_px
from analysis.transport.templates import EmissionProfile, TemplateGrid, TemplateSettings

#: Δχ² of a one-parameter 68 % interval and of the joint 2-D 68 % and 95 % regions.
DCHI2_1D = 1.0
DCHI2_2D_68 = 2.30
DCHI2_2D_95 = 6.18


class FitInputError(ValueError):
    """The data cannot be fitted (too few frames, a camera missing, nothing unsaturated...)."""


@dataclass(frozen=True)
class ProfileData:
    """One camera's stacked radial profile at one setting.

    ``mean_gray``/``sem_gray``/``count`` are the band means of the stacked
    crop after rejecting outlying pixels per band (hot pixels and specks,
    see `BandPixels.clipped_profile`), ``background_gray`` the constant of the
    stack's exponential + constant fit, ``pixels`` the geometry of its bands
    (for averaging the model the same way).
    """

    camera: str
    mean_gray: np.ndarray = field(repr=False)
    sem_gray: np.ndarray = field(repr=False)
    count: np.ndarray = field(repr=False)
    background_gray: float
    n_frames: int
    pixels: BandPixels = field(repr=False)

    @classmethod
    def from_stack(cls, camera: str, stack: StackResult) -> ProfileData:
        """From `analysis.stack.stack_frames` output (needs its measurement, pixels and centre)."""
        if stack.measurement is None or stack.stacked_pixels is None or stack.center_xy is None:
            raise FitInputError(f"camera {camera}: the stack carries no profile to fit")
        n = len(stack.measurement.profile.mean_gray)
        img = stack.stacked_pixels
        pixels = BandPixels.from_crop(img.shape, stack.center_xy, n, valid=np.isfinite(img))
        mean, sem, count = pixels.clipped_profile(img.ravel()[pixels.flat_index].astype(np.float64))
        return cls(
            camera=camera,
            mean_gray=mean,
            sem_gray=sem,
            count=count,
            background_gray=float(stack.background_gray),
            n_frames=stack.n_frames,
            pixels=pixels,
        )


@dataclass(frozen=True)
class SettingProfiles:
    """Near and far profiles taken at one exposure and gain."""

    exposure_s: float
    gain_db: float
    near: ProfileData
    far: ProfileData


@dataclass(frozen=True)
class FitConfig:
    """Choices of the χ² fit.

    ``psf_sigma_px`` ± ``psf_sigma_err_px`` is the Gaussian PSF (defocus
    plus the sub-pixel spread of stacking); ``focal_rel_err`` the relative
    uncertainty of the image scale; ``halo_scale_err`` that of the templates'
    overall halo level (their accuracy: the quadrature's, the Monte Carlo's
    normalisation), common to all bands; ``lambda_sca_sys_rel`` the relative
    systematic error quoted on λ_sca for the templates' accuracy (the halo's
    radial shape fixes λ_sca to ~0.1 % statistically, finer than the first
    order's quadrature is exact near the LEM's limb, 0.1-0.4 %);
    ``model_rel_err`` a relative uncertainty
    added to every model bin (the LEM's and the optics' departures from the
    ideal model); bands with fewer than ``min_band_pixels`` pixels are left
    out, and so are bands whose 8-bit rounding bias could exceed
    ``max_quantisation_bias`` times their statistical error
    (`quantisation_bias_gray`: the faint halo at low gain).
    ``template_errors`` adds the templates' Monte Carlo errors to σ_T (held
    at their values for the current best water); switch it off when the data
    were simulated from the same template grid (a shared Monte Carlo sample
    is no independent error, and counting it de-weights the halo). ``mie_g``
    (⟨cos θ⟩) is held at this value (None: the templates' first node).
    ``contour_points`` per axis of the Δχ² map.
    """

    psf_sigma_px: float = 1.2
    psf_sigma_err_px: float = 0.3
    focal_rel_err: float = 0.003
    halo_scale_err: float = 0.005
    lambda_sca_sys_rel: float = 0.005
    model_rel_err: float = 0.002
    min_band_pixels: int = 16
    max_quantisation_bias: float = 0.1
    template_errors: bool = True
    mie_g: float | None = None
    lambda_abs_range_m: tuple[float, float] = (2.0, 2000.0)
    contour_points: int = 25

    def __post_init__(self) -> None:
        if not self.psf_sigma_px > 0 or self.psf_sigma_err_px < 0:
            raise ValueError(f"psf_sigma_px must be > 0 and psf_sigma_err_px >= 0, got {self.psf_sigma_px}")
        if min(self.focal_rel_err, self.model_rel_err, self.halo_scale_err, self.lambda_sca_sys_rel) < 0:
            raise ValueError(
                "focal_rel_err, halo_scale_err, lambda_sca_sys_rel and model_rel_err must be >= 0"
            )
        if self.contour_points < 5:
            raise ValueError(f"contour_points must be >= 5, got {self.contour_points}")


@dataclass(frozen=True)
class Nuisance:
    """A fitted nuisance parameter: its shift from nominal, prior width and pull (shift/width)."""

    name: str
    unit: str
    shift: float
    sigma: float

    @property
    def pull(self) -> float:
        return self.shift / self.sigma if self.sigma > 0 else 0.0


@dataclass(frozen=True)
class ContourMap:
    """Δχ² (profiled over everything else) on a grid of λ_abs × λ_sca (both log-spaced)."""

    lambda_abs_m: np.ndarray = field(repr=False)
    lambda_sca_m: np.ndarray = field(repr=False)
    delta_chi2: np.ndarray = field(repr=False)  # shape (len(lambda_sca_m), len(lambda_abs_m))


@dataclass(frozen=True)
class SettingModel:
    """Data and best-fit model of one setting, normalised (for plots and residuals)."""

    exposure_s: float
    gain_db: float
    radius_px: np.ndarray = field(repr=False)
    data: np.ndarray = field(repr=False)  # (2, n) near, far
    error: np.ndarray = field(repr=False)
    model: np.ndarray = field(repr=False)
    halo: np.ndarray = field(repr=False)
    used: np.ndarray = field(repr=False)


@dataclass(frozen=True)
class ChiSquareFit:
    """λ_abs and λ_sca of one wavelength with errors, and everything that led to them.

    Errors are one standard deviation from the profiled Δχ² = 1 crossings
    (``*_err_m`` is the mean of the lower and upper distances);
    ``lambda_sca_sys_err_m`` is the templates' systematic error on λ_sca
    (`FitConfig.lambda_sca_sys_rel`), to be added in quadrature. ``lambda_att_m``
    follows from 1/λ_att = 1/λ_abs + 1/λ_sca with its error from the local
    curvature of χ². ``at_edge`` names a parameter whose minimum lies on
    the edge of the allowed range (its error is then one-sided).
    """

    wavelength_nm: int
    lambda_abs_m: float
    lambda_abs_err_m: float
    lambda_abs_interval_m: tuple[float, float]
    lambda_sca_m: float
    lambda_sca_err_m: float
    lambda_sca_interval_m: tuple[float, float]
    lambda_sca_sys_err_m: float
    lambda_att_m: float
    lambda_att_err_m: float
    correlation: float
    chi2: float
    ndof: int
    mie_g: float
    nuisances: tuple[Nuisance, ...]
    at_edge: tuple[str, ...]
    contour: ContourMap = field(repr=False)
    settings: tuple[SettingModel, ...] = field(repr=False)
    geometry: Geometry
    emission_ratio: EmissionRatio
    config: FitConfig
    focal_px: float
    templates: TemplateSettings
    n_evaluations: int

    @property
    def lambda_sca_total_err_m(self) -> float:
        return math.hypot(self.lambda_sca_err_m, self.lambda_sca_sys_err_m)

    @property
    def chi2_ndof(self) -> float:
        return self.chi2 / self.ndof if self.ndof > 0 else float("nan")


_NUISANCES = ("distance_near", "distance_far", "emission_ratio", "psf_sigma", "focal_scale", "halo_scale")
_UNITS = {
    "distance_near": "m",
    "distance_far": "m",
    "emission_ratio": "rel",
    "psf_sigma": "px",
    "focal_scale": "rel",
    "halo_scale": "rel",
}


def quantisation_bias_gray(sem_gray: np.ndarray, count: np.ndarray, n_frames: np.ndarray) -> np.ndarray:
    """Bound on the bias of a band mean from the 8-bit rounding of faint, little-noisy pixels.

    Rounding is linear on average only when the pixel noise dithers it: for
    Gaussian noise σ (gray) the mean of rounded values departs from the true
    level by up to exp(-2π²σ²)/π (the first term of its Fourier series),
    0.03 gray at σ = 0.3 (low gain) but 3·10⁻⁴ at σ = 0.6. σ is the
    single-frame pixel noise, sem·sqrt(count·n_frames) of the stacked band.
    The bias changes with the level and is alike in neighbouring bands, so
    it is neither subtracted nor treated as noise: bands where it could
    exceed a fraction of the statistical error are left out of the fit
    (`FitConfig.max_quantisation_bias`).
    """
    sigma = np.nan_to_num(sem_gray) * np.sqrt(np.maximum(count, 1.0) * n_frames)
    return np.exp(-2.0 * math.pi**2 * sigma * sigma) / math.pi


class _Problem:
    """Precomputed data and geometry of one wavelength; evaluates the profiled χ²."""

    def __init__(
        self,
        settings: Sequence[SettingProfiles],
        grid: TemplateGrid,
        geometry: Geometry,
        ratio: EmissionRatio,
        config: FitConfig,
    ) -> None:
        self.grid = grid
        self.geometry = geometry
        self.ratio = ratio
        self.config = config
        self.settings = list(settings)
        ts = grid.settings
        self.focal_px = ts.focal_px
        self.lem_radius_m = ts.lem_radius_m
        self.mie_g = ts.mie_g_nodes[0] if config.mie_g is None else float(config.mie_g)
        n_tmpl = ts.n_bands
        n = min(n_tmpl, *(len(p.mean_gray) for s in settings for p in (s.near, s.far)))
        self.n = n
        self.radius_px = np.arange(n) + 0.5
        sig = np.array(
            [
                geometry.distance_near_err_m,
                geometry.distance_far_err_m,
                ratio.err / ratio.value,
                config.psf_sigma_err_px,
                config.focal_rel_err,
                config.halo_scale_err,
            ]
        )
        self.active = np.flatnonzero(sig > 0)
        self.prior_sigma = sig
        self.work = np.zeros(6)  # working point: shifts from nominal of the six nuisances
        m, e, used, n_px = [], [], [], []
        for s in self.settings:
            pd = np.stack(
                [s.near.mean_gray[:n] - s.near.background_gray, s.far.mean_gray[:n] - s.far.background_gray]
            )
            cnt = np.stack([s.near.count[:n], s.far.count[:n]]).astype(np.float64)
            sem = np.stack([s.near.sem_gray[:n], s.far.sem_gray[:n]])
            frames = np.array([[s.near.n_frames], [s.far.n_frames]], dtype=np.float64)
            floor = 0.29 / np.sqrt(np.maximum(cnt, 1.0) * frames)
            quant = quantisation_bias_gray(sem, cnt, frames)
            sem = np.maximum(sem, floor)
            ok = (cnt >= config.min_band_pixels) & np.isfinite(pd) & np.isfinite(sem)
            ok &= quant <= config.max_quantisation_bias * sem
            norm = float(np.sum(np.where(ok[0], cnt[0] * pd[0], 0.0)))
            if not norm > 0:
                raise FitInputError(
                    f"setting {s.exposure_s:g} s / {s.gain_db:g} dB: the near camera's profile holds no light"
                )
            m.append(np.where(ok, pd / norm, 0.0))
            e.append(np.where(ok, sem / norm, 1.0))
            used.append(ok)
            n_px.append(cnt)
        self.data = np.stack(m)  # (set, cam, band)
        self.data_err = np.stack(e)
        self.used = np.stack(used)
        self.counts = np.stack(n_px)
        self.n_eval = 0
        self.frozen_halo_err: np.ndarray | None = None
        self._set_working_point(np.zeros(6))

    def freeze_template_errors(self, lambda_abs_m: float, lambda_sca_m: float) -> None:
        """Hold the templates' Monte Carlo errors at their values for this water.

        σ_T changes with the parameters (reweighting moves it), and a χ² whose
        weights move with the parameters is pulled toward where the template
        is noisiest. Held fixed, only the model moves.
        """
        self.frozen_halo_err = None
        mod = self.model(lambda_abs_m, lambda_sca_m)
        self.frozen_halo_err = mod["halo_err"][None] / self._norm(mod["total"])[:, None, None]

    def _norm(self, total: np.ndarray) -> np.ndarray:
        """The model's normalisation per setting: its near-camera sum over the bands used."""
        return np.sum(np.where(self.used[:, 0], self.counts[:, 0] * total[:, 0], 0.0), axis=1)

    # -- geometry at the working point ---------------------------------
    def _set_working_point(self, work: np.ndarray) -> None:
        """Disk profiles and their derivatives at the nuisances' current values."""
        self.work = work.copy()
        psf = max(self.config.psf_sigma_px + work[3], 0.3)
        scale = 1.0 + work[4]
        dists = np.array([self.geometry.distance_near_m + work[0], self.geometry.distance_far_m + work[1]])
        self.distances = dists
        self.disk_r = np.array([disk_radius_px(d, self.lem_radius_m, self.focal_px * scale) for d in dists])
        disk, d_r, d_s = [], [], []
        for s in self.settings:
            per_cam = []
            for c, prof in enumerate((s.near, s.far)):
                r = self.disk_r[c]
                base = prof.pixels.disk_profile(r, psf)[: self.n]
                dr = (
                    prof.pixels.disk_profile(r + 0.05, psf)[: self.n]
                    - prof.pixels.disk_profile(r - 0.05, psf)[: self.n]
                ) / 0.1
                ds = (
                    prof.pixels.disk_profile(r, psf + 0.05)[: self.n]
                    - prof.pixels.disk_profile(r, max(psf - 0.05, 0.1))[: self.n]
                ) / (psf + 0.05 - max(psf - 0.05, 0.1))
                per_cam.append((base, dr, ds))
            disk.append([p[0] for p in per_cam])
            d_r.append([p[1] for p in per_cam])
            d_s.append([p[2] for p in per_cam])
        self.disk = np.nan_to_num(np.array(disk))
        self.disk_dr = np.nan_to_num(np.array(d_r))
        self.disk_ds = np.nan_to_num(np.array(d_s))

    # -- the model --------------------------------------------------------
    def model(self, lambda_abs_m: float, lambda_sca_m: float) -> dict[str, np.ndarray]:
        """Template T per setting, camera and band, its MC error and derivatives (not normalised)."""
        work = self.work
        ratio = self.ratio.value * (1.0 + work[2])
        lam_att = 1.0 / (1.0 / lambda_abs_m + 1.0 / lambda_sca_m)
        tmpl = self.grid.halo(lambda_abs_m, lambda_sca_m, self.mie_g)
        scale = 1.0 + work[4]
        halo_c = tmpl.radiance[:, :, : self.grid.settings.n_bands]
        halo_e = tmpl.error[:, :, : self.grid.settings.n_bands]
        if abs(work[4]) > 0:
            x = np.arange(halo_c.shape[-1]) + 0.5
            src = x / scale
            halo_c = np.stack([[np.interp(src, x, h) for h in cam] for cam in halo_c])
            halo_e = np.stack([[np.interp(src, x, h) for h in cam] for cam in halo_e])
        halo_c, halo_e = halo_c[:, :, : self.n], halo_e[:, :, : self.n]
        w = EmissionProfile(ratio).weights()
        halo = np.einsum("k,ckb->cb", w, halo_c)
        halo_err = np.sqrt(np.einsum("k,ckb->cb", w * w, halo_e**2))
        # Attenuation of the template's nominal distances to the working ones.
        nominal = np.array([c.distance_m for c in self.grid.settings.cameras])
        att_shift = np.exp(-(self.distances - nominal) / lam_att)
        halo = halo * att_shift[:, None]
        halo_err = halo_err * att_shift[:, None]
        amp = np.array(
            [math.exp(-self.distances[0] / lam_att), ratio * math.exp(-self.distances[1] / lam_att)]
        )
        direct = amp[None, :, None] * self.disk  # (set, cam, band)
        total = direct + halo[None]
        # Derivatives with respect to each nuisance (per unit of its shift).
        deriv = np.zeros((6, *total.shape))
        for c in range(2):
            big_l = self.distances[c]
            dr_dl = -self.disk_r[c] * big_l / (big_l * big_l - self.lem_radius_m**2)
            deriv[c, :, c] = -total[:, c] / lam_att + amp[c] * self.disk_dr[:, c] * dr_dl
        # Per unit of relative shift of I0'/I0 from nominal: d(ratio)/d(shift) = nominal ratio.
        per_ratio = self.ratio.value / ratio
        deriv[2] = (ratio * halo_c[:, 1] * att_shift[:, None] * per_ratio)[None]
        deriv[2, :, 1] += direct[:, 1] * per_ratio
        deriv[3] = amp[None, :, None] * self.disk_ds
        dh = np.gradient(halo, axis=-1)
        deriv[4] = (
            amp[None, :, None] * self.disk_dr * self.disk_r[None, :, None] - (self.radius_px * dh)[None]
        )
        return {"total": total, "halo": halo, "halo_err": halo_err, "deriv": deriv}

    def chi2(
        self, lambda_abs_m: float, lambda_sca_m: float, *, detail: bool = False
    ) -> tuple[float, dict[str, object]]:
        """χ² profiled over the linear parameters at one (λ_abs, λ_sca)."""
        self.n_eval += 1
        mod = self.model(lambda_abs_m, lambda_sca_m)
        total = mod["total"]
        norm = self._norm(total)  # (set,)
        t = total / norm[:, None, None]
        # Model uncertainty: the templates' MC error, and a relative one taken on the data (not
        # the model), so that the weights do not move with the parameters being fitted. The MC
        # error is held in the normalised units of the data: dividing a held error by the
        # normalisation of the current model would let it move again (see freeze_template_errors).
        if self.frozen_halo_err is None:
            halo_err = mod["halo_err"][None] / norm[:, None, None]
        else:
            halo_err = self.frozen_halo_err
        if not self.config.template_errors:
            halo_err = np.zeros_like(halo_err)
        terr = np.sqrt(halo_err**2 + (self.config.model_rel_err * self.data) ** 2)
        g = mod["deriv"][self.active] / norm[None, :, None, None]  # (k, set, cam, band)
        var = self.data_err**2 + terr**2
        wgt = np.where(self.used, 1.0 / var, 0.0)
        n_set, _, n_band = t.shape
        # Local design per setting: s·T + β_near·[cam 0] + β_far·[cam 1].
        x = np.zeros((n_set, 3, 2, n_band))
        x[:, 0] = t
        x[:, 1, 0] = 1.0
        x[:, 2, 1] = 1.0
        y = self.data
        prior = 1.0 / self.prior_sigma[self.active] ** 2
        a = np.einsum("sicb,scb,sjcb->sij", x, wgt, x)
        a_inv = np.linalg.inv(a)
        cvec = np.einsum("sicb,scb,scb->si", x, wgt, y)
        # The nuisances act on s·T: solve with s = 1, rescale their columns by the fitted s, solve again.
        scale = np.ones(n_set)
        for _ in range(3):
            gs = g * scale[None, :, None, None]
            b = np.einsum("sicb,scb,kscb->sik", x, wgt, gs)
            cmat = np.einsum("kscb,scb,lscb->kl", gs, wgt, gs) + np.diag(prior)
            dvec = np.einsum("kscb,scb,scb->k", gs, wgt, y) - prior * self.work[self.active]
            schur = cmat - np.einsum("sik,sij,sjl->kl", b, a_inv, b)
            rhs = dvec - np.einsum("sik,sij,sj->k", b, a_inv, cvec)
            eps = np.linalg.solve(schur, rhs) if len(self.active) else np.zeros(0)
            loc = np.einsum("sij,sj->si", a_inv, cvec - np.einsum("sik,k->si", b, eps))
            if np.allclose(loc[:, 0], scale, rtol=1e-6, atol=0.0):
                break
            scale = loc[:, 0].copy()
        fit = np.einsum("si,sicb->scb", loc, x) + np.einsum("k,kscb->scb", eps, gs)
        resid = y - fit
        chi2 = float(np.sum(wgt * resid**2) + np.sum(prior * (self.work[self.active] + eps) ** 2))
        info: dict[str, object] = {}
        if detail:
            shifts = self.work.copy()
            shifts[self.active] += eps
            info = {
                "shifts": shifts,
                "fit": fit,
                "err": np.sqrt(np.where(self.used, var, np.nan)),
                # The scattered light as it appears in the background-subtracted data: s·halo + β.
                "halo": mod["halo"][None] / norm[:, None, None] * loc[:, 0, None, None] + loc[:, 1:3, None],
            }
        return chi2, info

    def n_bins(self) -> int:
        return int(self.used.sum())

    def n_linear(self) -> int:
        return 3 * len(self.settings)


def fit_wavelength(
    wavelength_nm: int,
    settings: Sequence[SettingProfiles],
    grid: TemplateGrid,
    geometry: Geometry,
    ratio: EmissionRatio,
    config: FitConfig | None = None,
) -> ChiSquareFit:
    """Fit λ_abs and λ_sca to the profiles of one wavelength.

    1. a coarse scan of χ² over the grid's λ_sca range and a broad λ_abs
       range finds the region of the minimum;
    2. Nelder-Mead in (ln λ_abs, ln λ_sca) refines it; if the PSF width or
       the image scale moved by more than a third of their prior widths, the
       disk is recomputed there (they change its shape non-linearly) and the
       minimum refined again;
    3. the curvature of χ² at the minimum gives the covariance (hence
       λ_att's error and the correlation) and brackets each parameter's
       interval, whose ends are where the χ² profiled over the other rises
       by 1;
    4. Δχ² is mapped on a grid around the minimum for the contour plot.
    """
    config = config or FitConfig()
    if not settings:
        raise FitInputError(f"{wavelength_nm} nm: no setting with stacked profiles of both cameras")
    prob = _Problem(settings, grid, geometry, ratio, config)
    obj = _Objective(prob, np.log([list(config.lambda_abs_range_m), list(grid.lambda_sca_range_m)]))
    best = obj.minimise()
    chi2_min = obj(best)
    cov = _curvature_covariance(obj, best)
    sigma = np.sqrt(np.maximum(np.diag(cov), 1e-8))
    names = ("lambda_abs", "lambda_sca")
    edges = [names[k] for k in range(2) if obj.on_edge(best[k], k)]
    intervals = []
    for k in range(2):
        lo, lo_edge = obj.crossing(best, k, -1.0, chi2_min + DCHI2_1D, sigma[k])
        hi, hi_edge = obj.crossing(best, k, 1.0, chi2_min + DCHI2_1D, sigma[k])
        if lo_edge or hi_edge:
            edges.append(names[k])
        intervals.append((math.exp(lo), math.exp(hi)))
    est = np.exp(best)
    # λ_att: 1/λ_att = 1/λ_abs + 1/λ_sca, with d(1/λ)/d(ln λ) = -1/λ.
    u = 1.0 / est
    cov_u = np.diag(-u) @ cov @ np.diag(-u)
    lam_att = 1.0 / (u[0] + u[1])
    lam_att_err = lam_att**2 * math.sqrt(max(float(cov_u.sum()), 0.0))
    corr = float(cov[0, 1] / (sigma[0] * sigma[1]))
    span = np.maximum(3.2 * np.log([iv[1] / iv[0] for iv in intervals]) / 2.0, 0.02)
    contour = obj.contour(best, span, chi2_min, config.contour_points)
    return _result(wavelength_nm, prob, est, intervals, lam_att, lam_att_err, corr, edges, contour)


class _Objective:
    """χ² of (ln λ_abs, ln λ_sca) within bounds, with the searches of `fit_wavelength`."""

    def __init__(self, prob: _Problem, bounds: np.ndarray) -> None:
        self.prob = prob
        self.bounds = bounds

    def __call__(self, p: np.ndarray) -> float:
        q = np.clip(p, self.bounds[:, 0], self.bounds[:, 1])
        penalty = 1e6 * float(np.sum((p - q) ** 2))  # keeps Nelder-Mead inside
        return self.prob.chi2(math.exp(q[0]), math.exp(q[1]))[0] + penalty

    def on_edge(self, x: float, k: int) -> bool:
        return bool(min(abs(x - self.bounds[k, 0]), abs(x - self.bounds[k, 1])) < 1e-3)

    def minimise(self) -> np.ndarray:
        la = np.linspace(self.bounds[0, 0], self.bounds[0, 1], 15)
        ls = np.linspace(self.bounds[1, 0], self.bounds[1, 1], 9)
        scan = np.array([[self(np.array([a, s])) for a in la] for s in ls])
        j, i = np.unravel_index(int(np.argmin(scan)), scan.shape)
        prob = self.prob
        best = np.array([la[i], ls[j]])
        for _ in range(2):  # the template errors held at the current best water
            prob.freeze_template_errors(math.exp(best[0]), math.exp(best[1]))
            best = self._nelder_mead(best)
        for _ in range(2):
            _, info = prob.chi2(math.exp(best[0]), math.exp(best[1]), detail=True)
            shifts = np.asarray(info["shifts"])
            work = prob.work.copy()
            for k in (3, 4):  # PSF width, image scale
                if prob.prior_sigma[k] > 0 and abs(shifts[k] - work[k]) > prob.prior_sigma[k] / 3:
                    work[k] = shifts[k]
            if np.array_equal(work, prob.work):
                break
            prob._set_working_point(work)
            best = self._nelder_mead(best)
        return best

    def _nelder_mead(self, start: np.ndarray) -> np.ndarray:
        simplex = np.array([start, start + np.array([0.1, 0.0]), start + np.array([0.0, 0.05])])
        res = minimize(
            self,
            start,
            method="Nelder-Mead",
            options={"xatol": 1e-4, "fatol": 1e-3, "initial_simplex": simplex},
        )
        return np.asarray(res.x)

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
        return float(res.fun)

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


def _curvature_covariance(obj: _Objective, best: np.ndarray) -> np.ndarray:
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


def _result(
    wavelength_nm: int,
    prob: _Problem,
    est: np.ndarray,
    intervals: list[tuple[float, float]],
    lam_att: float,
    lam_att_err: float,
    corr: float,
    edges: list[str],
    contour: ContourMap,
) -> ChiSquareFit:
    chi2_val, info = prob.chi2(float(est[0]), float(est[1]), detail=True)
    shifts = np.asarray(info["shifts"])
    nuis = tuple(
        Nuisance(_NUISANCES[k], _UNITS[_NUISANCES[k]], float(shifts[k]), float(prob.prior_sigma[k]))
        for k in prob.active
    )
    fit_arr, err_arr, halo_arr = (np.asarray(info[k]) for k in ("fit", "err", "halo"))
    models = tuple(
        SettingModel(
            s.exposure_s,
            s.gain_db,
            prob.radius_px,
            prob.data[i],
            err_arr[i],
            fit_arr[i],
            halo_arr[i],
            prob.used[i],
        )
        for i, s in enumerate(prob.settings)
    )
    return ChiSquareFit(
        wavelength_nm=int(wavelength_nm),
        lambda_abs_m=float(est[0]),
        lambda_abs_err_m=0.5 * (intervals[0][1] - intervals[0][0]),
        lambda_abs_interval_m=intervals[0],
        lambda_sca_m=float(est[1]),
        lambda_sca_err_m=0.5 * (intervals[1][1] - intervals[1][0]),
        lambda_sca_interval_m=intervals[1],
        lambda_sca_sys_err_m=float(est[1]) * prob.config.lambda_sca_sys_rel,
        lambda_att_m=lam_att,
        lambda_att_err_m=lam_att_err,
        correlation=corr,
        chi2=float(chi2_val),
        ndof=prob.n_bins() - prob.n_linear() - 2,
        mie_g=prob.mie_g,
        nuisances=nuis,
        at_edge=tuple(sorted(set(edges))),
        contour=contour,
        settings=models,
        geometry=prob.geometry,
        emission_ratio=prob.ratio,
        config=prob.config,
        focal_px=prob.focal_px,
        templates=prob.grid.settings,
        n_evaluations=prob.n_eval,
    )


def collect_settings(
    stacks: dict[tuple[str, Any], StackResult],
    wavelength_nm: int,
    near_camera: str,
    far_camera: str,
    min_frames: int = 3,
) -> list[SettingProfiles]:
    """The settings of one wavelength where both cameras have stacked, unsaturated frames.

    ``stacks`` maps ``(camera, setting)`` to stacks (`analysis.dataset.stack_by_setting`),
    settings having ``wavelength_nm``, ``exposure_s`` and ``gain_db``. Raises
    `FitInputError` with the reason when nothing can be fitted: a camera
    without accepted frames, fewer than ``min_frames`` accepted frames from a
    camera, or no setting shared by both.
    """
    by_cam: dict[str, dict[tuple[float, float], StackResult]] = {near_camera: {}, far_camera: {}}
    for (camera, setting), stack in stacks.items():
        if getattr(setting, "wavelength_nm", None) != wavelength_nm or camera not in by_cam:
            continue
        by_cam[camera][(setting.exposure_s, setting.gain_db)] = stack  # type: ignore[attr-defined]
    for cam, role in ((near_camera, "near"), (far_camera, "far")):
        n = sum(s.n_frames for s in by_cam[cam].values())
        if n == 0:
            raise FitInputError(
                f"{wavelength_nm} nm: no accepted (unsaturated) frame from the {role} camera {cam}"
            )
        if n < min_frames:
            raise FitInputError(
                f"{wavelength_nm} nm: only {n} accepted frame(s) from the {role} camera {cam}; "
                f"the χ² fit needs at least {min_frames}"
            )
    shared = sorted(set(by_cam[near_camera]) & set(by_cam[far_camera]))
    if not shared:
        raise FitInputError(
            f"{wavelength_nm} nm: no exposure/gain setting with accepted frames from both cameras "
            f"{near_camera} and {far_camera}"
        )
    return [
        SettingProfiles(
            e,
            g,
            ProfileData.from_stack(near_camera, by_cam[near_camera][(e, g)]),
            ProfileData.from_stack(far_camera, by_cam[far_camera][(e, g)]),
        )
        for e, g in shared
    ]
