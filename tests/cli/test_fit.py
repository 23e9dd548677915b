"""``camcal fit`` end to end on a small simulated frame set, and its one-line refusals."""

from __future__ import annotations

import csv
import json
import math
import shutil
from pathlib import Path
from types import SimpleNamespace

import pytest
from typer.testing import CliRunner

from analysis.scattering import WaterOptics
from camcal.cli import app
from camcal.core.schedule import Schedule
from camcal.fitdoc import estimate_text
from camcal.report.fitsection import fit_section
from lrm.sim.camera import CameraModel
from lrm.sim.render import TransportHalo
from lrm.sim.scene import TREX_PLACEMENTS, Placement, Water
from lrm.simset import SimulationSpec, simulate_frame_set

FOCAL_PX = 1224.0 / math.tan(math.radians(8.0))
TRUTH = WaterOptics(100.0, 140.0)


def small_camera() -> CameraModel:
    return CameraModel(width_px=800, height_px=700, fov_deg=2.0 * math.degrees(math.atan(400.0 / FOCAL_PX)))


def simulate(
    out: Path,
    exposures: tuple[float, ...],
    gains: tuple[float, ...],
    repeats: int,
    halo: str,
    cache: Path,
    placements: tuple[Placement, ...] = TREX_PLACEMENTS,
) -> Path:
    spec = SimulationSpec(
        water=Water({460: TRUTH}, name="clear"),
        placements=placements,
        camera=small_camera(),
        schedule=Schedule(
            name="test", exposures_s=exposures, gains_db=gains, repeats=repeats, wavelengths_nm=(460,)
        ),
        seed=4,
        jitter_px=1.5,
        halo_model=halo,
        transport=TransportHalo(cache_dir=str(cache), n_photons=200_000),
    )
    simulate_frame_set(out, spec, workers=1)
    return out


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("cli-templates")


@pytest.fixture(scope="module")
def frameset(tmp_path_factory: pytest.TempPathFactory, cache_dir: Path) -> Path:
    """Clear water, 460 nm, two exposures x two gains x 4 repeats, halo from the transport."""
    return simulate(
        tmp_path_factory.mktemp("set") / "fs", (0.01, 0.02), (14.0, 18.0), 4, "transport", cache_dir
    )


@pytest.fixture(scope="module")
def budget_cache(frameset: Path, cache_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The fit's templates and, once the first budget test made them, the budget's variants (kept
    out of the shared cache; both budget tests fit T-REX's distances)."""
    return Path(shutil.copytree(cache_dir, tmp_path_factory.mktemp("budget") / "cache"))


def run(*args: str) -> tuple[int, str]:
    result = CliRunner().invoke(app, list(args))
    return result.exit_code, result.output


def fit_args(folder: Path, cache_dir: Path, *extra: str) -> list[str]:
    return [
        "fit",
        str(folder),
        "--photons",
        "150000",
        "--sca-nodes",
        "110,180",
        "--cache-dir",
        str(cache_dir),
        "--workers",
        "2",
        "--quiet",
        "--templates",
        "monte-carlo",
        *extra,
    ]


def test_the_default_fit_measures_the_phase_function_or_says_why_it_cannot(
    frameset: Path, tmp_path: Path
) -> None:
    """Smooth templates, Mie ⟨cos θ⟩ and the Rayleigh share floated: the JSON carries them (a value, a
    limit or a degenerate case, never a bare number) with the Δχ² map, and the lengths' intervals
    hold the truth whatever the data could say about the phase function."""
    code, output = run(
        "fit", str(frameset), "--cache-dir", str(tmp_path / "smooth"), "--workers", "2", "--quiet",
        NO_BUDGET, "--json", str(tmp_path / "fit.json"),
    )  # fmt: skip
    assert code == 0, output
    (res,) = json.loads((tmp_path / "fit.json").read_text())["fits"]
    assert res["g_mie_fixed"] is False and res["rayleigh_share_fixed"] is False
    assert res["phase_case"] in ("measured", "limit", "degenerate"), res["phase_case"]
    assert res["phase_case_text"] and "phase function" in output
    phase = res["phase"]
    if res["phase_case"] == "measured":
        assert res["g_mie"] is not None and res["g_mie_err"] > 0
    else:  # a limit or nothing: no value to quote
        assert res["g_mie"] is None and phase["g_mie"]["status"] != "measured"
    grid = res["phase_map"]
    assert len(grid["dchi2"]) == len(grid["rayleigh_share"]) and len(grid["dchi2"][0]) == len(grid["g_mie"])
    assert min(min(row) for row in grid["dchi2"]) == pytest.approx(0.0, abs=0.5)
    # The lengths: the truth (the default phase function of the simulator) inside the quoted intervals.
    for key, truth in (("lambda_abs", TRUTH.lambda_abs_m), ("lambda_sca", TRUTH.lambda_sca_m)):
        entry = res[key]
        if entry["status"] == "measured":
            lo, hi = entry["interval_m"]
            assert lo - 2 * (hi - lo) < truth < hi + 2 * (hi - lo), (key, entry)
        else:
            assert entry["status"] == "lower_limit" and entry["limit_m"] < truth, (key, entry)
    assert res["fit_quality_ok"] is True, res["fit_quality_reason"]


#: The systematic budget refits every wavelength a dozen times: tested on its own (slow).
NO_BUDGET = "--no-systematics"


@pytest.fixture(scope="module")
def fitted(
    frameset: Path, cache_dir: Path, tmp_path_factory: pytest.TempPathFactory
) -> tuple[int, str, Path]:
    out = tmp_path_factory.mktemp("fit-out")
    code, output = run(
        *fit_args(
            frameset, cache_dir, NO_BUDGET, "--json", str(out / "fit.json"), "--plots", str(out / "plots")
        )
    )
    return code, output, out


def test_fit_reports_lengths_within_their_errors(fitted: tuple[int, str, Path]) -> None:
    code, output, out = fitted
    assert code == 0, output
    doc = json.loads((out / "fit.json").read_text())
    (res,) = doc["fits"]
    assert res["wavelength_nm"] == 460
    assert abs(res["lambda_abs_m"] - TRUTH.lambda_abs_m) < 3 * res["lambda_abs_err_m"]
    # The simulator drew its halo from its own Monte Carlo (200k photons), independent of the
    # templates': its noise in the multiply scattered light is part of this "truth" but of no
    # reported error, so λ_sca (measured to ~0.4 %) is held to 3 %. The fit's own pulls are
    # tested with a shared sample in tests/analysis/test_chisq.py.
    assert abs(res["lambda_sca_m"] - TRUTH.lambda_sca_m) < 0.03 * TRUTH.lambda_sca_m
    # 1/λ_abs + 1/λ_sca against the I_center λ_att of the same frames.
    assert res["att_check_agrees"] is True
    assert abs(res["lambda_att_icenter_m"] - TRUTH.lambda_att_m) < 3 * res["lambda_att_icenter_err_m"]
    lo, hi = res["lambda_sca_interval_m"]
    assert lo < res["lambda_sca_m"] < hi
    # The disk's edge is a free mixture of blurs per setting and camera (no single PSF nuisance).
    assert {n["name"] for n in res["nuisances"]} == {
        "distance_near",
        "distance_far",
        "emission_ratio",
        "focal_scale",
        "halo_scale",
    }
    # χ² per radial band and the verdict; the phase function held fixed says so.
    assert res["fit_quality_ok"] is True and res["fit_failed"] is False and res["chi2_ndof"] < 1.5
    assert {b["camera"] for b in res["chi2_bands"]} == {"near", "far"}
    assert sum(b["n_bins"] for b in res["chi2_bands"]) == res["ndof"] + 2 + 3 * len(res["settings"])
    assert res["g_mie_fixed"] is True and res["g_mie_err"] is None and res["phase_case"] == "fixed"
    assert res["mean_cos_theta"] == pytest.approx((1 - res["rayleigh_share"]) * res["g_mie"])
    # The document says where the numbers came from.
    assert doc["inputs"]["templates"]["lambda_sca_nodes_m"] == [110.0, 180.0]
    assert doc["inputs"]["geometry"]["distance_far_m"] == 41.62
    assert doc["software"]["name"] == "camcal"
    assert "460" in output and "agrees" in output
    assert res["nuisance_check_flagged"] is False and res["nuisance_check_advice"] is None
    assert "flagged" not in output.lower()
    # Made with --no-systematics: no "± 0.00 (sys)" anywhere, the entry and the table say so.
    for key in ("lambda_abs", "lambda_sca"):
        assert res[key]["systematics"] == "no budget" and res[key]["sys_err_m"] is None
        assert estimate_text(res, key).endswith(" (no budget) m")
    assert "budget)" in output  # "(no budget)", perhaps wrapped by the 80-column table
    assert "± 0.00" not in output


def test_fit_writes_readable_plots(fitted: tuple[int, str, Path]) -> None:
    _, _, out = fitted
    for name in ("contour_460.png", "fit_460.png"):
        path = out / "plots" / name
        assert path.stat().st_size > 20_000
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_templates_went_to_the_cache_directory(fitted: tuple[int, str, Path], cache_dir: Path) -> None:
    kinds = sorted(p.name.rsplit("-", 1)[0] for p in cache_dir.glob("*.npz"))
    # The simulator's own halo pieces (one camera each) and the fit's: one cap table shared by all.
    assert kinds.count("cap-table") == 1
    assert kinds.count("higher-orders") == 2 + 2  # two simulator cameras, two fit nodes
    assert not list(cache_dir.glob(".*"))  # no half-written files


@pytest.mark.slow
def test_fit_with_its_systematic_budget(
    fitted: tuple[int, str, Path], frameset: Path, budget_cache: Path, tmp_path: Path
) -> None:
    """The default fit: what it holds fixed varied, the shifts in the JSON, the table and the report."""
    cache = budget_cache
    code, output = run(
        *fit_args(frameset, cache, "--json", str(tmp_path / "fit.json"), "--sys-photon-factor", "0.5")
    )
    assert code == 0, output
    (f,) = json.loads((tmp_path / "fit.json").read_text())["fits"]
    (plain,) = json.loads((fitted[2] / "fit.json").read_text())["fits"]
    b = f["systematics"]
    names = [i["name"] for i in b["items"]]
    assert names[:4] == ["phase_function", "emission_shape", "template_sample", "template_accuracy"]
    # The templates' own Monte Carlo: refits on three other seeds; one sample's error √(mean shift²/2),
    # and the values quoted are the mean over the four samples (the nominal's shift 0), so the line's
    # error is that mean's: one sample's / √4.
    sample = b["items"][2]
    assert len(sample["cases"]) == 3 and sample["lambda_sca_err_m"] > 0
    for key, k in (("lambda_abs", 0), ("lambda_sca", 1)):
        shifts = sample[f"{key}_shift_m"]
        one = (sum(x * x for x in shifts) / 6) ** 0.5
        assert sample[f"{key}_err_m"] == pytest.approx(one / 2, rel=1e-2, abs=2e-3)
        assert b["sample_move_m"][k] == pytest.approx(sum(shifts) / 4, abs=2e-3)
        # the quoted value moved by it; the χ² minimum stays the nominal templates'
        assert f[key]["value_m"] == pytest.approx(plain[f"{key}_m"] + b["sample_move_m"][k], abs=2e-3)
        assert f["best_fit_m"][k] == plain["best_fit_m"][k]
    assert sample["note"].startswith("values quoted: the mean over the nominal templates and these 3 samples")
    assert {"emission_ratio", "distance_near", "distance_far"} <= set(names)
    assert "psf_sigma" not in names  # each setting and camera fits its own edge: no one PSF width to vary
    held = [i for i in b["items"] if not i["profiled"]]
    for key in ("lambda_abs", "lambda_sca"):
        total = math.sqrt(sum(i[f"{key}_err_m"] ** 2 for i in held))
        assert b[f"{key}_sys_m"] == pytest.approx(total, rel=1e-3, abs=2e-3)
        assert f[key]["sys_err_m"] == b[f"{key}_sys_m"]
    # Refits on a grid of ⟨cos θ⟩ × Rayleigh share. A larger ⟨cos θ⟩ puts the same halo at a longer
    # scattering length (λ_sca(1 - g) holds the halo's width): the two ends shift λ_sca apart.
    p = next(i for i in b["items"] if i["name"] == "phase_function")
    assert len(p["cases"]) == 18 and p["cases"][0] == "0.88/0.1" and "(18 refits)" in p["cases_text"]
    ref = p["cases"].index("0.93/0.17")
    assert p["lambda_sca_shift_m"][ref] == 0.0 and p["delta_chi2"][ref] == 0.0
    at = {c: s for c, s in zip(p["cases"], p["lambda_sca_shift_m"], strict=True)}
    assert at["0.88/0.17"] < 0 < at["0.96/0.17"]
    # The line's error: the RMS shift over the uniform prior on the box, so between the smallest
    # and the largest |shift|; the note also says what the data alone make of the two parameters.
    shifts = [abs(x) for x in p["lambda_sca_shift_m"]]
    assert sorted(shifts)[1] < p["lambda_sca_err_m"] < max(shifts)
    assert p["note"].startswith("error: RMS shift over a uniform prior")
    # Upward and downward apart (each the RMS over its own side, so neither above the largest
    # shift and the RMS between them), each summed on its own.
    up, down = p["errors_up_m"][1], p["errors_down_m"][1]
    assert min(up, down) <= p["lambda_sca_err_m"] * 1.001 and max(up, down) >= p["lambda_sca_err_m"] * 0.999
    assert max(up, down) <= max(shifts) * 1.001
    assert f["lambda_sca"]["sys_err_up_m"] == b["sys_up_m"][1]
    assert f["lambda_sca"]["sys_err_down_m"] == b["sys_down_m"][1]
    assert "(sys)" in estimate_text(f, "lambda_sca")
    assert "the data alone: ⟨cos θ⟩ 0." in p["note"]
    # Sums finite, budget shown in the table, and the fit's λ_att error grew by its systematic part.
    assert "systematic budget" in output and "quadrature" in output  # the 80-column table wraps cells
    assert f["lambda_att_fit_err_m"] >= plain["lambda_att_fit_err_m"]
    from camcal.report.fitsection import _budgets

    page = _budgets([f])
    assert "460 nm: systematic budget" in page and "Mie ⟨cos θ⟩" in page


def subset(src: Path, dst: Path, keep: object) -> Path:
    """A copy of a frame set with only the manifest rows ``keep(row)`` accepts."""
    dst.mkdir()
    shutil.copy(src / "setup.json", dst / "setup.json")
    with open(src / "manifest.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    kept = [r for r in rows if keep(r)]  # type: ignore[operator]
    with open(dst / "manifest.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(kept)
    for r in kept:
        shutil.copy(src / r["file"], dst / r["file"])
    return dst


def assert_one_line_error(code: int, output: str, *phrases: str) -> None:
    assert code == 2, output
    lines = [line for line in output.strip().splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:"), output
    assert "Traceback" not in output
    for p in phrases:
        assert p in output, output


def test_a_distance_the_frames_contradict_is_flagged_in_the_json_the_cli_and_the_report(
    frameset: Path, cache_dir: Path, tmp_path: Path
) -> None:
    """setup.json puts the near camera 0.34 m (1.6 %) further than the frames were taken from: the
    disk's size still passes the focal-length check, I_center's λ_att moves with it and the fit's
    1/λ_abs + 1/λ_sca "agrees" with it, but λ_abs came out 164 m for 100 (a value, not a limit).
    The fit pulls both distances ~9σ off their ±0.02/0.04 m to make the profiles fit: that is
    flagged (beyond 3σ) with what to do, wherever the fit is shown."""
    folder = Path(shutil.copytree(frameset, tmp_path / "wrong-distance"))
    setup = json.loads((folder / "setup.json").read_text())
    setup["cameras"]["A"]["distance_m"] = 21.9
    (folder / "setup.json").write_text(json.dumps(setup))
    code, output = run(*fit_args(folder, cache_dir, NO_BUDGET, "--json", str(tmp_path / "fit.json")))
    assert code == 0, output
    doc = json.loads((tmp_path / "fit.json").read_text())
    (res,) = doc["fits"]
    pulls = {n["name"]: n["pull"] for n in res["nuisances"]}
    assert pulls["distance_near"] < -3, pulls
    assert res["nuisance_check_flagged"] is True
    advice = res["nuisance_check_advice"]
    assert "the near camera's distance by -0.1" in advice and "σ of its ±0.02 m" in advice, advice
    assert "do not quote λ_abs and λ_sca" in advice and "setup.json" in advice
    said = " ".join(output.split())
    assert "460 nm flagged: the fit moved the near camera's distance" in said, said
    report = fit_section(
        SimpleNamespace(
            dive={"name": "wrong-distance"},
            data_dir="DATA",
            fit={"result": doc, "id": 1, "created_unix_s": 0, "software_version": "test", "run_id": 1,
                 "span": {"n_frames": 32, "depth_min_m": 3000.0}},
            run={"id": 1},
        )  # type: ignore[arg-type]
    )  # fmt: skip
    assert "a calibration pulled &gt; 3σ" in report
    assert "460 nm flagged.</b> The fit moved the near camera&#x27;s distance" in report, report[:3000]


def test_a_wrong_distance_stays_flagged_when_the_phase_function_is_varied(
    cache_dir: Path, budget_cache: Path, tmp_path: Path
) -> None:
    """The budget refits at other phase functions may relieve a calibration the nominal fit strained
    (then the phase function moved it: not flagged). A distance 0.34 m off is not the phase
    function's doing: no data-allowed refit keeps every calibration within 3σ, so it stays flagged.
    (The frames taken 0.34 m nearer than setup.json says, so that the fit's templates, T-REX's
    distances, are the budget test's.)"""
    near = (Placement("A", 21.22, 0.02), *TREX_PLACEMENTS[1:])
    folder = simulate(tmp_path / "off", (0.01, 0.02), (14.0, 18.0), 4, "transport", cache_dir, near)
    setup = json.loads((folder / "setup.json").read_text())
    setup["cameras"]["A"]["distance_m"] = 21.56
    (folder / "setup.json").write_text(json.dumps(setup))
    args = fit_args(folder, budget_cache, "--json", str(tmp_path / "fit.json"), "--sys-photon-factor", "0.5")
    code, output = run(*args)
    assert code == 0, output
    (res,) = json.loads((tmp_path / "fit.json").read_text())["fits"]
    assert {n["name"]: n["pull"] for n in res["nuisances"]}["distance_near"] < -3
    assert res["nuisance_check_relief"] is None
    assert res["nuisance_check_flagged"] is True, res["nuisance_check_advice"]


def test_one_camera_missing(frameset: Path, cache_dir: Path, tmp_path: Path) -> None:
    only_a = subset(frameset, tmp_path / "a", lambda r: r["camera"] == "A")
    code, output = run(*fit_args(only_a, cache_dir))
    assert_one_line_error(code, output, "needs frames from two cameras", "has: A")


def test_too_few_frames(frameset: Path, cache_dir: Path, tmp_path: Path) -> None:
    seen: set[str] = set()

    def first_of_each(r: dict[str, str]) -> bool:
        if r["camera"] in seen:
            return False
        seen.add(r["camera"])
        return True

    few = subset(frameset, tmp_path / "few", first_of_each)
    code, output = run(*fit_args(few, cache_dir))
    assert_one_line_error(code, output, "only 1 accepted frame(s)", "at least 3")


def test_only_saturated_frames(tmp_path: Path, cache_dir: Path) -> None:
    bright = simulate(tmp_path / "bright", (1.0,), (20.0,), 2, "single", cache_dir)
    code, output = run(*fit_args(bright, cache_dir, "--min-frames", "1"))
    assert_one_line_error(code, output, "no accepted (unsaturated) frame")


def test_wrong_focal_length(frameset: Path, cache_dir: Path) -> None:
    code, output = run(*fit_args(frameset, cache_dir, "--focal-px", "6000"))
    assert_one_line_error(code, output, "the LEM's disk measures", "--focal-px")


def test_missing_folder(tmp_path: Path, cache_dir: Path) -> None:
    code, output = run(*fit_args(tmp_path / "nowhere", cache_dir))
    assert_one_line_error(code, output, "nowhere", "no such frame-set folder")


def test_bad_option_values(frameset: Path, cache_dir: Path) -> None:
    code, output = run(*fit_args(frameset, cache_dir, "--sca-nodes", "abc"))
    assert_one_line_error(code, output, "--sca-nodes")
    code, output = run(*fit_args(frameset, cache_dir, "--mie-g", "1.5"))
    assert_one_line_error(code, output, "mie_g")


def test_c_coefficients_command(tmp_path: Path) -> None:
    out = tmp_path / "c.png"
    code, output = run(
        "transport",
        "c-coefficients",
        "--out",
        str(out),
        "--radii",
        "10,60,4",
        "--mc-radii",
        "30",
        "--photons",
        "50000",
    )
    assert code == 0, output
    assert out.read_bytes()[:4] == b"\x89PNG"
    row = next(line for line in output.splitlines() if line.replace(" ", "").startswith("│30│"))
    pulls = [float(x) for x in row.replace("│", " ").split() if x.startswith(("+", "-")) and "." in x]
    assert len(pulls) == 2 and all(abs(p) < 3 for p in pulls)


def test_c_coefficients_refuses_bad_lengths(tmp_path: Path) -> None:
    code, output = run("transport", "c-coefficients", "--out", str(tmp_path / "c.png"), "--lambda-mie", "-5")
    assert_one_line_error(code, output, "lambda_mie_m")
