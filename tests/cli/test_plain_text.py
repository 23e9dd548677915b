"""The command line shows text as it is: paths, keys, units and messages are never read as rich markup.

rich takes "[b]", "[m]" or "[px]" for a style tag and drops it: a folder "d[b]" printed as "d",
a listed Z85 key lost two characters, "λ_att fit [m]" lost its unit, "--psf-sigma" read
"Gaussian PSF width (prior centre)".
"""

from __future__ import annotations

import re
import shutil
import tempfile
from pathlib import Path

import pytest
from typer.testing import CliRunner

from camcal.cli import app

WIDE = {"COLUMNS": "250", "NO_COLOR": "1"}


def test_a_data_folder_whose_name_looks_like_markup_is_shown_whole() -> None:
    """A path (or a refused key's fingerprint, Z85 holds "[" and "]") with "[b]" in it lost those
    characters: rich read the detail as markup. (A short folder in /tmp: the table cuts long paths.)"""
    data = Path(tempfile.mkdtemp(prefix="d[b]", dir="/tmp"))
    try:
        res = CliRunner().invoke(app, ["doctor", "--check", "data"], env={"CAMCAL_DATA_DIR": str(data)})
        assert f"{data} is writable" in res.output, res.output
    finally:
        shutil.rmtree(data)


def test_an_error_names_the_path_it_was_given(tmp_path: Path) -> None:
    missing = tmp_path / "run[b]7"
    res = CliRunner().invoke(app, ["analyze", str(missing)], env=WIDE)
    assert res.exit_code == 2
    assert f"{missing}: no such frame-set folder" in re.sub(r"\s*\n\s*", "", res.output), res.output


def test_an_unknown_doctor_check_is_an_error_that_lists_the_checks() -> None:
    res = CliRunner().invoke(app, ["doctor", "--check", "dat[b]a"], env=WIDE)
    assert res.exit_code == 2
    assert "unknown check(s): dat[b]a (the checks: data, database" in res.output, res.output


@pytest.mark.parametrize(
    ("command", "option", "text"),
    [
        (["fit"], "--psf-sigma", "Gaussian PSF width [px] (prior centre)."),
        (["fit"], "--depth-min", "Frames at or below this depth [m]"),
        (["calibrate", "psf"], "--window", "Side of the fit window around the source [px], odd."),
    ],
)
def test_help_shows_each_options_unit(command: list[str], option: str, text: str) -> None:
    res = CliRunner().invoke(app, [*command, "--help"], env=WIDE)
    assert res.exit_code == 0
    line = next(line for line in res.output.splitlines() if f"{option} " in line)
    assert text in line, line
