"""The photon transport against analytic limits, exact quadratures and itself."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from analysis.profile import radial_profile
from analysis.scattering import WaterOptics, single_scatter_halo
from analysis.transport import engine
from analysis.transport.cache import TemplateCache
from analysis.transport.coefficients import ScatteringMix, c1_coefficient, c2_coefficient, sphere_paths_mc
from analysis.transport.disk import BandPixels, blurred_disk
from analysis.transport.engine import run_transport
from analysis.transport.reference import single_scatter_radiance
from analysis.transport.sampling import random_unit_vectors, rotate, sample_hg_cos, sample_mixed_cos
from analysis.transport.scene import (
    LEM_RADIUS_M,
    CameraSite,
    ScatteringMedium,
    TransportConfig,
    TransportScene,
    band_edges_px,
)
from analysis.transport.single import CapTable, bin_first_order, first_order_lines, first_order_radiance
from analysis.transport.templates import (
    EmissionProfile,
    TemplateGrid,
    TemplateSettings,
    build_template_grid,
    cached_cap_table,
)
from lrm.sim import FrameRenderer
from lrm.sim.render import TransportHalo
from lrm.sim.scene import TREX_PLACEMENTS, Water
from tests.analysis.transport_cases import CASES, FOCAL_PX, GEOMETRY, small_camera

A = LEM_RADIUS_M


def two_cameras(edges: tuple[float, ...]) -> TransportScene:
    return TransportScene(
        (CameraSite("near", 21.56, 1, FOCAL_PX), CameraSite("far", 41.62, -1, FOCAL_PX)), edges
    )


@pytest.fixture(scope="module")
def cap_table(template_cache: TemplateCache) -> CapTable:
    """The Mie(0.93) + 17 % Rayleigh cap table (shared with the session's templates)."""
    return cached_cap_table(A, 0.93, 0.17, 400.0, template_cache)


# -- sampling -------------------------------------------------------------------


@pytest.mark.parametrize("g", [0.5, 0.93])
def test_henyey_greenstein_sampling_has_mean_cosine_g(g: float) -> None:
    mu = sample_hg_cos(np.random.default_rng(1).random(400_000), g)
    assert abs(mu.mean() - g) < 4 * mu.std() / math.sqrt(len(mu))


def test_rayleigh_sampling_moments() -> None:
    mu = sample_mixed_cos(np.random.default_rng(2), 400_000, 0.9, 1.0)
    assert abs(mu.mean()) < 4 * mu.std() / math.sqrt(len(mu))
    m2 = mu * mu
    assert abs(m2.mean() - 0.4) < 4 * m2.std() / math.sqrt(len(m2))  # (3/8)∫μ²(1+μ²)dμ = 2/5


def test_rotation_turns_by_the_requested_angle() -> None:
    rng = np.random.default_rng(3)
    d = random_unit_vectors(rng, 1000)
    d[:10] = [0.0, 0.0, 1.0]  # the pole, where the general formula divides by zero
    mu = 2 * rng.random(1000) - 1
    out = rotate(d, mu, 2 * np.pi * rng.random(1000))
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.einsum("ij,ij->i", d, out), mu, atol=1e-9)


# -- analytic limits ------------------------------------------------------------


def test_unscattered_flux_falls_as_exp_over_distance_squared() -> None:
    """No scattering: the LEM (radiance 1) gives the flux π a² e^(-L/λ)/L² at distance L, and its disk
    the radiance e^(-d/λ), d the path from its surface."""
    cams = (
        CameraSite("a", 10.0, 1, FOCAL_PX),
        CameraSite("b", 20.0, -1, FOCAL_PX),
        CameraSite("c", 40.0, 1, FOCAL_PX),
    )
    scene = TransportScene(cams, band_edges_px(200))
    cfg = TransportConfig(n_photons=1000, max_order=1, direct_samples=400_000, batch_size=100_000)
    tally = run_transport(scene, ScatteringMedium(1e12), cfg, seed=4)
    lam_abs = 30.0
    direct, err = tally.radiance(lam_abs, orders=slice(0, 1))
    halo, _ = tally.radiance(lam_abs, orders=slice(1, None))
    for c, cam in enumerate(cams):
        omega = scene.band_solid_angle_sr(c)
        flux = float((direct[c] * omega).sum())
        flux_err = float(np.sqrt(((err[c] * omega) ** 2).sum()))
        ratio = flux * cam.distance_m**2 / (math.pi * A * A) * math.exp(cam.distance_m / lam_abs)
        # The light leaves the surface, up to one radius nearer than the centre.
        assert 1.0 - 4 * flux_err / flux <= ratio <= math.exp(A / lam_abs) + 4 * flux_err / flux
        inside = slice(5, int(scene.disk_radius_px(c) * 0.8))
        expected = math.exp(-(cam.distance_m - A) / lam_abs)
        np.testing.assert_allclose(direct[c, inside].mean(), expected, rtol=0.01)
        assert halo[c].sum() < 1e-6 * direct[c].sum()


# -- single scattering ----------------------------------------------------------


def test_mc_single_scattering_matches_the_quadrature(cap_table: CapTable) -> None:
    edges = band_edges_px(160, 600.0, 8)
    scene = two_cameras(edges)
    tally = run_transport(
        scene,
        ScatteringMedium(30.0),
        TransportConfig(n_photons=150_000, max_order=1, direct_samples=0),
        seed=5,
    )
    mc, mc_err = tally.radiance(40.0, orders=slice(1, 2))
    quad = first_order_radiance(first_order_lines(scene, cap_table), 30.0, 40.0).sum(axis=1)
    groups = [
        (0, 20),
        (20, 40),
        (40, 60),
        (60, 80),
        (80, 100),
        (100, 130),
        (130, 160),
        (160, 164),
        (164, 168),
    ]
    chi2 = 0.0
    for c in range(2):
        omega = scene.band_solid_angle_sr(c)
        for g0, g1 in groups:
            w = omega[g0:g1]
            m = (mc[c, g0:g1] * w).sum() / w.sum()
            e = math.sqrt(((mc_err[c, g0:g1] * w) ** 2).sum()) / w.sum()
            q = (quad[c, g0:g1] * w).sum() / w.sum()
            assert e < 0.1 * m
            chi2 += ((m - q) / e) ** 2
    ndof = 2 * len(groups)
    assert chi2 < ndof + 5 * math.sqrt(2 * ndof)


def test_flights_guided_toward_a_camera_leave_the_higher_orders_unbiased() -> None:
    """Orders 2-3 with and without the guided flights (other seeds): the same light within errors.

    Turbid water, the near camera: where the guided flights matter most. The
    comparison is over groups of bands, each run's error from the scatter of
    its batch groups as the templates take it.
    """
    edges = band_edges_px(160)
    scene = two_cameras(edges)
    medium = ScatteringMedium(25.0)
    runs = []
    # Mostly guided flights in the second run, so that a wrong density of theirs would show.
    for natural, guided, seed in ((0.4, 0.0, 11), (0.1, 0.8, 12)):
        config = TransportConfig(
            n_photons=200_000, max_order=3, direct_samples=0, natural_fraction=natural, guided_fraction=guided
        )
        runs.append(run_transport(scene, medium, config, seed=seed).radiance(25.0, orders=slice(2, 4)))
    (plain, plain_err), (guided, guided_err) = runs
    chi2, n = 0.0, 0
    for c in range(2):
        omega = scene.band_solid_angle_sr(c)
        for g0 in range(0, 160, 40):
            w = omega[g0 : g0 + 40]
            a, b = (float((v[c, g0 : g0 + 40] * w).sum() / w.sum()) for v in (plain, guided))
            ea, eb = (
                math.sqrt(float(((e[c, g0 : g0 + 40] * w) ** 2).sum())) / w.sum()
                for e in (plain_err, guided_err)
            )
            assert a > 0 and b > 0
            chi2 += (a - b) ** 2 / (ea * ea + eb * eb)
            n += 1
    assert chi2 < n + 5 * math.sqrt(2 * n)
    with pytest.raises(ValueError, match="guided_fraction"):
        TransportConfig(natural_fraction=0.8, guided_fraction=0.3)


def test_quadrature_matches_the_exact_reference(cap_table: CapTable) -> None:
    radii = (20.5, 60.5, 100.5, 140.5)
    edges = [0.0]
    for r in radii:
        edges += [r - 1e-3, r + 1e-3]
    scene = two_cameras(tuple(edges))
    quad = first_order_radiance(first_order_lines(scene, cap_table), 50.0, 60.0).sum(axis=1)
    for c, cam in enumerate(scene.cameras):
        for k, r in enumerate(radii):
            exact = single_scatter_radiance(
                math.atan(r / FOCAL_PX), cam.distance_m, A, 50.0, 60.0, 0.93, 0.17
            )
            assert quad[c, 2 * k + 1] == pytest.approx(exact, rel=3e-3)


def test_single_scatter_halo_is_right_far_from_the_disk_only(cap_table: CapTable) -> None:
    """The simulator's default halo averages the Mie forward peak over a cone: good far from the disk,
    too low next to it, where the forward peak of light from the LEM's limb matters."""
    water = WaterOptics(60.0, 40.0, 0.93, 0.17)
    for c, cam in enumerate(two_cameras(band_edges_px(8)).cameras):
        disk = FOCAL_PX * A / cam.distance_m
        radii = np.array([1.2, 3.0, 5.0, 8.0]) * disk
        edges = [0.0]
        for r in radii:
            edges += [r - 1e-3, r + 1e-3]
        scene = TransportScene((cam,), tuple(edges))
        quad = first_order_radiance(first_order_lines(scene, cap_table), 40.0, 60.0).sum(axis=1)[0, 1::2]
        approx = single_scatter_halo(np.arctan(radii / FOCAL_PX), cam.distance_m, water, A)
        ratio = approx / quad
        assert ratio[0] < 0.85, c
        assert np.all(np.abs(ratio[1:] - 1) < 0.08), ratio
        assert np.all(np.diff(np.abs(ratio - 1)) < 0), ratio


def test_absorption_reweighting_of_binned_paths_is_exact(cap_table: CapTable) -> None:
    scene = two_cameras(band_edges_px(48))
    lines = first_order_lines(scene, cap_table)
    cfg = TransportConfig()
    moments = bin_first_order(lines, cfg.path_edges_m(), np.array([21.56 - A, 41.62 - A]))
    for lam_sca, lam_abs in ((20.0, 15.0), (60.0, 200.0)):
        direct = first_order_radiance(lines, lam_sca, lam_abs)
        binned, _ = moments.reweight(1 / lam_sca + 1 / lam_abs)
        np.testing.assert_allclose(binned / lam_sca, direct, rtol=1e-3)


# -- templates ------------------------------------------------------------------


def test_scattering_length_reweighting_agrees_with_a_direct_run(
    grids: dict[str, TemplateGrid], template_cache: TemplateCache
) -> None:
    """The turbid grid (nodes 20 and 33 m) served at 25 m agrees with a grid built at 25 m."""
    settings = grids["turbid"].settings
    direct = build_template_grid(
        TemplateSettings.near_far(
            21.56,
            41.62,
            FOCAL_PX,
            n_bands=settings.n_bands,
            outer_px=settings.outer_px,
            n_outer=settings.n_outer,
            lambda_sca_nodes_m=(25.0,),
            n_photons=settings.n_photons,
            seed=12,
        ),
        template_cache,
    )
    a, var_a = grids["turbid"].higher_orders(30.0, 25.0)
    b, var_b = direct.higher_orders(30.0, 25.0)
    fine = slice(0, settings.n_bands // settings.mc_band_px)
    for c in range(2):
        ha, hb = a[c, :, fine].sum(), b[c, :, fine].sum()
        err = math.sqrt(var_a[c, :, fine].sum() + var_b[c, :, fine].sum())
        assert abs(ha - hb) < 4 * err, (c, ha, hb, err)
    # The first order is exact at any scattering length: reweighting it is interpolation-free.
    first = grids["turbid"].halo(30.0, 25.0).radiance - np.einsum(
        "fj,ckj->ckf", grids["turbid"]._coarse_to_fine, a
    )
    np.testing.assert_allclose(
        first,
        direct.halo(30.0, 25.0).radiance - np.einsum("fj,ckj->ckf", direct._coarse_to_fine, b),
        rtol=1e-9,
    )


def test_templates_are_cached_and_deterministic(
    tmp_path: Path,
    template_cache: TemplateCache,
    grids: dict[str, TemplateGrid],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    settings = TemplateSettings.near_far(
        21.56, 41.62, FOCAL_PX, n_bands=16, lambda_sca_nodes_m=(30.0,), n_photons=4000, mc_band_px=8, seed=3
    )
    # The phase function's cap table is shared by every geometry: take the session's (``grids`` has
    # put it into the session cache).
    dirs = [tmp_path / "one", tmp_path / "two"]
    for d in dirs:
        d.mkdir()
        for table in template_cache.directory.glob("cap-table-*.npz"):
            (d / table.name).write_bytes(table.read_bytes())
    cache = TemplateCache(dirs[0])
    first = build_template_grid(settings, cache)
    files = sorted(p.name.split("-")[0] for p in dirs[0].glob("*.npz"))
    assert files == ["cap", "first", "higher"] and not list(dirs[0].glob(".*"))
    calls = []
    monkeypatch.setattr(
        "analysis.transport.templates.run_transport",
        lambda *a, **k: calls.append(1) or run_transport(*a, **k),
    )
    again = build_template_grid(settings, cache)
    assert calls == []
    np.testing.assert_array_equal(first.halo(40.0, 30.0).radiance, again.halo(40.0, 30.0).radiance)
    elsewhere = build_template_grid(settings, TemplateCache(dirs[1]))
    assert calls == [1]
    np.testing.assert_array_equal(first.halo(40.0, 30.0).radiance, elsewhere.halo(40.0, 30.0).radiance)
    # A damaged file is recomputed, not trusted.
    node = next(dirs[0].glob("higher-orders-*.npz"))
    node.write_bytes(b"not a zip")
    build_template_grid(settings, cache)
    assert calls == [1, 1]


def test_cache_directory_from_the_environment(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CAMCAL_CACHE_DIR", str(tmp_path / "here"))
    assert TemplateCache().directory == tmp_path / "here"
    monkeypatch.delenv("CAMCAL_CACHE_DIR")
    assert TemplateCache().directory.parts[-3:] == (".cache", "camcal", "templates")


def test_template_errors_name_the_parameter(grids: dict[str, TemplateGrid]) -> None:
    grid = grids["clear"]
    with pytest.raises(ValueError, match=r"lambda_sca_m 1000 m outside the template grid"):
        grid.halo(50.0, 1000.0)
    with pytest.raises(ValueError, match=r"mie_g 0\.8 outside the template nodes"):
        grid.halo(50.0, 140.0, 0.8)
    with pytest.raises(ValueError, match="lambda_abs_m must be > 0"):
        grid.halo(0.0, 140.0)
    with pytest.raises(ValueError, match="n_bands must be >= 8 and a multiple of mc_band_px"):
        TemplateSettings.near_far(21.56, 41.62, FOCAL_PX, n_bands=20)
    with pytest.raises(ValueError, match="far_near_ratio"):
        EmissionProfile(-1.0)


def test_emission_profile_is_pinned_by_the_far_near_ratio() -> None:
    p = EmissionProfile(1.27)
    np.testing.assert_allclose(p.intensity(np.array([1.0, 0.0, -1.0])), [1.0, 1.135, 1.27])
    np.testing.assert_allclose(p.weights(), [1.0, 1.27])


def test_halo_grows_with_scattering_relative_to_the_disk_and_falls_with_absorption(
    grids: dict[str, TemplateGrid],
) -> None:
    grid = grids["turbid"]
    base, _ = grid.halo(30.0, 25.0).total(EmissionProfile(1.27))
    more_scattering, _ = grid.halo(30.0, 20.0).total(EmissionProfile(1.27))
    more_absorption, _ = grid.halo(15.0, 25.0).total(EmissionProfile(1.27))
    # Relative to the direct light (exp(-L/λ_att)), more scattering means more halo.
    direct = np.exp(-np.array([21.56, 41.62]) * (1 / 30 + 1 / np.array([[25.0], [20.0]])))
    assert np.all(more_scattering[:, :144] / direct[1][:, None] > base[:, :144] / direct[0][:, None])
    assert np.all(more_absorption < base)


# -- the simulator's halo -------------------------------------------------------


def test_renderer_draws_the_transport_halo(grids: dict[str, TemplateGrid]) -> None:
    grid = grids["clear"]
    water = Water({460: CASES["clear"].optics})
    for p in TREX_PLACEMENTS:
        r = FrameRenderer(
            small_camera(), p, water, halo_model="transport", transport=TransportHalo(grid=grid)
        )
        h = r.halo_table(460) * r.emission_factor(460)
        side = -1 if p.faces_far_side else 1
        expected = grid.halo_at_psi(
            r._psi_grid, grid.camera_index(p.distance_m, side), 100.0, 140.0, 0.93, EmissionProfile(1.27)
        )
        np.testing.assert_allclose(h, expected, rtol=1e-12)
        plain = FrameRenderer(small_camera(), p, water)
        single = plain.halo_table(460) * plain.emission_factor(460)
        # Exact single scattering plus multiple scattering: more light than the approximation.
        psi_edge = math.atan(1.2 * r.disk_radius_px / FOCAL_PX)
        assert np.interp(psi_edge, r._psi_grid, h) > 1.15 * np.interp(psi_edge, plain._psi_grid, single)
    with pytest.raises(ValueError, match="halo_model must be one of single, transport"):
        FrameRenderer(small_camera(), TREX_PLACEMENTS[0], water, halo_model="double")


def test_renderer_refuses_a_grid_without_its_camera(grids: dict[str, TemplateGrid]) -> None:
    water = Water({460: CASES["clear"].optics})
    from lrm.sim.scene import Placement

    r = FrameRenderer(
        small_camera(),
        Placement("C", 30.0),
        water,
        halo_model="transport",
        transport=TransportHalo(grid=grids["clear"]),
    )
    with pytest.raises(ValueError, match=r"no template camera at 30\.0 m"):
        r.halo_table(460)


# -- the direct disk ------------------------------------------------------------


def test_disk_model_matches_a_rendered_blurred_disk() -> None:
    shape, centre, radius, sigma = (300, 300), (150.3, 149.7), 86.85, 1.2
    ys = np.arange(shape[0], dtype=np.float32)[:, None] - centre[1]
    xs = np.arange(shape[1], dtype=np.float32)[None, :] - centre[0]
    disk = np.clip(radius - np.sqrt(ys**2 + xs**2) + 0.5, 0, 1).astype(np.float32)
    image = cv2.GaussianBlur(disk, (0, 0), sigma, borderType=cv2.BORDER_CONSTANT)
    measured = radial_profile(image, centre).mean_gray
    model = BandPixels.from_crop(shape, centre, 150).disk_profile(radius, sigma)
    np.testing.assert_allclose(model, measured, atol=1e-3)
    assert blurred_disk(np.array([0.0, radius, 2 * radius]), radius, sigma) == pytest.approx(
        [1.0, 0.5, 0.0], abs=0.01
    )


def test_clipped_profile_ignores_a_hot_pixel() -> None:
    rng = np.random.default_rng(6)
    image = 3.0 + 0.3 * rng.standard_normal((200, 200))
    image[100, 160] = 255.0  # 60 px from the centre
    pixels = BandPixels.from_crop(image.shape, (100.0, 100.0), 90)
    mean, sem, count = pixels.clipped_profile(image.ravel()[pixels.flat_index])
    plain = pixels.band_mean(image.ravel()[pixels.flat_index])
    assert plain[60] > 3.5
    assert abs(mean[60] - 3.0) < 5 * sem[60]
    assert count[60] == pixels.count[60] - 1


# -- the refined model's coefficients -------------------------------------------


@pytest.mark.parametrize("radius_m", [15.0, 60.0])
def test_c1_c2_match_the_monte_carlo(radius_m: float) -> None:
    mix = ScatteringMix(50.0, 200.0, 0.9)
    mc = sphere_paths_mc(radius_m, mix, 250_000, seed=int(radius_m))
    c1, c2 = c1_coefficient(radius_m, mix), c2_coefficient(radius_m, mix)
    assert abs(mc.c1 - c1) < 3 * mc.c1_err
    assert abs(mc.c2 - c2) < 3 * mc.c2_err
    assert 1.0 < c1 < c2 < 1.4  # longer paths for more scatterings
    # The quadrature has converged well below the Monte Carlo's errors.
    assert abs(c1_coefficient(radius_m, mix, n_x=96, n_mu=128) - c1) < 1e-5
    assert abs(c2_coefficient(radius_m, mix, n_x=24, n_mu=36, n_y=24, n_phi=18) - c2) < 1e-4


def test_c_coefficients_fall_with_distance() -> None:
    mix = ScatteringMix(50.0, 200.0, 0.9)
    c1 = [c1_coefficient(r, mix) for r in (5.0, 20.0, 80.0)]
    assert c1[0] > c1[1] > c1[2] > 1.0
    with pytest.raises(ValueError, match="radius_m must be > 0"):
        c1_coefficient(0.0, mix)


def test_engine_is_deterministic_for_a_seed() -> None:
    scene = two_cameras(band_edges_px(16))
    cfg = TransportConfig(n_photons=3000, max_order=3, direct_samples=1000, batch_size=1000)
    a = run_transport(scene, ScatteringMedium(25.0), cfg, seed=9)
    b = run_transport(scene, ScatteringMedium(25.0), cfg, seed=9)
    c = run_transport(scene, ScatteringMedium(25.0), cfg, seed=10)
    np.testing.assert_array_equal(a.sum_w, b.sum_w)
    assert not np.array_equal(a.sum_w, c.sum_w)
    assert a.group_w.shape[0] == engine.N_GROUPS or a.group_w.shape[0] == 3


def test_geometry_constants_match_the_simulator() -> None:
    assert GEOMETRY.distance_near_m == TREX_PLACEMENTS[0].distance_m
    assert GEOMETRY.distance_far_m == TREX_PLACEMENTS[1].distance_m


def test_variance_factor_widens_the_bins_whose_groups_scatter_more() -> None:
    """A bin whose 16 batch groups scatter 3x more than its Σw² says gets its own, larger factor."""
    from analysis.transport.templates import variance_factor

    rng = np.random.default_rng(3)
    n_groups, n_bin = 16, 12
    sum_w2 = np.zeros((1, 1, 3, n_bin, 1))
    sum_w2[:, :, 2] = 1.0  # Σw² of the higher orders: 1 in every bin
    sigma = np.full(n_bin, 1.0 / math.sqrt(n_groups))  # group sums consistent with Σw²...
    sigma[6] *= 3.0  # ...but one heavy-tailed bin
    group_w = 5.0 + rng.standard_normal((n_groups, 1, 1, n_bin)) * sigma[None, None, None, :]
    factor = variance_factor(sum_w2, group_w)
    assert factor.shape == (1, n_bin)
    assert np.all(factor >= 1.0)
    assert factor[0, 6] > 2.0  # ≈ (9 + 1 + 1)/3 from the bin and its neighbours (16 groups: ±37 %)
    assert factor[0, 0] < 0.8 * factor[0, 6]
    # Too few groups to measure a scatter: no scaling.
    assert np.all(variance_factor(sum_w2, group_w[:3]) == 1.0)
