"""``camcal calibrate``: each subcommand against the simulator's truth, its JSON record, its failures."""

from __future__ import annotations

import csv
import hashlib
import json
import shutil
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner, Result

from camcal.calibrate import SCHEMA
from camcal.cli import app
from tests.cli.conftest import KINDS
from tests.utils.labsets import assert_recovers_truth, make_lab_set

runner = CliRunner()

#: The figures each subcommand writes with --plots.
PLOTS = {
    "linearity": ["linearity_460nm.png"],
    "emission-ratio": ["emission_ratio.png"],
    "air-scan": ["air_scan.png", "air_scan_hough.png"],
    "tank-scan": ["tank_scan.png"],
    "psf": ["psf_460nm.png"],
}


def calibrate(*args: str | Path) -> Result:
    return runner.invoke(app, ["calibrate", *map(str, args), "--quiet", "--workers", "1"])


def fails_with(result: Result, message: str) -> None:
    """Exit status 2, one error line naming the problem, no traceback."""
    assert result.exit_code == 2, result.output
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, lines
    assert lines[0].startswith("error: ") and message in lines[0], lines[0]
    assert "Traceback" not in result.output + result.stderr


@pytest.fixture(scope="module")
def results(lab_sets: dict, tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Result, dict, Path]]:
    """Run every subcommand once on its lab set: the CLI result, the JSON document, the plot folder."""
    out = tmp_path_factory.mktemp("calibrated")
    done = {}
    for kind in KINDS:
        folder, _ = lab_sets[kind]
        result = calibrate(kind, folder, "--json", out / f"{kind}.json", "--plots", out / kind)
        doc = json.loads((out / f"{kind}.json").read_text()) if result.exit_code == 0 else {}
        done[kind] = (result, doc, out / kind)
    return done


@pytest.mark.parametrize("kind", KINDS)
def test_recovers_the_simulated_truth_within_its_errors(kind: str, results: dict, lab_sets: dict) -> None:
    result, doc, _ = results[kind]
    assert result.exit_code == 0, result.output
    assert assert_recovers_truth(doc["values"], lab_sets[kind][1]) >= 4


@pytest.mark.parametrize("kind", KINDS)
def test_result_is_a_calibration_record(kind: str, results: dict, lab_sets: dict) -> None:
    _, doc, _ = results[kind]
    folder = lab_sets[kind][0]
    assert doc["schema"] == SCHEMA
    assert doc["name"] == kind.replace("-", "_")
    assert doc["source"]["command"].startswith(f"camcal calibrate {kind} {folder}")
    frame_set = doc["source"]["frame_set"]
    assert frame_set["manifest_sha256"] == hashlib.sha256((folder / "manifest.csv").read_bytes()).hexdigest()
    assert frame_set["n_rows"] == len(doc["frames"])
    assert doc["camera"] == "A" and doc["created_utc"].endswith("Z")
    assert doc["summary"] == {"ok": len(doc["frames"])}
    for v in doc["values"]:
        assert {"quantity", "value", "err", "unit"} <= set(v) and v["value"] is not None


@pytest.mark.parametrize("kind", KINDS)
def test_writes_its_figures(kind: str, results: dict) -> None:
    result, _, plots = results[kind]
    for name in PLOTS[kind]:
        png = plots / name
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000
        assert f"wrote {png}" in result.stdout.replace("\n", "")


def test_linearity_recommends_the_linear_range_for_setup_json(results: dict, lab_sets: dict) -> None:
    _, doc, _ = results["linearity"]
    low, high = doc["setup"]["linear_range"]
    departure = lab_sets["linearity"][1]["truth"]["exposure_sweep"]["departure_gray"]
    assert low <= 5.0  # the paper's lower end, and the simulated sensor is linear below it
    assert 235.0 <= high <= departure
    r2 = [v["value"] for v in doc["values"] if v["quantity"] == "r2"]
    assert r2 and min(r2) > 0.999


def test_emission_ratio_fills_setup_json_and_sees_the_temperature_effect(results: dict) -> None:
    result, doc, _ = results["emission-ratio"]
    ratios = doc["setup"]["emission_ratio"]
    assert set(ratios) == {"405", "460", "525"}
    assert all(0 < r["err"] < 0.01 for r in ratios.values())
    changes = [v for v in doc["values"] if v["quantity"] == "ratio_change"]
    assert len(changes) == 3 and all(abs(v["value"]) < 0.02 for v in changes)
    assert "405 nm" in result.stdout and "at 2 °C" in result.stdout


def test_air_scan_and_tank_scan_report_their_laws(results: dict) -> None:
    _, air, _ = results["air-scan"]
    exponents = [v["value"] for v in air["values"] if v["quantity"] == "total_exponent"]
    assert len(exponents) == 3 and all(abs(n - 2.0) < 0.05 for n in exponents)
    _, tank, _ = results["tank-scan"]
    media = {v["medium"] for v in tank["values"] if v["quantity"] == "lambda_att_m"}
    assert media == {"water", "water relative to air"}


def test_the_record_remembers_options_that_shape_the_result(lab_sets: dict, tmp_path: Path) -> None:
    folder, _ = lab_sets["tank-scan"]
    result = calibrate("tank-scan", folder, "--distance-err", "0.02", "--json", tmp_path / "r.json")
    assert result.exit_code == 0, result.output
    doc = json.loads((tmp_path / "r.json").read_text())
    assert doc["source"]["command"] == f"camcal calibrate tank-scan {folder} --distance-err 0.02"
    assert doc["inputs"]["distance_err_m"] == 0.02


# ------------------------------------------------------------------ failures
def _copy_with_manifest(src: Path, dst: Path, keep_row: Any = None, drop_column: str | None = None) -> Path:
    """A copy of a lab set whose manifest lost some rows or a column."""
    shutil.copytree(src, dst)
    with (src / "manifest.csv").open(newline="") as fh:
        reader = csv.DictReader(fh)
        fields = [f for f in reader.fieldnames or [] if f != drop_column]
        rows = [r for r in reader if keep_row is None or keep_row(r)]
    with (dst / "manifest.csv").open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=fields, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
    return dst


def test_scan_without_distances_is_refused(lab_sets: dict, tmp_path: Path) -> None:
    folder = _copy_with_manifest(lab_sets["air-scan"][0], tmp_path / "set", drop_column="distance_m")
    fails_with(calibrate("air-scan", folder), "air-scan needs a distance_m column in manifest.csv")


def test_scan_with_a_frame_lacking_its_distance_is_refused(lab_sets: dict, tmp_path: Path) -> None:
    src = lab_sets["tank-scan"][0]
    folder = _copy_with_manifest(src, tmp_path / "set")
    text = (folder / "manifest.csv").read_text().splitlines()
    fields = text[0].split(",")
    cells = text[2].split(",")
    cells[fields.index("distance_m")] = ""
    text[2] = ",".join(cells)
    (folder / "manifest.csv").write_text("\n".join(text) + "\n")
    fails_with(calibrate("tank-scan", folder), "1 of 18 rows lack it, the first is A_00002.png")


def test_scan_with_too_few_distances_is_refused(lab_sets: dict, tmp_path: Path) -> None:
    folder = _copy_with_manifest(
        lab_sets["tank-scan"][0], tmp_path / "set", keep_row=lambda r: float(r["distance_m"]) < 1.3
    )
    fails_with(calibrate("tank-scan", folder), "needs frames at >= 3 distinct distances, got 2 (1, 1.25 m)")


def test_tank_scan_needs_the_medium(lab_sets: dict, tmp_path: Path) -> None:
    folder = _copy_with_manifest(lab_sets["tank-scan"][0], tmp_path / "set", drop_column="medium")
    fails_with(calibrate("tank-scan", folder), "tank-scan needs a medium column")


def test_emission_ratio_needs_the_hemisphere(lab_sets: dict, tmp_path: Path) -> None:
    folder = _copy_with_manifest(lab_sets["emission-ratio"][0], tmp_path / "set", drop_column="hemisphere")
    fails_with(calibrate("emission-ratio", folder), "emission-ratio needs a hemisphere column")


def test_all_frames_saturated_is_refused_with_the_remedy(tmp_path: Path) -> None:
    make_lab_set(tmp_path / "bright", "emission-ratio", repeats=1, wavelengths_nm=(460,), target_gray=900.0)
    fails_with(
        calibrate("emission-ratio", tmp_path / "bright"),
        "no usable frame: all 4 rejected: 4 saturated (LEM pixels above the linear range: "
        "use a shorter exposure or lower gain)",
    )


def test_psf_refuses_saturated_point_sources(tmp_path: Path) -> None:
    make_lab_set(tmp_path / "bright", "psf", n_positions=2, target_peak_gray=400.0)
    fails_with(calibrate("psf", tmp_path / "bright"), "psf: no usable frame: all 2 rejected: 2 saturated")


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["linearity", "/nonexistent/set"], "/nonexistent/set: no such frame-set folder"),
        (["linearity", "{set}", "--tolerance", "2"], "--tolerance must lie in (0, 1), got 2.0"),
        (["air-scan", "{set}", "--camera", "Z"], "--camera: no frames of camera 'Z' (have A)"),
        (["psf", "{set}", "--window", "8"], "--window must be an odd number of pixels >= 7, got 8"),
        (["air-scan", "{set}", "--distance-err", "-1"], "--distance-err must be >= 0, got -1.0"),
    ],
)
def test_bad_options_get_one_line(args: list[str], message: str, lab_sets: dict) -> None:
    folder = str(lab_sets[args[0]][0])
    fails_with(calibrate(*[a.replace("{set}", folder) for a in args]), message)


def test_several_cameras_need_a_choice(lab_sets: dict, tmp_path: Path) -> None:
    folder = _copy_with_manifest(lab_sets["psf"][0], tmp_path / "set")
    text = (folder / "manifest.csv").read_text().replace(",A,", ",B,", 3)
    (folder / "manifest.csv").write_text(text)
    fails_with(calibrate("psf", folder), "psf: the frame set holds cameras A, B; choose one with --camera")
    assert calibrate("psf", folder, "--camera", "A").exit_code == 0
