"""A card whose manifest gives one sequence number to two frames: the first row keeps it.

Cards written before `camcal.core.files.AppendLog` could hold such rows (a full card took part
of a failed frame's row and the rest landed with the next frame's, which had the same number).
Both rows were stored under one key: the second image over the first one's file, whose row (and
checksum) were the first's. Now the repeat is named and not imported. A real `camcal import`.
"""

from __future__ import annotations

import csv
import hashlib
import re
import sqlite3
from pathlib import Path

import numpy as np

from camcal.core.images import encode_png
from tests.utils.live import camcal_cli
from tests.utils.sim import SMALL_CAMERA, renderer


def test_a_repeated_sequence_number_is_named_and_the_first_row_keeps_it(tmp_path: Path) -> None:
    folder, data = tmp_path / "card", tmp_path / "data"
    folder.mkdir()
    render = renderer("trex", 21.56, camera=SMALL_CAMERA, camera_id="A")
    images: dict[str, bytes] = {}
    rows = [(1, 405), (2, 460), (2, 525), (3, 405)]  # row 3 repeats row 2's number
    with open(folder / "manifest.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["file", "camera", "wavelength_nm", "exposure_s", "gain_db", "timestamp", "seq", "boot"])
        for k, (seq, wl) in enumerate(rows):
            name = f"A_{wl}_{seq}.png"
            pixels, _ = render.render(wl, 0.05, 8.0, rng=np.random.default_rng(k))
            images[name] = encode_png(pixels)
            (folder / name).write_bytes(images[name])
            w.writerow([name, "A", wl, 0.05, 8.0, f"2026-11-28T03:00:{10 + k:02d}Z", seq, "b1"])

    res = camcal_cli("import", str(folder), "--data", str(data))
    out = re.sub(r"[\s│]+", " ", res.stdout + res.stderr)  # a table's cells, cut over lines, read as one
    assert res.returncode == 0, out
    assert "3 frames imported" in out, out
    assert "repeats the sequence number 2 of camera A (boot b1) of row 2: not imported" in out, out
    with sqlite3.connect(data / "camcal.db") as db:
        stored = db.execute("SELECT seq, wavelength_nm, path, sha256 FROM frames ORDER BY seq").fetchall()
    assert [(seq, wl) for seq, wl, _, _ in stored] == [(1, 405), (2, 460), (3, 405)]
    for _, _, path, sha in stored:  # every stored file is its row's image
        assert hashlib.sha256((data / path).read_bytes()).hexdigest() == sha
    assert stored[1][3] == hashlib.sha256(images["A_460_2.png"]).hexdigest()
