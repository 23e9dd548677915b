"""``camcal simulate-lab``: lab frame sets with their truth, and its refusals."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from camcal.cli import app

runner = CliRunner()


def test_writes_a_frame_set_with_truth(tmp_path: Path) -> None:
    out = tmp_path / "tank"
    result = runner.invoke(
        app,
        ["simulate-lab", "tank-scan", str(out), "--width", "320", "--height", "256", "--repeats", "1",
         "--distances", "1,2,3", "--abs", "460=10", "--sca", "460=30", "--quiet"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    with (out / "manifest.csv").open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 6 and {r["medium"] for r in rows} == {"air", "water"}
    assert sorted({float(r["distance_m"]) for r in rows}) == [1.0, 2.0, 3.0]
    truth = json.loads((out / "truth.json").read_text())
    assert truth["kind"] == "tank-scan"
    assert truth["truth"]["wavelengths"]["460"]["lambda_att_m"] == pytest.approx(7.5)
    assert all((out / r["file"]).is_file() for r in rows)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["sky-scan"], "KIND: unknown experiment 'sky-scan'"),
        (["air-scan", "--temperatures", "2,19"], "--temperatures does not apply to air-scan"),
        (["psf", "--wavelengths", "405,460"], "--wavelengths: psf uses one wavelength, got 2"),
        (["linearity", "--abs", "460=5"], "--abs/--sca apply to tank-scan only"),
        (["emission-ratio", "--wavelengths", "470"], "the LEM has no 470 nm LED"),
    ],
)
def test_refuses_bad_requests_in_one_line(args: list[str], message: str, tmp_path: Path) -> None:
    result = runner.invoke(app, ["simulate-lab", args[0], str(tmp_path / "out"), *args[1:], "--quiet"])
    assert result.exit_code == 2, result.output
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and message in lines[0], lines
