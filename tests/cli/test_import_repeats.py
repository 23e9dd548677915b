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


def _card(
    folder: Path, frames: list[tuple[str, bytes, int, str | None]], columns_reversed: bool = False
) -> None:
    """A frame set without a boot column: (file, image bytes, wavelength, timestamp or None)."""
    folder.mkdir(parents=True, exist_ok=True)
    header = ["file", "camera", "wavelength_nm", "exposure_s", "gain_db", "timestamp"]
    order = header[::-1] if columns_reversed else header
    with open(folder / "manifest.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(order)
        for name, image, wl, stamp in frames:
            (folder / name).write_bytes(image)
            row = dict(zip(header, [name, "A", wl, 0.05, 8.0, stamp or ""], strict=True))
            w.writerow([row[c] for c in order])


def _stored(data: Path) -> int:
    with sqlite3.connect(data / "camcal.db") as db:
        return int(db.execute("SELECT count(*) FROM frames").fetchone()[0])


def test_the_same_images_under_a_changed_manifest_are_not_stored_again(tmp_path: Path) -> None:
    """Without a boot column the keys come from the manifest's bytes: a copy whose manifest changed
    at all (columns reordered, a typo fixed) stored every frame a second time, and the dive's counts,
    export and report doubled without a word. Now the images are found by their content."""
    render = renderer("trex", 21.56, camera=SMALL_CAMERA, camera_id="A")
    frames = []
    for k, wl in enumerate((405, 460, 525)):
        pixels, _ = render.render(wl, 0.05, 8.0, rng=np.random.default_rng(k))
        frames.append((f"A_{wl}.png", encode_png(pixels), wl, f"2026-11-28T03:00:{10 + k:02d}Z"))
    data = tmp_path / "data"
    _card(tmp_path / "set", frames)
    assert camcal_cli("import", str(tmp_path / "set"), "--data", str(data), "--dive", "d1").returncode == 0
    _card(tmp_path / "copy", frames, columns_reversed=True)
    res = camcal_cli("import", str(tmp_path / "copy"), "--data", str(data), "--dive", "d1")
    out = re.sub(r"\s+", " ", res.stdout + res.stderr)
    assert res.returncode == 0 and "0 frames imported, 3 already present" in out, out
    assert "3 of those already present by their content" in out, out
    assert _stored(data) == 3


def test_lens_capped_frames_that_share_their_bytes_but_not_their_time_are_all_kept(tmp_path: Path) -> None:
    black = encode_png(np.zeros((64, 80), np.uint8))  # a zero black level: every dark frame the same bytes
    frames = [(f"A_dark_{k}.png", black, 460, f"2026-11-28T03:01:{10 + k:02d}Z") for k in range(3)]
    _card(tmp_path / "set", frames)
    res = camcal_cli("import", str(tmp_path / "set"), "--data", str(tmp_path / "data"), "--dive", "d1")
    assert res.returncode == 0 and "3 frames imported" in re.sub(r"\s+", " ", res.stdout), res.stdout
    assert _stored(tmp_path / "data") == 3
