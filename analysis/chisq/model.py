"""The profiled χ² of one wavelength: data, model (direct disk + halo templates) and nuisances."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from analysis.attenuation import EmissionRatio, Geometry
from analysis.chisq.data import FitInputError, SettingProfiles, quantisation_bias_gray
from analysis.chisq.results import NUISANCES, FitConfig
from analysis.transport.disk import BandPixels, disk_radius_px, disk_transmittance
from analysis.transport.source import HaloSource
from analysis.transport.templates import EmissionProfile


class OutsideTemplates(ValueError):
    """The water asked for lies outside what the templates serve."""


def shape_basis(radius_px: np.ndarray, disk_px: float, step: float) -> np.ndarray:
    """The halo's shape functions at ``radius_px`` (rows): first the halo under the disk (1 inside,
    0 outside), then hat functions ``step`` apart in ln ρ from the disk's edge to the last band.

    Outside the disk the hats sum to one; the halo under the disk is its own (it sits under the
    direct light, where no other engine's halo is better known than to a few per cent).
    """
    inside = radius_px < disk_px
    u = np.log(np.maximum(radius_px, disk_px) / disk_px)
    n_knots = max(math.ceil(float(u.max()) / step) + 1, 2)
    knots = np.linspace(0.0, float(u.max()), n_knots)
    width = knots[1] - knots[0] if n_knots > 1 else 1.0
    hats = np.clip(1.0 - np.abs(u[None, :] - knots[:, None]) / max(width, 1e-9), 0.0, 1.0)
    hats[:, inside] = 0.0
    return np.vstack([inside.astype(np.float64)[None, :], hats])


#: Prior width of the edge's mixture weights (per setting and camera; see `Problem.chi2`).
EDGE_WEIGHT_PRIOR = 1.0


class Problem:
    """Precomputed data and geometry of one wavelength; evaluates the profiled χ²."""

    def __init__(
        self,
        settings: Sequence[SettingProfiles],
        grid: HaloSource,
        geometry: Geometry,
        ratio: EmissionRatio,
        config: FitConfig,
        disk_cache: dict[tuple[int, int, float, float, float], tuple[np.ndarray, ...]] | None = None,
    ) -> None:
        # Disk profiles per (setting, camera, radius, PSF width): refits of the same settings with
        # another input (the systematic budget) share them; they cost most of a refit otherwise.
        self._disk_cache = {} if disk_cache is None else disk_cache
        self.grid = grid
        self.geometry = geometry
        self.ratio = ratio
        self.config = config
        self.settings = list(settings)
        ts = grid.settings
        self.focal_px = ts.focal_px
        self.lem_radius_m = ts.lem_radius_m
        self.mie_g = ts.mie_g_nodes[0] if config.mie_g is None else float(config.mie_g)
        # The Rayleigh share: the templates' own unless a phase fit sets another (`set_phase`).
        self.rayleigh_share = float(ts.rayleigh_fraction)
        n_tmpl = ts.n_bands
        n = min(n_tmpl, *(len(p.mean_gray) for s in settings for p in (s.near, s.far)))
        self.n = n
        self.radius_px = np.arange(n) + 0.5
        # With a free edge (`FitConfig.edge_sigmas_px`) the blur's width per setting and camera is
        # among the linear parameters, and the one PSF width of the nuisances would repeat it.
        self.edge_sigmas = tuple(float(x) for x in config.edge_sigmas_px)
        sig = np.array(
            [
                geometry.distance_near_err_m,
                geometry.distance_far_err_m,
                ratio.err / ratio.value,
                0.0 if self.edge_sigmas else config.psf_sigma_err_px,
                config.focal_rel_err,
                config.halo_scale_err,
            ]
        )
        # The halo's shape per camera: `shape_basis` functions in ln ρ, a nuisance each (see
        # `FitConfig.halo_shape_err`), after the six above.
        self.shape = []
        names = list(NUISANCES)
        widths: list[float] = []
        for c, (cam, d) in enumerate((("near", geometry.distance_near_m), ("far", geometry.distance_far_m))):
            rd = disk_radius_px(d, self.lem_radius_m, self.focal_px)
            basis = shape_basis(np.arange(n) + 0.5, rd, config.halo_shape_step)
            self.shape.append((c, basis))
            names += [f"halo_under_disk_{cam}"] + [f"halo_shape_{cam}_{j}" for j in range(1, len(basis))]
            widths += [config.halo_disk_err] + [config.halo_shape_err] * (len(basis) - 1)
        self.nuisance_names = tuple(names)
        sig = np.concatenate([sig, widths])
        self.active = np.flatnonzero(sig > 0)
        self.prior_sigma = sig
        self.work = np.zeros(len(sig))  # working point: shifts from nominal of the nuisances
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
        self.set_working_point(np.zeros(len(self.prior_sigma)))

    def set_phase(self, mie_g: float, rayleigh_share: float) -> None:
        """Evaluate the model at another phase function (Mie ⟨cos θ⟩, Rayleigh share).

        The templates' errors stay frozen where they were: χ² at different phase functions compares
        only with the same weights.
        """
        self.mie_g = float(mie_g)
        self.rayleigh_share = float(rayleigh_share)

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
    def set_working_point(self, work: np.ndarray) -> None:
        """Disk profiles and their derivatives at the nuisances' current values."""
        self.work = work.copy()
        psf = max(self.config.psf_sigma_px + work[3], 0.3)
        scale = 1.0 + work[4]
        dists = np.array([self.geometry.distance_near_m + work[0], self.geometry.distance_far_m + work[1]])
        self.distances = dists
        self.disk_r = np.array([disk_radius_px(d, self.lem_radius_m, self.focal_px * scale) for d in dists])
        disk, d_r, d_s, pieces = [], [], [], []
        for i, s in enumerate(self.settings):
            per_cam = []
            for c, prof in enumerate((s.near, s.far)):
                key = (i, c, round(float(self.disk_r[c]), 9), round(float(psf), 9), round(float(dists[c]), 9))
                if key not in self._disk_cache:
                    self._disk_cache[key] = self._disk_pieces(
                        prof.pixels, float(self.disk_r[c]), psf, float(dists[c]), self.focal_px * scale
                    )
                per_cam.append(self._disk_cache[key])
            pieces.append(per_cam)
            disk.append([p[0] for p in per_cam])
            d_r.append([p[1] for p in per_cam])
            d_s.append([p[2] for p in per_cam])
        self.disk_m1 = np.nan_to_num(np.array([[p[3] for p in cams] for cams in pieces]))
        self.disk_m2 = np.nan_to_num(np.array([[p[4] for p in cams] for cams in pieces]))
        # (set, cam, basis, band): the disk blurred more or less than the working PSF, minus the disk
        # at it; each conserves the disk's light and moves it across the edge only.
        self.edge_basis = np.nan_to_num(np.array([[p[5] for p in cams] for cams in pieces]))
        self.disk = np.nan_to_num(np.array(disk))
        self.disk_dr = np.nan_to_num(np.array(d_r))
        self.disk_ds = np.nan_to_num(np.array(d_s))

    def _disk_pieces(
        self, pixels: BandPixels, r: float, psf: float, distance_m: float, focal_px: float
    ) -> tuple[np.ndarray, ...]:
        """The blurred disk's band profile, its derivatives in radius and PSF width, its path moments.

        The moments (`BandPixels.disk_path_moments`) give the disk's
        transmittance along each pixel's ray to the sphere's surface.
        """
        moments = pixels.disk_path_moments(r, psf, distance_m, self.lem_radius_m, focal_px)
        base, m1, m2 = (m[: self.n] for m in moments)
        dr = (
            pixels.disk_profile(r + 0.05, psf)[: self.n] - pixels.disk_profile(r - 0.05, psf)[: self.n]
        ) / 0.1
        lo = max(psf - 0.05, 0.1)
        ds = (pixels.disk_profile(r, psf + 0.05)[: self.n] - pixels.disk_profile(r, lo)[: self.n]) / (
            psf + 0.05 - lo
        )
        ref = pixels.disk_profile(r, psf)[: self.n]
        edge = np.array([pixels.disk_profile(r, w)[: self.n] - ref for w in self.edge_sigmas]).reshape(
            len(self.edge_sigmas), self.n
        )
        return base, dr, ds, m1, m2, edge

    # -- the model --------------------------------------------------------
    def model(self, lambda_abs_m: float, lambda_sca_m: float) -> dict[str, np.ndarray]:
        """Template T per setting, camera and band, its MC error and derivatives (not normalised)."""
        work = self.work
        ratio = self.ratio.value * (1.0 + work[2])
        lam_att = 1.0 / (1.0 / lambda_abs_m + 1.0 / lambda_sca_m)
        try:
            tmpl = self.grid.halo(lambda_abs_m, lambda_sca_m, self.mie_g, self.rayleigh_share)
        except ValueError as exc:
            raise OutsideTemplates(str(exc)) from exc
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
        # The disk's transmittance along each pixel's ray to the sphere's surface (not its centre).
        a = self.lem_radius_m
        # The edge's derivatives take the limb's transmittance (path sqrt(L² - a²)).
        limb = np.sqrt(self.distances**2 - a * a)
        amp = np.array([math.exp(-limb[0] / lam_att), ratio * math.exp(-limb[1] / lam_att)])
        direct = np.stack(
            [
                (1.0 if c == 0 else ratio)
                * disk_transmittance(
                    (self.disk[:, c], self.disk_m1[:, c], self.disk_m2[:, c]), self.distances[c], a, lam_att
                )
                for c in range(2)
            ],
            axis=1,
        )  # (set, cam, band)
        total = direct + halo[None]
        # Derivatives with respect to each nuisance (per unit of its shift).
        deriv = np.zeros((len(self.prior_sigma), *total.shape))
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
        # The templates' accuracy: the halo's level, and its shape per camera.
        deriv[5] = halo[None]
        k = len(NUISANCES)
        for c, basis in self.shape:
            deriv[k : k + len(basis), :, c] = (halo[c][None, :] * basis)[:, None, :]
            k += len(basis)
        return {"total": total, "halo": halo, "halo_err": halo_err, "deriv": deriv, "amp": amp}

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
        # Plus, per camera, the edge's blur: the disk blurred by each of `edge_sigmas` instead of the
        # working PSF, in the disk's own amplitude (a coefficient is then a mixture weight times s).
        n_edge = len(self.edge_sigmas)
        x = np.zeros((n_set, 3 + 2 * n_edge, 2, n_band))
        x[:, 0] = t
        x[:, 1, 0] = 1.0
        x[:, 2, 1] = 1.0
        for c in range(2):
            cols = slice(3 + c * n_edge, 3 + (c + 1) * n_edge)
            x[:, cols, c] = self.edge_basis[:, c] * (mod["amp"][c] / norm)[:, None, None]
        y = self.data
        prior = 1.0 / self.prior_sigma[self.active] ** 2
        # Flattened over (camera, band), as matrix products: the settings' blocks are small, the
        # bands many (einsum over five indices cost most of a refit).
        n_loc, n_k = x.shape[1], len(self.active)
        xf = x.reshape(n_set, n_loc, -1)
        wf = wgt.reshape(n_set, -1)
        yf = y.reshape(n_set, -1)
        g0 = g.reshape(n_k, n_set, -1).transpose(1, 0, 2)  # (set, k, n)
        xw = xf * wf[:, None, :]
        a = xw @ xf.transpose(0, 2, 1)
        # A weak prior on the edge's mixture weights (±1, a whole disk's worth of blur) keeps the local
        # problem regular where a camera's edge holds few bands; it adds Σ w² to χ² below.
        ridge = np.zeros(n_loc)
        ridge[3:] = 1.0 / EDGE_WEIGHT_PRIOR**2
        a = a + np.diag(ridge)[None]
        a_inv = np.linalg.inv(a)
        cvec = (xw @ yf[:, :, None])[:, :, 0]
        b0 = xw @ g0.transpose(0, 2, 1)  # (set, loc, k)
        gw = g0 * wf[:, None, :]
        c0 = gw @ g0.transpose(0, 2, 1)  # (set, k, k)
        d0 = (gw @ yf[:, :, None])[:, :, 0]  # (set, k)
        # The nuisances act on s·T: solve with s = 1, rescale their columns by the fitted s, solve again.
        scale = np.ones(n_set)
        for _ in range(3):
            b = b0 * scale[:, None, None]
            cmat = np.tensordot(scale**2, c0, axes=(0, 0)) + np.diag(prior)
            dvec = scale @ d0 - prior * self.work[self.active]
            bt = b.transpose(0, 2, 1)
            schur = cmat - (bt @ (a_inv @ b)).sum(axis=0)
            rhs = dvec - (bt @ (a_inv @ cvec[:, :, None]))[:, :, 0].sum(axis=0)
            eps = np.linalg.solve(schur, rhs) if n_k else np.zeros(0)
            loc = (a_inv @ (cvec - b @ eps)[:, :, None])[:, :, 0]
            if np.allclose(loc[:, 0], scale, rtol=1e-6, atol=0.0):
                break
            scale = loc[:, 0].copy()
        local = (loc[:, None, :] @ xf)[:, 0]
        fit = (local + scale[:, None] * (eps @ g0)).reshape(y.shape)
        resid = y - fit
        chi2 = float(
            np.sum(wgt * resid**2)
            + np.sum(prior * (self.work[self.active] + eps) ** 2)
            + np.sum(ridge[None] * loc**2)
        )
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
