"""The frame set's per-frame columns for lab scans: distance, its error, temperature, medium, hemisphere."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from camcal.core.frameset import FrameSetError, ManifestRow, read_manifest
from camcal.core.framewriter import FrameSetWriter

HEADER = (
    "file,camera,wavelength_nm,exposure_s,gain_db,distance_m,distance_err_m,temperature_c,medium,hemisphere\n"
)


def _manifest(folder: Path, body: str, header: str = HEADER) -> list[ManifestRow]:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "manifest.csv").write_text(header + body, encoding="utf-8")
    return read_manifest(folder)


def test_lab_columns_are_read(tmp_path: Path) -> None:
    rows = _manifest(tmp_path, "a.png,A,460,0.05,0,5.2,0.1,2.1,air,far\nb.png,A,460,0.05,0,,,,,\n")
    a, b = rows
    assert (a.distance_m, a.distance_err_m, a.temperature_c, a.medium, a.hemisphere) == (
        5.2,
        0.1,
        2.1,
        "air",
        "far",
    )
    assert a.error is None
    assert (b.distance_m, b.temperature_c, b.medium, b.hemisphere) == (None, None, None, None)


@pytest.mark.parametrize(
    ("values", "problem"),
    [
        ("-1,0.1,2,air,near", "distance_m -1 must be > 0"),
        ("5,-0.1,2,air,near", "distance_err_m -0.1 must be >= 0"),
        ("5,0.1,-300,air,near", "temperature_c -300 is below absolute zero"),
        ("5,0.1,2,oil,near", "medium 'oil' must be air or water"),
        ("5,0.1,2,air,left", "hemisphere 'left' must be near or far"),
    ],
)
def test_unusable_lab_values_reject_the_row_naming_the_column(
    tmp_path: Path, values: str, problem: str
) -> None:
    (row,) = _manifest(tmp_path, f"a.png,A,460,0.05,0,{values}\n")
    assert row.error is not None and problem in row.error


def test_writer_continues_an_older_manifest_in_its_own_columns(tmp_path: Path) -> None:
    old = "file,camera,wavelength_nm,exposure_s,gain_db,distance_m\n"
    _manifest(tmp_path, "a.png,A,460,0.05,0,5.0\n", header=old)
    frame = np.zeros((16, 16), dtype=np.uint8)
    with FrameSetWriter(tmp_path) as writer:
        writer.add(frame, ManifestRow(1, "b.png", "A", 460, 0.05, 0.0, distance_m=10.0))
        with pytest.raises(FrameSetError, match="has no column hemisphere"):
            writer.add(frame, ManifestRow(2, "c.png", "A", 460, 0.05, 0.0, hemisphere="far"))
    with (tmp_path / "manifest.csv").open(newline="") as fh:
        records = list(csv.DictReader(fh))
    assert [r["file"] for r in records] == ["a.png", "b.png"]
    assert records[1]["distance_m"] == "10.0"
    assert read_manifest(tmp_path)[1].distance_m == 10.0
