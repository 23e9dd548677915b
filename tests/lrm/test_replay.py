"""Replaying a frame set: the recorded bytes go out unchanged, bad files are skipped and named."""

from __future__ import annotations

import threading
from pathlib import Path

import cv2
import numpy as np

from camcal.core.images import decode_frame, encode_png
from lrm.replay import ReplaySource
from tests.utils.live import RealClock


def write_set(folder: Path, files: dict[str, bytes]) -> None:
    folder.mkdir()
    lines = ["file,camera,wavelength_nm,exposure_s,gain_db,timestamp"]
    for i, (name, data) in enumerate(files.items()):
        if data:
            (folder / name).write_bytes(data)
        lines.append(f"{name},A,460,0.05,8,2021-09-10T04:00:{i:02d}Z")
    lines.append("B_1.png,B,460,0.05,8,2021-09-10T04:00:00Z")
    (folder / "manifest.csv").write_text("\n".join(lines) + "\n")


def test_good_frames_go_out_as_recorded_and_each_bad_one_is_skipped_with_its_reason(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    gray = rng.integers(0, 250, (48, 64), dtype=np.uint8)
    png = encode_png(gray)
    tiff = cv2.imencode(".tiff", gray)[1].tobytes()
    files = {
        "good.png": png,
        "missing.png": b"",
        "cut.png": png[: len(png) // 2],
        "deep.png": cv2.imencode(".png", gray.astype(np.uint16) * 200)[1].tobytes(),
        "colour.png": cv2.imencode(".png", np.dstack([gray] * 3))[1].tobytes(),
        "text.png": b"not an image at all\n",
        "good.tif": tiff,
    }
    write_set(tmp_path / "set", files)
    source = ReplaySource(tmp_path / "set", "A", RealClock(), speed=0)
    assert len(source) == len(files)
    stop = threading.Event()
    caps = []
    while (cap := source(stop)) is not None:
        caps.append(cap)
    assert [c.frame.extra["source"] for c in caps] == ["good.png", "good.tif"]
    assert caps[0].frame.png == png  # the recorded bytes, not re-encoded
    assert np.array_equal(decode_frame(caps[1].frame.png), gray)  # a TIFF goes out as PNG
    assert all(c.frame.extra["size"] == (64, 48) for c in caps)
    assert (caps[0].wavelength_nm, caps[0].frame.exposure_s, caps[0].frame.gain_db) == (460, 0.05, 8.0)
    skipped = dict(source.skipped)
    assert set(skipped) == {"missing.png", "cut.png", "deep.png", "colour.png", "text.png"}
    assert "No such file" in skipped["missing.png"]
    assert "truncated" in skipped["cut.png"]
    assert "16-bit" in skipped["deep.png"]
    assert "colour type" in skipped["colour.png"]
    assert skipped["text.png"].startswith("unreadable")
