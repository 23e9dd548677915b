"""The direct disk against the exact transmittance along each pixel's ray to the LEM's surface.

The exact value is computed here independently: each pixel's ray, a unit
vector through (x/f, y/f, 1), meets the sphere of radius a centred at
distance L where the quadratic |t·u - L·z|² = a² has its smaller root; the
light then travels t metres of water. The fit's model
(`BandPixels.disk_path_moments` + `disk_transmittance`) and the simulator
(`FrameRenderer`) must both reproduce exp(-t/λ_att) band by band.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from analysis.scattering import WaterOptics
from analysis.transport.disk import (
    BandPixels,
    blurred_disk,
    disk_radius_px,
    disk_transmittance,
    surface_path_m,
)
from camcal.core.frameset import TREX_FOCAL_PX
from lrm.sim import CameraModel, FrameRenderer, Placement
from lrm.sim.scene import LEMModel, Water

A_M = 0.215
FOCAL_PX = TREX_FOCAL_PX


def exact_path_m(dx_px: np.ndarray, dy_px: np.ndarray, distance_m: float, focal_px: float) -> np.ndarray:
    """Ray-sphere intersection: the water path along each pixel's ray (NaN where it misses)."""
    u = np.stack([dx_px / focal_px, dy_px / focal_px, np.ones_like(dx_px)])
    u /= np.linalg.norm(u, axis=0)
    # |t u - L z|² = a²  →  t² - 2 t L u_z + L² - a² = 0
    b = distance_m * u[2]
    disc = b * b - (distance_m * distance_m - A_M * A_M)
    with np.errstate(invalid="ignore"):
        return np.where(disc >= 0, b - np.sqrt(disc), np.nan)


def exact_band_means(distance_m: float, lam_att_m: float, n_bands: int) -> tuple[BandPixels, np.ndarray]:
    """A crop around a sub-pixel centre, its bands, and the band means of exp(-t/λ) over pixels that hit."""
    centre = (130.3, 129.6)
    shape = (261, 261)
    pixels = BandPixels.from_crop(shape, centre, n_bands)
    rows, cols = np.unravel_index(pixels.flat_index, shape)
    t = exact_path_m(cols - centre[0], rows - centre[1], distance_m, FOCAL_PX)
    return pixels, pixels.band_mean(np.where(np.isfinite(t), np.exp(-t / lam_att_m), np.nan))


@pytest.mark.parametrize("distance_m", [21.56, 41.62])
def test_surface_path_is_the_ray_sphere_intersection(distance_m: float) -> None:
    r = disk_radius_px(distance_m, A_M, FOCAL_PX)
    rho = np.linspace(0.0, r * 0.999, 200)
    exact = exact_path_m(rho, np.zeros_like(rho), distance_m, FOCAL_PX)
    np.testing.assert_allclose(surface_path_m(rho, distance_m, A_M, FOCAL_PX), exact, rtol=0, atol=1e-9)
    assert float(surface_path_m(0.0, distance_m, A_M, FOCAL_PX)) == pytest.approx(distance_m - A_M, abs=1e-12)
    limb = float(surface_path_m(r, distance_m, A_M, FOCAL_PX))
    assert limb == pytest.approx(math.sqrt(distance_m**2 - A_M**2), abs=1e-9)


@pytest.mark.parametrize(
    ("distance_m", "lam_att_m"), [(21.56, 12.5), (41.62, 12.5), (21.56, 5.0), (21.56, 20.0)]
)
def test_fit_disk_model_matches_exact_transmittance(distance_m: float, lam_att_m: float) -> None:
    r = disk_radius_px(distance_m, A_M, FOCAL_PX)
    n_bands = int(r) + 3
    pixels, exact = exact_band_means(distance_m, lam_att_m, n_bands)
    model = disk_transmittance(
        pixels.disk_path_moments(r, 0.0, distance_m, A_M, FOCAL_PX), distance_m, A_M, lam_att_m
    )
    inner = np.arange(n_bands) < int(r) - 1  # bands wholly inside the disk (no edge ramp)
    np.testing.assert_allclose(model[inner], exact[inner], rtol=2e-4)
    # The whole direct disk (every pixel that sees the sphere) within 0.5 %.
    w = pixels.count[inner]
    total_model = float(np.sum(w * model[inner]))
    total_exact = float(np.sum(w * exact[inner]))
    assert total_model / total_exact == pytest.approx(1.0, abs=5e-3)
    # The old model, exp(-L/λ) with L to the LEM's centre, is too faint: by a/λ at the centre, by
    # 2a/(3λ) over the disk (the path's excess over L - a averages a/3 over the disk's area).
    old = math.exp(-distance_m / lam_att_m) * float(np.sum(w)) / total_exact
    assert 1.0 - old == pytest.approx(2 * A_M / (3 * lam_att_m), rel=0.1)
    assert 1.0 - math.exp(-distance_m / lam_att_m) / exact[0] == pytest.approx(A_M / lam_att_m, rel=0.05)


def test_blurred_disk_model_keeps_its_brightness_profile() -> None:
    """With the PSF the interior keeps the transmittance's dome; only the edge bands change."""
    distance_m, lam = 21.56, 8.0
    r = disk_radius_px(distance_m, A_M, FOCAL_PX)
    pixels, exact = exact_band_means(distance_m, lam, int(r) + 8)
    sharp = disk_transmittance(
        pixels.disk_path_moments(r, 0.0, distance_m, A_M, FOCAL_PX), distance_m, A_M, lam
    )
    blurred = disk_transmittance(
        pixels.disk_path_moments(r, 1.2, distance_m, A_M, FOCAL_PX), distance_m, A_M, lam
    )
    inner = np.arange(len(sharp)) < int(r) - 6
    np.testing.assert_allclose(blurred[inner], exact[inner], rtol=3e-4)
    # Light is only moved across the edge, not created: the sums agree.
    w = pixels.count
    assert float(np.sum(w * blurred)) == pytest.approx(float(np.sum(w * sharp)), rel=1e-3)
    assert exact[0] / exact[int(r) - 2] > math.exp(0.7 * A_M / lam)  # the dome is there


def test_simulator_draws_the_exact_transmittance() -> None:
    cam = CameraModel(width_px=400, height_px=400, fov_deg=16.0, psf_sigma_px=0.0)
    lem = LEMModel()
    water = Water({460: WaterOptics(12.0, 12.0)})
    near = FrameRenderer(cam, Placement("A", 21.56), water, lem)
    lam = water.at(460).lambda_att_m
    r = near.disk_radius_px
    rho = np.linspace(0.0, 0.99 * r, 50)
    exact = exact_path_m(rho, np.zeros_like(rho), 21.56, cam.focal_px)
    b = lem.radiance_e_per_s[460]
    np.testing.assert_allclose(near.direct_e_per_s(460, rho), b * np.exp(-exact / lam), rtol=1e-9)
    assert near.direct_center_e_per_s(460) == pytest.approx(b * math.exp(-(21.56 - A_M) / lam), rel=1e-12)
    # The far camera faces the far side: I0'/I0 times the same transmittance.
    far = FrameRenderer(cam, Placement("B", 41.62, faces_far_side=True), water, lem)
    assert far.direct_center_e_per_s(460) == pytest.approx(
        b * lem.emission_ratio[460] * math.exp(-(41.62 - A_M) / lam), rel=1e-12
    )
    # The centre ratio that I_center uses keeps exp(-(L_far - L_near)/λ): the a cancels.
    ratio = near.direct_center_e_per_s(460) / far.direct_center_e_per_s(460) * lem.emission_ratio[460]
    assert math.log(ratio) == pytest.approx((41.62 - 21.56) / lam, rel=1e-12)


@pytest.mark.parametrize("sigma_px", [0.1, 0.3, 1.2])
def test_the_blurred_disk_matches_a_brute_force_convolution_for_narrow_and_wide_psfs(sigma_px: float) -> None:
    """The disk with its one-pixel edge ramp, blurred by a Gaussian, against the convolution summed
    on a fine grid around each point (no noncentral χ², no quadrature over the ramp). A PSF of
    0.1 px leaves a sharp step inside the ramp: eight Gauss-Legendre nodes over it were off by up
    to 3·10⁻⁴ there."""
    radius = 6.3
    rho = np.arange(radius - 1.0, radius + 1.0 + 1e-9, 0.05)
    h = 12.0 * sigma_px / 1200
    u = (np.arange(1200) + 0.5) * h - 6.0 * sigma_px
    gx, gy = np.meshgrid(u, u)
    gauss = np.exp(-(gx**2 + gy**2) / (2 * sigma_px**2))
    gauss /= gauss.sum()
    brute = [float(np.sum(gauss * np.clip(radius - np.hypot(r + gx, gy) + 0.5, 0.0, 1.0))) for r in rho]
    assert blurred_disk(rho, radius, sigma_px) == pytest.approx(brute, abs=2e-5)
