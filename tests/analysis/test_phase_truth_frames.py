"""The independent truth's frames (issue 35): a Mitsuba halo table, a blur drawn per frame, all on record.

`bench/bench_phase_truth.py` fits such frame sets; here the generator's
physics is checked on a small one, made from a checked-in table of a
non-HG water (Fournier-Forand particles with seawater's Rayleigh share,
`tests/data/mitsuba/README.md`): the per-frame PSF and streak are recorded
in truth.json and are what blurred the frame (the disk's measured edge
width follows the PSF; along a streak it widens by the streak's L²/12),
and the halo in the frames is the table's.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from camcal.cli import app
from camcal.core.schedule import Schedule
from lrm.sim.blur import PsfJitter
from lrm.sim.halotable import HaloTable
from lrm.simset import simulate_frame_set, table_spec
from tests.analysis.transport_cases import small_camera

TABLE = Path(__file__).resolve().parents[1] / "data" / "mitsuba" / "ff-460.npz"


def _frames(folder: Path, truth: dict, camera: str) -> list[tuple[np.ndarray, dict]]:
    out = []
    for f in truth["frames"]:
        if f["camera"] == camera:
            img = cv2.imread(str(folder / f["file"]), cv2.IMREAD_UNCHANGED)
            out.append((img.astype(np.float64), f))
    return out


def _edge_sigma(img: np.ndarray, f: dict, along: tuple[float, float] | None = None) -> float:
    """The disk's edge width: an erf fitted to the radial profile at the limb (1/4-px rings).

    ``along``: only the pixels within 25° of that direction (either way) from the centre.
    """
    from scipy.optimize import curve_fit
    from scipy.special import erfc

    cx, cy = f["centroid_px"]
    r_disk = f["disk_radius_px"]
    ys, xs = np.mgrid[0 : img.shape[0], 0 : img.shape[1]]
    rho = np.hypot(xs - cx, ys - cy).ravel()
    sel = np.abs(rho - r_disk) < 8
    if along is not None:
        cos = ((xs - cx) * along[0] + (ys - cy) * along[1]).ravel() / np.maximum(rho, 1e-9)
        sel &= np.abs(cos) > math.cos(math.radians(25))
    edges = np.arange(r_disk - 8, r_disk + 8.01, 0.25)
    idx = np.digitize(rho[sel], edges) - 1
    vals = img.ravel()[sel]
    n = np.bincount(idx, minlength=len(edges))[: len(edges) - 1]
    mean = np.bincount(idx, vals, minlength=len(edges))[: len(edges) - 1] / np.maximum(n, 1)
    r = 0.5 * (edges[:-1] + edges[1:])

    def model(x: np.ndarray, a: float, b: float, r0: float, s: float) -> np.ndarray:
        return b + a * 0.5 * erfc((x - r0) / (math.sqrt(2) * s))

    p, _ = curve_fit(model, r[n > 0], mean[n > 0], p0=(mean[0] - mean[-1], mean[-1], r_disk, 1.5))
    return abs(float(p[3]))


@pytest.fixture(scope="module")
def frame_set(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict, HaloTable]:
    table = HaloTable.load(TABLE)
    folder = tmp_path_factory.mktemp("phase-truth") / "set"
    schedule = Schedule(exposures_s=(0.02,), gains_db=(16.0,), repeats=10, wavelengths_nm=(460,))
    spec = table_spec(
        [table],
        schedule,
        camera=small_camera(),
        seed=4,
        jitter_px=1.0,
        sway_m_per_s=0.0,
        psf_jitter=PsfJitter(sigma_px=(0.8, 2.0), streak_fraction=0.3, streak_px=(5.0, 8.0)),
    )
    truth = simulate_frame_set(folder, spec, workers=1)
    return folder, truth, table


def test_the_truth_records_the_phase_function_and_every_frames_blur(
    frame_set: tuple[Path, dict, HaloTable],
) -> None:
    folder, truth, table = frame_set
    on_disk = json.loads((folder / "truth.json").read_text())
    assert on_disk["phase"] == truth["phase"]  # what simulate_frame_set returned is what it wrote
    assert on_disk["phase"]["460"]["family"] == "fournier-forand"
    phase, water = on_disk["phase"]["460"], on_disk["water"]["460"]
    # ⟨cos θ⟩ of the whole is (1 − f)·g of the particles (Rayleigh's mean cosine is 0): FF of Petzold's
    # b_b/b has the nominal HG's 0.930, with 17 % seawater 0.772.
    assert phase["g_mie"] == pytest.approx(0.930, abs=0.001)
    assert phase["mean_cos_theta"] == pytest.approx((1 - phase["rayleigh_share"]) * phase["g_mie"])
    assert water["mean_cos_theta"] == pytest.approx(phase["mean_cos_theta"])
    assert 0.015 < phase["backscatter_fraction"] < 0.2 and phase["fraction_within_1deg"] > 0.15
    assert (
        water["lambda_abs_m"] == table.water.lambda_abs_m
        and water["lambda_sca_m"] == table.water.lambda_sca_m
    )
    assert on_disk["emission_ratio"] == {"460": 1.0}  # the tables' LEM is uniform
    assert on_disk["psf_jitter"]["sigma_px"] == [0.8, 2.0]
    sigmas = [f["psf_sigma_px"] for f in on_disk["frames"]]
    assert all(0.8 <= s <= 2.0 for s in sigmas) and len(set(sigmas)) == len(sigmas)
    streaks = [f for f in on_disk["frames"] if math.hypot(*f["blur_xy_px"]) > 1.0]
    assert 0 < len(streaks) < len(sigmas)
    assert all(5.0 <= math.hypot(*f["blur_xy_px"]) <= 8.0 for f in streaks)


def test_each_frame_is_blurred_by_the_psf_its_truth_records(frame_set: tuple[Path, dict, HaloTable]) -> None:
    folder, truth, _ = frame_set
    pairs = []
    for img, f in _frames(folder, truth, "A"):
        if math.hypot(*f["blur_xy_px"]) < 0.5:
            # the antialiased disk's one-pixel ramp adds 1/12 px² to the PSF's σ²
            pairs.append((math.sqrt(f["psf_sigma_px"] ** 2 + 1 / 12), _edge_sigma(img, f)))
    assert len(pairs) >= 4
    want, got = np.array(pairs).T
    assert np.corrcoef(want, got)[0, 1] > 0.9, pairs
    assert np.max(np.abs(got - want)) < 0.25, pairs


def test_a_streak_widens_the_disks_edge_along_its_direction(frame_set: tuple[Path, dict, HaloTable]) -> None:
    folder, truth, _ = frame_set
    checked = 0
    for camera in ("A", "B"):
        for img, f in _frames(folder, truth, camera):
            dx, dy = f["blur_xy_px"]
            length = math.hypot(dx, dy)
            if length < 0.5:
                continue
            along = _edge_sigma(img, f, (dx / length, dy / length))
            across = _edge_sigma(img, f, (-dy / length, dx / length))
            # a uniform streak of length L adds L²/12 to the edge's variance along it, nothing across
            assert across == pytest.approx(math.sqrt(f["psf_sigma_px"] ** 2 + 1 / 12), abs=0.3)
            assert along**2 - across**2 == pytest.approx(length**2 / 12, rel=0.3)
            checked += 1
    assert checked >= 2


def test_the_frames_halo_is_the_tables(frame_set: tuple[Path, dict, HaloTable]) -> None:
    folder, truth, table = frame_set
    for camera, dist in (("A", 21.56), ("B", 41.62)):
        frames = _frames(folder, truth, camera)
        f0 = frames[0][1]
        r_disk = f0["disk_radius_px"]
        att = truth["water"]["460"]["lambda_att_m"]
        # B·t·gain in gray: the direct light at the centre over its transmittance exp(−(L − a)/λ_att)
        scale = f0["direct_center_gray"] / math.exp(-(dist - 0.215) / att)
        edges = np.arange(1.4 * r_disk, 3.0 * r_disk, 8.0)
        ratios = []
        for img, f in frames:
            cx, cy = f["centroid_px"]
            ys, xs = np.mgrid[0 : img.shape[0], 0 : img.shape[1]]
            rho = np.hypot(xs - cx, ys - cy).ravel()
            idx = np.digitize(rho, edges) - 1
            ok = (idx >= 0) & (idx < len(edges) - 1)
            mean = np.bincount(idx[ok], img.ravel()[ok], len(edges) - 1) / np.bincount(
                idx[ok], None, len(edges) - 1
            )
            centres = 0.5 * (edges[:-1] + edges[1:])
            h = table.at(dist, np.arctan(centres / small_camera().focal_px))
            ratios.append((mean - f["background_gray"]) / (scale * h))
        ratio = np.mean(ratios, axis=0)
        # 8-bit frames, ten of them: the halo's few gray agree to a few per cent in every ring
        assert np.all(np.abs(ratio - 1.0) < 0.06), (camera, ratio)
        assert abs(float(np.mean(ratio)) - 1.0) < 0.02, (camera, ratio)


def test_simulate_set_takes_halo_tables_and_a_per_frame_psf(tmp_path: Path) -> None:
    out = tmp_path / "set"
    fov = 2.0 * math.degrees(math.atan(200.0 / small_camera().focal_px))
    result = CliRunner().invoke(
        app,
        ["simulate-set", str(out), "--halo-table", str(TABLE), "--psf-jitter", "0.8,2.0", "--streaks", "0.5",
         "--exposures", "0.02", "--gains", "8", "--repeats", "2", "--width", "400", "--height", "300",
         "--fov-deg", f"{fov:.6f}", "--workers", "1", "--quiet"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    truth = json.loads((out / "truth.json").read_text())
    assert set(truth["water"]) == {"460"} and truth["phase"]["460"]["halo_table"] == "ff-460"
    assert all(0.8 <= f["psf_sigma_px"] <= 2.0 for f in truth["frames"]) and len(truth["frames"]) == 4
    bad = CliRunner().invoke(
        app, ["simulate-set", str(tmp_path / "x"), "--halo-table", str(TABLE), "--sca", "460=9"]
    )
    assert bad.exit_code == 2 and "leave out --abs and --sca" in bad.output
