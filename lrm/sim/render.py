"""Rendering one camera frame of the LEM through the water.

What a frame holds, in electrons per pixel, before the sensor turns it into
gray values:

* the LEM disk: radius ``f * a / sqrt(L² - a²)`` pixels, radiance
  ``B * exp(-s / λ_att)`` (B of the side the camera faces, s the path in water
  along each pixel's ray to the sphere's surface: ``L - a`` at the centre,
  `analysis.transport.disk.surface_path_m`), antialiased;
* the scattered-light halo around it: by default the once-scattered halo of
  `analysis.scattering.single_scatter_halo`; with ``halo_model="transport"``
  the photon transport's (`analysis.transport`: exact single scattering plus
  Monte Carlo multiple scattering, the physics the χ² fit uses), cached;
* the dark current, and fixed hot pixels of the sensor;
* optionally bioluminescence specks;

blurred by motion during the exposure (a line kernel from the module's sway)
and by a Gaussian PSF, displaced by pointing jitter, and, near the edge of the
view of a camera with an uneven dome (LRM-A in T-REX), doubled: part of the
light lands ~15 px away. The sensor then adds shot and read noise, a dark
offset, gain, the soft knee above 240, quantisation and clipping at 255.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import cv2
import numpy as np

from analysis.scattering import WaterOptics, single_scatter_halo
from analysis.transport.cache import TemplateCache
from analysis.transport.disk import surface_path_m
from analysis.transport.templates import EmissionProfile, TemplateGrid, camera_halo
from lrm.sim.blur import blur_image
from lrm.sim.camera import CameraModel
from lrm.sim.halotable import HaloTable
from lrm.sim.scene import LEMModel, Placement, Water

#: The coarse grid on which the wide halo is evaluated before upsampling.
HALO_GRID_STEP = 8
#: The halo models a renderer knows.
HALO_MODELS = ("single", "transport")


@dataclass(frozen=True)
class TransportHalo:
    """How a renderer computes its halo with ``halo_model="transport"``.

    By default the halo is a one-node template
    (`analysis.transport.templates.camera_halo`) at the water's own λ_sca
    and ⟨cos θ⟩, cached in ``cache_dir`` (None: the default cache). Its
    ``seed`` differs from the fit templates' default, so simulated frames and
    the templates fitted to them carry independent Monte Carlo noise.

    ``grid`` instead evaluates a given template grid (it must hold this
    camera and reach the frame's corner): simulation studies of the fit that
    want the simulator and the fit to share not only the physics but the
    same Monte Carlo sample, so that only the fit itself is tested.

    ``table`` renders a halo another engine made (`lrm.sim.halotable`,
    Mitsuba 3): frames whose scattered light camcal's transport never
    touched. It holds one water and a uniform LEM; the renderer refuses
    another water or an uneven LEM. ``tables`` does the same for several
    wavelengths, each table at the wavelength it records.
    """

    cache_dir: str | None = None
    n_photons: int = 1_000_000
    max_order: int = 6
    seed: int = 7
    grid: TemplateGrid | None = field(default=None, repr=False, compare=False)
    table: HaloTable | None = field(default=None, repr=False, compare=False)
    tables: tuple[HaloTable, ...] = field(default=(), repr=False, compare=False)

    def table_for(self, wavelength_nm: int) -> HaloTable | None:
        """The other engine's table for ``wavelength_nm`` (None: the transport makes the halo)."""
        if self.table is not None:
            return self.table
        if not self.tables:
            return None
        for t in self.tables:
            if t.wavelength_nm == wavelength_nm:
                return t
        have = ", ".join(str(t.wavelength_nm) for t in self.tables)
        raise ValueError(f"no halo table at {wavelength_nm} nm (the tables are at {have} nm)")


@dataclass(frozen=True)
class FrameTruth:
    """What the simulator knows about a frame it rendered.

    Gray values are noise-free expectations. ``direct_center_gray`` and
    ``halo_center_gray`` are the direct and once-scattered light at the
    LEM's centre above the dark level; ``expected_center_gray`` is the gray
    the centre pixels average to (dark level included, knee applied).
    """

    camera: str
    wavelength_nm: int
    exposure_s: float
    gain_db: float
    distance_m: float
    lambda_att_m: float
    emission_factor: float
    centroid_px: tuple[float, float]
    disk_radius_px: float
    direct_center_gray: float
    halo_center_gray: float
    background_gray: float
    expected_center_gray: float
    blur_px: float
    double_image: bool
    lem_on: bool
    lem_in_view: bool
    n_flashes: int
    psf_sigma_px: float = 0.0
    blur_xy_px: tuple[float, float] = (0.0, 0.0)

    def to_dict(self) -> dict[str, object]:
        return asdict(self)


class FrameRenderer:
    """Renders frames of one camera at one placement in one water.

    Expensive set-up (the halo integral per wavelength, the sensor's hot
    pixels, a bank of Gaussian noise) is done once; each `render` call then
    costs a few passes over the frame. Noise for a frame is a window of the
    bank at a random offset, so frames are statistically independent while
    no frame pays for generating five million normal deviates.
    """

    def __init__(
        self,
        camera: CameraModel,
        placement: Placement,
        water: Water,
        lem: LEMModel | None = None,
        *,
        seed: int = 0,
        double_image: bool = False,
        double_image_edge_fraction: float = 0.08,
        double_image_offset_px: float = 15.0,
        double_image_fraction: float = 0.42,
        halo_model: str = "single",
        transport: TransportHalo | None = None,
    ) -> None:
        self.camera = camera
        self.placement = placement
        self.water = water
        self.lem = lem or LEMModel()
        self.double_image = double_image
        self.double_image_edge_fraction = double_image_edge_fraction
        self.double_image_offset_px = double_image_offset_px
        self.double_image_fraction = double_image_fraction
        if halo_model not in HALO_MODELS:
            raise ValueError(f"halo_model must be one of {', '.join(HALO_MODELS)}, got {halo_model!r}")
        self.halo_model = halo_model
        self.transport = transport or TransportHalo()
        a, big_l = self.lem.radius_m, placement.distance_m
        if big_l <= a:
            raise ValueError(f"camera {placement.camera} at {big_l} m sits inside the LEM")
        self.disk_radius_px = camera.focal_px * a / math.sqrt(big_l * big_l - a * a)
        half_diag = math.hypot(camera.width_px, camera.height_px)
        psi_max = math.atan(half_diag / camera.focal_px) * 1.05
        self._psi_grid = np.concatenate([[0.0], np.geomspace(1e-6, psi_max, 400)])
        if halo_model == "transport":
            # The transport's halo is tabulated per one-pixel band: sample it every half pixel so
            # that interpolating here does not reshape it (its kinks would move otherwise).
            self._psi_grid = np.arctan(
                np.arange(0.0, math.tan(psi_max) * camera.focal_px + 1.0, 0.5) / camera.focal_px
            )
        self._halo: dict[int, np.ndarray] = {}
        camera_seed = int(np.frombuffer(placement.camera.encode()[:8].ljust(8, b"\0"), "<u8")[0])
        self._hot = camera.hot_pixels(seed=(seed * 7919 + camera_seed) % (2**63))
        npix = camera.width_px * camera.height_px
        self._bank_extra = max(npix // 2, 1 << 16)
        bank_rng = np.random.default_rng([seed, camera_seed % (2**32), 17])
        self._bank = bank_rng.standard_normal(npix + self._bank_extra, dtype=np.float32)

    # -- physics helpers -------------------------------------------------
    def halo_table(self, wavelength_nm: int) -> np.ndarray:
        """h(ψ) on the renderer's ψ grid: halo radiance over LEM surface radiance."""
        if wavelength_nm not in self._halo:
            water = self.water.at(wavelength_nm)
            if self.halo_model == "transport":
                self._halo[wavelength_nm] = self._transport_halo(wavelength_nm, water)
            else:
                self._halo[wavelength_nm] = single_scatter_halo(
                    self._psi_grid, self.placement.distance_m, water, self.lem.radius_m
                )
        return self._halo[wavelength_nm]

    def _transport_halo(self, wavelength_nm: int, water: WaterOptics) -> np.ndarray:
        """The transport's halo over the surface radiance of the side this camera faces."""
        opts = self.transport
        emission = EmissionProfile(float(self.lem.emission_ratio.get(wavelength_nm, 1.0)))
        side = -1 if self.placement.faces_far_side else 1
        table = opts.table_for(wavelength_nm)
        if table is not None:
            t = table.water
            if max(abs(t.lambda_abs_m - water.lambda_abs_m), abs(t.lambda_sca_m - water.lambda_sca_m)) > 1e-6:
                raise ValueError(f"the halo table is of another water ({table.describe()})")
            if abs(self.emission_factor(wavelength_nm) - 1.0) > 1e-9 or emission.far_near_ratio != 1.0:
                raise ValueError("a halo table is of a uniform LEM: give the LEM an emission ratio of 1")
            return table.at(self.placement.distance_m, self._psi_grid)
        if opts.grid is not None:
            grid = opts.grid
            if abs(grid.settings.focal_px - self.camera.focal_px) > 1e-6 * self.camera.focal_px:
                raise ValueError(
                    f"transport grid focal_px {grid.settings.focal_px} differs from the camera's "
                    f"{self.camera.focal_px}"
                )
            h = grid.halo_at_psi(
                self._psi_grid,
                grid.camera_index(self.placement.distance_m, side),
                water.lambda_abs_m,
                water.lambda_sca_m,
                water.mie_g,
                emission,
            )
        else:
            h = camera_halo(
                self._psi_grid,
                self.placement.distance_m,
                side,
                self.camera.focal_px,
                water.lambda_abs_m,
                water.lambda_sca_m,
                water.mie_g,
                water.rayleigh_fraction,
                emission,
                lem_radius_m=self.lem.radius_m,
                refractive_index=water.refractive_index,
                n_photons=opts.n_photons,
                max_order=opts.max_order,
                seed=opts.seed,
                cache=TemplateCache(opts.cache_dir),
            )
        return h / self.emission_factor(wavelength_nm)

    def surface_radiance_e_per_s(self, wavelength_nm: int) -> float:
        """B of the LEM side this camera faces, before the water."""
        try:
            b = self.lem.radiance_e_per_s[wavelength_nm]
        except KeyError:
            raise ValueError(f"the LEM has no {wavelength_nm} nm LED") from None
        return b * self.emission_factor(wavelength_nm)

    def emission_factor(self, wavelength_nm: int) -> float:
        if self.placement.faces_far_side:
            return float(self.lem.emission_ratio[wavelength_nm])
        return 1.0

    def direct_e_per_s(self, wavelength_nm: int, rho_px: np.ndarray | float) -> np.ndarray:
        """The disk's radiance at ``rho_px`` from its centre: B·exp(-s/λ_att) along each pixel's ray.

        ``s`` is the path to the sphere's surface (`surface_path_m`), not the
        distance to its centre: the halo's light starts at the surface too.
        Beyond the limb it takes the limb's value (the antialiasing ramp).
        """
        att = self.water.at(wavelength_nm).lambda_att_m
        s = surface_path_m(
            np.minimum(rho_px, self.disk_radius_px),
            self.placement.distance_m,
            self.lem.radius_m,
            self.camera.focal_px,
        )
        return self.surface_radiance_e_per_s(wavelength_nm) * np.exp(-s / att)

    def direct_center_e_per_s(self, wavelength_nm: int) -> float:
        """The disk's radiance at its centre: B·exp(-(L - a)/λ_att)."""
        return float(self.direct_e_per_s(wavelength_nm, 0.0))

    def _halo_e_per_s(self, wavelength_nm: int, rho_px: np.ndarray) -> np.ndarray:
        psi = np.arctan(rho_px / self.camera.focal_px)
        h = np.interp(psi, self._psi_grid, self.halo_table(wavelength_nm))
        return (self.surface_radiance_e_per_s(wavelength_nm) * h).astype(np.float32)

    def expected_center_gray(self, wavelength_nm: int, exposure_s: float, gain_db: float) -> float:
        """Noise-free mean gray of the LEM's centre pixels at a setting (knee applied).

        What the schedule preview and the tests use to know, without rendering,
        whether a setting will be too dark, in range, or saturated.
        """
        cam = self.camera
        gain_total = cam.gray_per_electron * cam.gain_factor(gain_db)
        b = self.surface_radiance_e_per_s(wavelength_nm)
        direct = self.direct_center_e_per_s(wavelength_nm)
        halo = b * float(self.halo_table(wavelength_nm)[0])
        dark = cam.black_level_gray + cam.dark_current_e_per_s * exposure_s * gain_total
        return float(cam.respond(np.array([dark + (direct + halo) * exposure_s * gain_total]))[0])

    # -- rendering -------------------------------------------------------
    def render(
        self,
        wavelength_nm: int,
        exposure_s: float,
        gain_db: float,
        *,
        rng: np.random.Generator,
        offset_px: tuple[float, float] = (0.0, 0.0),
        blur_px: tuple[float, float] = (0.0, 0.0),
        lem_on: bool = True,
        flashes_per_frame: float = 0.0,
        psf_sigma_px: float | None = None,
    ) -> tuple[np.ndarray, FrameTruth]:
        """One 8-bit frame and what the simulator knows about it.

        ``offset_px`` moves the LEM from the optical axis (pointing, tilt,
        jitter); ``blur_px`` is the LEM's motion on the sensor during the
        exposure (x, y); ``psf_sigma_px`` this frame's Gaussian PSF (None:
        the camera's). ``lem_on=False`` renders a dark frame.
        """
        cam = self.camera
        psf = cam.psf_sigma_px if psf_sigma_px is None else float(psf_sigma_px)
        if not 0 <= psf <= 50:
            raise ValueError(f"psf_sigma_px must lie in [0, 50], got {psf}")
        cam.check_setting(exposure_s, gain_db)
        height, width = cam.height_px, cam.width_px
        water = self.water.at(wavelength_nm)
        cx = cam.center_xy[0] + float(offset_px[0])
        cy = cam.center_xy[1] + float(offset_px[1])
        r_disk = self.disk_radius_px
        b_direct = self.direct_center_e_per_s(wavelength_nm) if lem_on else 0.0
        gain_total = cam.gray_per_electron * cam.gain_factor(gain_db)

        # Electrons per second, full frame: first the wide halo on a coarse grid.
        rate = np.zeros((height, width), dtype=np.float32)
        if lem_on:
            step = HALO_GRID_STEP
            ny, nx = -(-height // step), -(-width // step)
            # Grid points sit where cv2.resize puts the centres of the coarse cells.
            gy = np.arange(ny, dtype=np.float32) * step + (step - 1) / 2.0
            gx = np.arange(nx, dtype=np.float32) * step + (step - 1) / 2.0
            rho = np.sqrt((gy[:, None] - cy) ** 2 + (gx[None, :] - cx) ** 2)
            coarse = self._halo_e_per_s(wavelength_nm, rho)
            big = cv2.resize(coarse, (nx * step, ny * step), interpolation=cv2.INTER_LINEAR)
            rate = big[:height, :width].astype(np.float32, copy=False)

        # The disk (and the steep inner halo) exactly, in a window around the LEM.
        blur_len = math.hypot(*blur_px)
        ghost = self.double_image and lem_on and self._near_edge(cx, cy)
        ghost_dx = ghost_dy = 0.0
        if ghost:
            to_centre = np.array(cam.center_xy) - np.array([cx, cy])
            norm = float(np.hypot(*to_centre)) or 1.0
            ghost_dx, ghost_dy = (to_centre / norm * self.double_image_offset_px).tolist()
        reach = r_disk * 3 + 4 * psf + blur_len + abs(ghost_dx) + abs(ghost_dy) + 12
        x0, x1 = max(int(cx - reach), 0), min(int(cx + reach) + 1, width)
        y0, y1 = max(int(cy - reach), 0), min(int(cy + reach) + 1, height)
        in_view = lem_on and x1 > x0 and y1 > y0
        if in_view:
            ys = np.arange(y0, y1, dtype=np.float32)[:, None]
            xs = np.arange(x0, x1, dtype=np.float32)[None, :]
            rho = np.sqrt((ys - cy) ** 2 + (xs - cx) ** 2)
            disk = np.clip(r_disk - rho + 0.5, 0.0, 1.0) * self.direct_e_per_s(wavelength_nm, rho)
            if ghost:
                rho2 = np.sqrt((ys - cy - ghost_dy) ** 2 + (xs - cx - ghost_dx) ** 2)
                disk2 = np.clip(r_disk - rho2 + 0.5, 0.0, 1.0) * self.direct_e_per_s(wavelength_nm, rho2)
                f = self.double_image_fraction
                disk = (1 - f) * disk + f * disk2
            disk = disk.astype(np.float32)
            disk = blur_image(disk, blur_px, psf)
            rate[y0:y1, x0:x1] = disk + self._halo_e_per_s(wavelength_nm, rho)

        # Electrons collected in the exposure, hot pixels, bioluminescence.
        electrons = rate
        electrons *= np.float32(exposure_s)
        electrons += np.float32(cam.dark_current_e_per_s * exposure_s)
        hot_r, hot_c, hot_rate = self._hot
        electrons[hot_r, hot_c] += (hot_rate * exposure_s).astype(np.float32)
        n_flashes = int(rng.poisson(flashes_per_frame)) if flashes_per_frame > 0 else 0
        for _ in range(n_flashes):
            _add_flash(electrons, rng, exposure_s)

        # The sensor: shot + read noise, gain, offset, knee, quantisation.
        sigma = np.sqrt(electrons + np.float32(cam.read_noise_e**2))
        start = int(rng.integers(0, self._bank_extra))
        noise = self._bank[start : start + height * width].reshape(height, width)
        gray = electrons
        gray *= np.float32(gain_total)
        gray += np.float32(cam.black_level_gray)
        sigma *= noise
        sigma *= np.float32(gain_total)
        gray += sigma
        if in_view:
            gray[y0:y1, x0:x1] = cam.respond(gray[y0:y1, x0:x1])
        gray[hot_r, hot_c] = cam.respond(gray[hot_r, hot_c])
        np.clip(gray, 0.0, 255.0, out=gray)
        gray += np.float32(0.5)
        frame = gray.astype(np.uint8)

        background = cam.black_level_gray + cam.dark_current_e_per_s * exposure_s * gain_total
        direct = b_direct * exposure_s * gain_total
        h0 = float(self.halo_table(wavelength_nm)[0]) if lem_on else 0.0
        halo = self.surface_radiance_e_per_s(wavelength_nm) * h0 * exposure_s * gain_total
        expected = float(cam.respond(np.array([background + direct + halo]))[0])
        f = self.double_image_fraction if ghost else 0.0
        truth = FrameTruth(
            camera=self.placement.camera,
            wavelength_nm=int(wavelength_nm),
            exposure_s=float(exposure_s),
            gain_db=float(gain_db),
            distance_m=self.placement.distance_m,
            lambda_att_m=water.lambda_att_m,
            emission_factor=self.emission_factor(wavelength_nm),
            centroid_px=(cx + f * ghost_dx, cy + f * ghost_dy),
            disk_radius_px=r_disk,
            direct_center_gray=direct,
            halo_center_gray=halo,
            background_gray=background,
            expected_center_gray=expected,
            blur_px=blur_len,
            double_image=ghost,
            lem_on=lem_on,
            lem_in_view=bool(
                lem_on and r_disk <= cx <= width - 1 - r_disk and r_disk <= cy <= height - 1 - r_disk
            ),
            n_flashes=n_flashes,
            psf_sigma_px=psf,
            blur_xy_px=(float(blur_px[0]), float(blur_px[1])),
        )
        return frame, truth

    def _near_edge(self, cx: float, cy: float) -> bool:
        """True when the disk comes within the edge band of the view (8 % of its size)."""
        w, h = self.camera.width_px, self.camera.height_px
        edge = min(cx, cy, w - 1 - cx, h - 1 - cy) - self.disk_radius_px
        return edge < self.double_image_edge_fraction * min(w, h)


def _add_flash(electrons: np.ndarray, rng: np.random.Generator, exposure_s: float) -> None:
    """A bioluminescent speck: a small bright Gaussian blob somewhere in the frame."""
    height, width = electrons.shape
    x, y = rng.uniform(0, width), rng.uniform(0, height)
    sigma = rng.uniform(0.7, 2.5)
    peak = rng.uniform(2e3, 2e5) * min(exposure_s, 0.05)
    r = math.ceil(4 * sigma)
    x0, x1 = max(int(x) - r, 0), min(int(x) + r + 1, width)
    y0, y1 = max(int(y) - r, 0), min(int(y) + r + 1, height)
    ys = np.arange(y0, y1, dtype=np.float32)[:, None] - y
    xs = np.arange(x0, x1, dtype=np.float32)[None, :] - x
    electrons[y0:y1, x0:x1] += np.float32(peak) * np.exp(-(xs**2 + ys**2) / (2 * sigma**2))
