"""`camcal doctor` shows its details as they are, whatever characters they hold."""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

from typer.testing import CliRunner

from camcal.cli import app


def test_a_data_folder_whose_name_looks_like_markup_is_shown_whole() -> None:
    """A path (or a refused key's fingerprint, Z85 holds "[" and "]") with "[b]" in it lost those
    characters: rich read the detail as markup. (A short folder in /tmp: the table cuts long paths.)"""
    data = Path(tempfile.mkdtemp(prefix="d[b]", dir="/tmp"))
    try:
        res = CliRunner().invoke(app, ["doctor", "--check", "data"], env={"CAMCAL_DATA_DIR": str(data)})
        assert f"{data} is writable" in res.output, res.output
    finally:
        shutil.rmtree(data)
