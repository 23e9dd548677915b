"""One transport run reweighted to other phase functions: exact at its own, unbiased at others."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from analysis.transport.cache import TemplateCache
from analysis.transport.engine import run_transport, run_transport_reweighted
from analysis.transport.scene import (
    CameraSite,
    ScatteringMedium,
    TransportConfig,
    TransportScene,
    band_edges_px,
)
from analysis.transport.template_settings import EmissionProfile
from analysis.transport.templates import build_template_grid
from tests.analysis.transport_cases import CASES, FOCAL_PX, grid_settings

SCENE = TransportScene(
    (CameraSite("near", 21.56, 1, FOCAL_PX), CameraSite("far", 41.62, -1, FOCAL_PX)), band_edges_px(160)
)
CONFIG = TransportConfig(n_photons=60_000, max_order=4, direct_samples=2000)


def banded(value: np.ndarray, err: np.ndarray, width: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """Radiance averaged over groups of ``width`` bands (solid-angle weighted), per camera."""
    out, out_err = [], []
    for c in range(value.shape[0]):
        w = SCENE.band_solid_angle_sr(c)
        for b in range(0, value.shape[1], width):
            ww = w[b : b + width]
            out.append(float((value[c, b : b + width] * ww).sum() / ww.sum()))
            out_err.append(math.sqrt(float(((err[c, b : b + width] * ww) ** 2).sum())) / ww.sum())
    return np.array(out), np.array(out_err)


def test_the_sampled_phase_function_itself_gives_the_plain_run() -> None:
    medium = ScatteringMedium(25.0, 0.93, 0.17)
    plain = run_transport(SCENE, medium, CONFIG, seed=3)
    other = ScatteringMedium(25.0, 0.88, 0.25)
    same, moved = run_transport_reweighted(SCENE, medium, CONFIG, [medium, other], seed=3)
    for k in ("sum_w", "sum_wl", "sum_wl2", "sum_w2", "group_w"):
        assert np.allclose(getattr(same, k), getattr(plain, k), rtol=1e-10, atol=0.0), k
    assert same.medium == medium and moved.medium == other
    # The direct light (order 0) does not depend on the phase function; the scattered light does.
    assert np.array_equal(moved.sum_w[:, :, 0], plain.sum_w[:, :, 0])
    assert not np.allclose(moved.sum_w[:, :, 1:], plain.sum_w[:, :, 1:])
    with pytest.raises(ValueError, match="lambda_sca_m"):
        run_transport_reweighted(SCENE, medium, CONFIG, [ScatteringMedium(30.0, 0.88)], seed=3)
    with pytest.raises(ValueError, match="at least one"):
        run_transport_reweighted(SCENE, medium, CONFIG, [], seed=3)


def test_reweighted_runs_agree_with_runs_made_at_that_phase_function() -> None:
    """Sampled at ⟨cos θ⟩ 0.93 / 17 % Rayleigh, tallied at 0.88 / 25 % and 0.96 / 10 %: direct runs agree."""
    medium = ScatteringMedium(20.0, 0.93, 0.17)
    targets = [ScatteringMedium(20.0, 0.88, 0.25), ScatteringMedium(20.0, 0.96, 0.10)]
    moved = run_transport_reweighted(SCENE, medium, CONFIG, targets, seed=21)
    chi2, n = 0.0, 0
    for target, tally in zip(targets, moved, strict=True):
        direct = run_transport(SCENE, target, CONFIG, seed=22)
        a, ea = banded(*tally.radiance(30.0))
        b, eb = banded(*direct.radiance(30.0))
        assert np.all(a > 0) and np.all(b > 0)
        chi2 += float(np.sum((a - b) ** 2 / (ea**2 + eb**2)))
        n += len(a)
    # The phase function matters here: the two targets' halos differ by far more than their errors.
    lo, hi = (banded(*t.radiance(30.0))[0] for t in moved)
    assert np.max(np.abs(lo / hi - 1)) > 0.2
    assert chi2 < n + 5 * math.sqrt(2 * n)


def test_template_nodes_that_share_their_photons_change_smoothly_with_mie_g(tmp_path: Path) -> None:
    """A grid reweighted from one run per λ_sca node (``mc_phase``): its ⟨cos θ⟩ nodes differ smoothly.

    The ratio of the halos at two ⟨cos θ⟩ nodes, band to band, scatters far
    less than with a run per node (independent Monte Carlo noise), which is
    what lets the data's Δχ² between ⟨cos θ⟩ values mean something.
    """
    base = replace(
        grid_settings(CASES["turbid"]),
        lambda_sca_nodes_m=(20.0,),
        mie_g_nodes=(0.90, 0.93),
        n_photons=60_000,
        max_order=4,
        n_bands=96,
        n_outer=0,
        outer_px=None,
    )
    cache = TemplateCache(tmp_path)
    em = EmissionProfile(1.27)
    scatter = {}
    for name, mc_phase in (("independent", None), ("shared", (0.93, 0.17))):
        grid = build_template_grid(replace(base, mc_phase=mc_phase), cache)
        lo, hi = (grid.halo(25.0, 20.0, g).total(em)[0] for g in (0.90, 0.93))
        ratio = (lo / hi)[:, 4::8]  # one band per Monte Carlo bin
        scatter[name] = float(np.std(np.diff(ratio, axis=1)))
    assert scatter["shared"] < 0.4 * scatter["independent"], scatter
    # The shared pieces name their sampling in the cache: two per scheme, none reused across them.
    assert len(list(tmp_path.glob("higher-orders-*.npz"))) == 4
