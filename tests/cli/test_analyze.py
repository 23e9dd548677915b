"""``camcal analyze`` end to end on simulated frame sets, good and broken."""

from __future__ import annotations

import csv
import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from camcal.cli import app
from camcal.core.frameset import TREX_FOCAL_PX

runner = CliRunner()


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    """The real command in a subprocess: exit status and stderr as a user sees them."""
    return subprocess.run(
        [sys.executable, "-c", "from camcal.cli import main; main()", *args],
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_analyze_writes_the_spec_json_and_plots(trex_small_set: Path, tmp_path: Path) -> None:
    out = tmp_path / "result.json"
    res = runner.invoke(
        app,
        [
            "analyze",
            str(trex_small_set),
            "--json",
            str(out),
            "--plots",
            str(tmp_path / "plots"),
            "--workers",
            "2",
        ],
    )
    assert res.exit_code == 0, res.output
    doc = json.loads(out.read_text())
    truth = json.loads((trex_small_set / "truth.json").read_text())
    with (trex_small_set / "manifest.csv").open() as fh:
        files = [row["file"] for row in csv.DictReader(fh)]
    assert [f["file"] for f in doc["frames"]] == files  # one entry per row, in manifest order
    for f in doc["frames"]:
        assert f["status"] in ("ok", "rejected")
        assert (f["reason"] is None) == (f["status"] == "ok")
        if f["status"] == "ok":
            assert len(f["centroid_px"]) == 2 and f["i_center"] > 0 and f["background"] > 0
    wavelengths = {a["wavelength_nm"] for a in doc["attenuation"]}
    assert wavelengths == {405, 460, 525}
    for a in doc["attenuation"]:
        true = truth["water"][str(a["wavelength_nm"])]["lambda_att_m"]
        assert a["lambda_att_m"] == pytest.approx(true, rel=0.05)
        assert a["stat_err_m"] > 0 and a["sys_err_m"] > 0 and a["n_pairs"] >= 1
    assert "λ_att" in res.output and "accepted" in res.output
    for name in ("profile_A.png", "profile_B.png", "attenuation.png"):
        assert (tmp_path / "plots" / name).stat().st_size > 10_000


def test_options_override_setup(trex_small_set: Path, tmp_path: Path) -> None:
    base = tmp_path / "a.json"
    moved = tmp_path / "b.json"
    assert runner.invoke(app, ["analyze", str(trex_small_set), "--json", str(base), "--quiet"]).exit_code == 0
    res = runner.invoke(
        app,
        [
            "analyze",
            str(trex_small_set),
            "--json",
            str(moved),
            "--quiet",
            "--distance",
            "B=51.62",
            "--ratio",
            "460=1.0:0.01",
        ],
    )
    assert res.exit_code == 0, res.output
    a = {x["wavelength_nm"]: x for x in json.loads(base.read_text())["attenuation"]}
    b = {x["wavelength_nm"]: x for x in json.loads(moved.read_text())["attenuation"]}
    # A longer baseline gives a longer λ for the same intensities (405 keeps its ratio).
    assert b[405]["lambda_att_m"] == pytest.approx(a[405]["lambda_att_m"] * 30.06 / 20.06, rel=1e-3)
    assert json.loads(moved.read_text())["inputs"]["setup"]["emission_ratio"]["460"]["value"] == 1.0


@pytest.fixture
def broken_set(trex_small_set: Path, tmp_path: Path) -> tuple[Path, dict[str, str]]:
    """A copy of the small set with one frame of each kind of damage."""
    folder = tmp_path / "broken"
    shutil.copytree(trex_small_set, folder)
    with (folder / "manifest.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    ok_files = [r["file"] for r in rows]
    expected: dict[str, str] = {}
    (folder / ok_files[0]).unlink()
    expected[ok_files[0]] = "unreadable"
    data = (folder / ok_files[1]).read_bytes()
    (folder / ok_files[1]).write_bytes(data[: len(data) // 3])
    expected[ok_files[1]] = "unreadable"
    img = cv2.imread(str(folder / ok_files[2]), cv2.IMREAD_UNCHANGED)
    # 16-bit grayscale is a camera's format now (docs/frameset.md); colour with alpha is not
    cv2.imwrite(str(folder / ok_files[2]), cv2.cvtColor(img, cv2.COLOR_GRAY2BGRA))
    expected[ok_files[2]] = "bad_format"
    cv2.imwrite(str(folder / ok_files[3]), cv2.cvtColor(img, cv2.COLOR_GRAY2BGR))
    expected[ok_files[3]] = "bad_format"
    (folder / ok_files[4]).write_bytes(b"this is not an image")
    expected[ok_files[4]] = "unreadable"
    rows[5]["exposure_s"] = "-0.05"
    expected[rows[5]["file"]] = "bad_metadata"
    rows[6]["wavelength_nm"] = "blue"
    expected[rows[6]["file"]] = "bad_metadata"
    # a frame too small to hold the LEM crashed the whole run (analysis.detect.FrameFormatError)
    cv2.imwrite(str(folder / ok_files[7]), np.full((1, 1), 40, np.uint8))
    expected[ok_files[7]] = "bad_format"
    cv2.imwrite(str(folder / ok_files[8]), np.full((3, 320), 40, np.uint8))
    expected[ok_files[8]] = "bad_format"
    # a JPEG under a .png name was measured: its lossy blocks move I_center
    _, jpeg = cv2.imencode(".jpg", img)
    (folder / ok_files[9]).write_bytes(jpeg.tobytes())
    expected[ok_files[9]] = "unreadable"
    with (folder / "manifest.csv").open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    return folder, expected


def test_bad_frames_are_rejected_with_reasons_and_the_run_goes_on(broken_set, tmp_path: Path) -> None:
    folder, expected = broken_set
    out = tmp_path / "r.json"
    proc = run_cli("analyze", str(folder), "--json", str(out), "--quiet")
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr + proc.stdout
    # the truncated PNG is said once, in its reason: not also by libpng and OpenCV on the console
    assert "libpng" not in proc.stderr and "WARN" not in proc.stderr, proc.stderr
    doc = json.loads(out.read_text())
    by_file = {f["file"]: f for f in doc["frames"]}
    for name, reason in expected.items():
        assert by_file[name]["status"] == "rejected"
        assert by_file[name]["reason"] == reason, by_file[name]
        assert by_file[name]["detail"]
    good = [f for name, f in by_file.items() if name not in expected]
    assert sum(f["status"] == "ok" for f in good) >= len(good) // 2
    assert {a["wavelength_nm"] for a in doc["attenuation"]} == {405, 460, 525}


def test_what_is_kept_but_looks_wrong_is_said_in_warnings(trex_small_set: Path, tmp_path: Path) -> None:
    """A camera the setup does not know, a distance in centimetres, a ratio in per cent and a
    misspelt key each gave a λ_att (or left a frame out of it) without a word."""
    folder = tmp_path / "set"
    shutil.copytree(trex_small_set, folder)
    text = (folder / "manifest.csv").read_text().splitlines()
    header = text[0].split(",")
    cam = header.index("camera")
    first = text[1].split(",")
    first[cam] = "C"
    text[1] = ",".join(first)
    (folder / "manifest.csv").write_text("\n".join(text) + "\n")
    setup = json.loads((folder / "setup.json").read_text())
    setup["cameras"]["B"]["distance_m"] = 4162.0
    setup["emission_ratio"]["460"]["value"] = 127.0
    setup["emission_ratios"] = {"525": {"value": 2.5}}
    (folder / "setup.json").write_text("\ufeff" + json.dumps(setup))  # with a BOM, as editors write
    out = tmp_path / "r.json"
    proc = run_cli("analyze", str(folder), "--json", str(out), "--quiet", "--workers", "1")
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
    warnings = json.loads(out.read_text())["warnings"]
    assert any("camera 'C' (1 frames) is not in setup.json" in w for w in warnings), warnings
    assert any("camera B 4162 m from the LEM: in metres?" in w for w in warnings), warnings
    assert any("emission_ratio 460 = 127" in w and "not a percentage" in w for w in warnings), warnings
    assert any("unknown key 'emission_ratios' ignored" in w for w in warnings), warnings
    assert proc.stdout.count("warning:") == len(warnings) == 4


@pytest.mark.parametrize("where", ["folder", "proc", "empty"])
def test_an_output_that_cannot_be_written_is_refused_before_the_work(
    trex_small_set: Path, tmp_path: Path, where: str
) -> None:
    target = {"folder": str(tmp_path), "proc": "/proc/camcal-result.json", "empty": ""}[where]
    proc = run_cli("analyze", str(trex_small_set), "--json", target, "--quiet")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1 and "--json" in proc.stderr
    assert "λ_att" not in proc.stdout  # refused before analysing, not after


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        ("no_manifest", "manifest missing"),
        ("no_column", "required column gain_db missing"),
        ("no_folder", "no such frame-set folder"),
        ("bad_setup", "setup.json"),
        ("setup_list", "setup.json: must be a JSON object"),
        ("column_twice", "column exposure_s appears twice in the header"),
    ],
)
def test_fatal_problems_exit_2_with_one_line(
    trex_small_set: Path, tmp_path: Path, damage: str, message: str
) -> None:
    folder = tmp_path / "set"
    shutil.copytree(trex_small_set, folder)
    if damage == "no_manifest":
        (folder / "manifest.csv").unlink()
    elif damage == "no_column":
        text = (folder / "manifest.csv").read_text().splitlines()
        header = text[0].split(",")
        idx = header.index("gain_db")
        rows = [",".join(c for i, c in enumerate(line.split(",")) if i != idx) for line in text]
        (folder / "manifest.csv").write_text("\n".join(rows) + "\n")
    elif damage == "no_folder":
        folder = tmp_path / "missing"
    elif damage == "bad_setup":
        (folder / "setup.json").write_text('{"cameras": {"A": {"distance_m": -3}}}')
    elif damage == "setup_list":
        (folder / "setup.json").write_text("[]")
    elif damage == "column_twice":  # csv kept the last of the two, silently
        lines = (folder / "manifest.csv").read_text().splitlines()
        idx = lines[0].split(",").index("exposure_s")
        lines = [f"{line},{line.split(',')[idx]}" for line in lines]
        (folder / "manifest.csv").write_text("\n".join(lines) + "\n")
    proc = run_cli("analyze", str(folder))
    assert proc.returncode == 2
    assert message in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1
    assert "Traceback" not in proc.stderr


def test_simulate_set_is_deterministic_and_refuses_a_used_folder(tmp_path: Path) -> None:
    args = [
        "simulate-set",
        "--width",
        "320",
        "--height",
        "256",
        "--fov-deg",
        "2.1",
        "--exposures",
        "0.05",
        "--gains",
        "6",
        "--repeats",
        "1",
        "--wavelengths",
        "460",
        "--workers",
        "1",
        "--quiet",
    ]
    a, b = tmp_path / "a", tmp_path / "b"
    assert runner.invoke(app, [*args, str(a)]).exit_code == 0
    assert runner.invoke(app, [*args, str(b)]).exit_code == 0
    for name in ("A_460_00001.png", "B_460_00001.png"):
        assert (a / name).read_bytes() == (b / name).read_bytes()
    truth = json.loads((a / "truth.json").read_text())
    assert truth["water"]["460"]["lambda_att_m"] == pytest.approx(1 / (1 / 65 + 1 / 50))
    again = run_cli(*args, str(a))
    assert again.returncode == 2 and "already holds a frame set" in again.stderr
    bad = run_cli(*args[:-3], "--exposures", "-1", str(tmp_path / "c"))
    assert bad.returncode == 2 and "exposure" in bad.stderr and "Traceback" not in bad.stderr


def test_one_frame_file_is_measured_alone_as_in_its_set(trex_small_set: Path, tmp_path: Path) -> None:
    """``camcal analyze FILE``: the frame's manifest row and the set's setup, the same I_center as in the
    whole set; a file that is no frame of the manifest is one line."""
    whole = tmp_path / "whole.json"
    res = runner.invoke(app, ["analyze", str(trex_small_set), "--json", str(whole), "--quiet"])
    assert res.exit_code == 0, res.output
    frames = json.loads(whole.read_text())["frames"]
    picked = next(f for f in frames if f["status"] == "ok")
    one = tmp_path / "one.json"
    res = runner.invoke(app, ["analyze", str(trex_small_set / picked["file"]), "--json", str(one)])
    assert res.exit_code == 0, res.output
    assert "I_center" in res.output and picked["file"] in res.output
    (got,) = json.loads(one.read_text())["frames"]
    assert got == picked
    res = run_cli("analyze", str(trex_small_set / "setup.json"))
    assert res.returncode == 2 and "not a frame of the manifest" in res.stderr
    assert "Traceback" not in res.stderr


def test_faint_frames_of_a_sensor_whose_black_level_is_zero_give_the_true_attenuation(tmp_path: Path) -> None:
    """Far disks of 6-14 gray, read noise 2.5 gray, black level 0: the dark noise is clipped at zero.

    Before the clipping was undone (`analysis.censor`) the background came out ~1 gray high and
    λ_att 4-7 % low here (pulls -5 to -6).
    """
    focal_px = TREX_FOCAL_PX
    fov = 2 * math.degrees(math.atan(400 / focal_px))
    out, doc = tmp_path / "faint", tmp_path / "faint.json"
    args = ["simulate-set", "--width", "800", "--height", "700", "--fov-deg", f"{fov:.6f}"]
    args += ["--exposures", "0.004,0.006,0.009", "--gains", "8", "--repeats", "10"]
    args += ["--wavelengths", "460,525"]
    args += ["--black-level", "0", "--read-noise", "25", "--seed", "3", "--workers", "2", "--quiet", str(out)]
    assert runner.invoke(app, args).exit_code == 0
    assert runner.invoke(app, ["analyze", str(out), "--json", str(doc), "--quiet"]).exit_code == 0
    truth = json.loads((out / "truth.json").read_text())["water"]
    rows = json.loads(doc.read_text())["attenuation"]
    assert {r["wavelength_nm"] for r in rows} == {460, 525}
    for r in rows:
        true_m = truth[str(r["wavelength_nm"])]["lambda_att_m"]
        assert abs(r["lambda_att_m"] - true_m) < max(3 * r["stat_err_m"], 0.015 * true_m), (r, true_m)
    one = runner.invoke(app, ["analyze", str(out / "B_460_00001.png")])
    said = " ".join(one.output.split())
    assert one.exit_code == 0 and "the camera's dark level sits at 0: its noise (2." in said, said


def test_one_pair_has_no_chi2_to_show(tmp_path: Path) -> None:
    """One exposure and gain per wavelength: one near/far pair each, whose agreement no χ² measures.
    The table said "0.00" (a perfect fit, it read); it says "—"."""
    out = tmp_path / "one-setting"
    made = CliRunner().invoke(
        app,
        ["simulate-set", str(out), "--width", "640", "--height", "512", "--exposures", "0.05",
         "--gains", "8", "--repeats", "2", "--seed", "5"],
    )  # fmt: skip
    assert made.exit_code == 0, made.output
    res = CliRunner().invoke(app, ["analyze", str(out)])
    assert res.exit_code == 0, res.output
    rows = [line for line in res.output.splitlines() if " nm " in line and "±" in line]
    assert len(rows) == 3, res.output
    for line in rows:
        cells = [c.strip() for c in line.strip("│┃ ").split("│")]
        assert cells[-2:] == ["1", "—"], line  # pairs, χ²/ndof


def test_an_option_naming_what_the_set_lacks_is_said_to_change_nothing(trex_small_set: Path) -> None:
    proc = run_cli(
        "analyze", str(trex_small_set), "--quiet", "--workers", "1", "--distance", "C=5", "--ratio", "999=1.2"
    )
    assert proc.returncode == 0, proc.stderr
    out = " ".join(proc.stdout.split())
    assert "--distance C=...: the manifest has no camera C" in out and "no frame at 999 nm" in out, out
