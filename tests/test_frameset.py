"""Reading and writing frame sets: manifest rows, setup, images, atomic writes."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from camcal.core.frameset import (
    FrameSetError,
    ManifestRow,
    Setup,
    read_manifest,
    read_setup,
)
from camcal.core.framewriter import FrameSetWriter
from camcal.core.images import FrameReadError, _decode_unfiltered_png, decode_frame, encode_png, read_frame


def write_manifest(folder: Path, text: str) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "manifest.csv").write_text(text)


def test_columns_in_any_order_unknown_ones_kept(tmp_path: Path) -> None:
    write_manifest(
        tmp_path, "gain_db,exposure_s,note,file,camera,wavelength_nm,depth_m\n8,0.05,hello,a.png,A,460,3420\n"
    )
    (row,) = read_manifest(tmp_path)
    assert (row.file, row.camera, row.wavelength_nm) == ("a.png", "A", 460)
    assert (row.exposure_s, row.gain_db) == (0.05, 8.0)
    assert row.depth_m == 3420 and row.error is None and row.extra == {"note": "hello"}


@pytest.mark.parametrize(
    ("cells", "fragment"),
    [
        ("a.png,A,460,-0.05,8", "exposure_s -0.05 must be > 0"),
        ("a.png,A,blue,0.05,8", "wavelength_nm 'blue' is not a number"),
        ("a.png,A,460.5,0.05,8", "not an integer"),
        ("a.png,A,460,0.05,", "gain_db is empty"),
        ("../etc/passwd,A,460,0.05,8", "inside the frame set"),
        ("/abs.png,A,460,0.05,8", "inside the frame set"),
        ("a.png,,460,0.05,8", "camera is empty"),
        ("a.png,A,460,nan,8", "not finite"),
    ],
)
def test_bad_rows_carry_an_error_not_an_exception(tmp_path: Path, cells: str, fragment: str) -> None:
    write_manifest(tmp_path, f"file,camera,wavelength_nm,exposure_s,gain_db\n{cells}\n")
    (row,) = read_manifest(tmp_path)
    assert row.error is not None and fragment in row.error


def test_a_byte_that_is_not_utf8_rejects_its_row_not_the_frame_set(tmp_path: Path) -> None:
    """A failing SD card's damaged byte: the manifest still reads, and only that row is rejected."""
    (tmp_path / "manifest.csv").write_bytes(
        b"file,camera,wavelength_nm,exposure_s,gain_db\na.png,A,460,0.05,8\nb.png,\xffA,460,0.05,8\n"
    )
    good, bad = read_manifest(tmp_path)
    assert good.error is None and good.camera == "A"
    assert bad.error is not None and "damaged bytes" in bad.error and "not UTF-8" in bad.error


def test_missing_required_columns_are_fatal_and_named(tmp_path: Path) -> None:
    write_manifest(tmp_path, "file,camera,wavelength_nm\na.png,A,460\n")
    with pytest.raises(FrameSetError, match="required columns exposure_s, gain_db missing"):
        read_manifest(tmp_path)


def test_setup_defaults_to_trex_and_validates(tmp_path: Path) -> None:
    setup = read_setup(tmp_path)
    assert setup.cameras["A"].distance_m == 21.56 and setup.emission_ratio[460].value == 1.27
    (tmp_path / "setup.json").write_text('{"emission_ratio": {"460": {"value": 1.3, "err": 0.02}}}')
    setup = read_setup(tmp_path)
    assert setup.emission_ratio[460].value == 1.3 and setup.cameras["B"].distance_m == 41.62
    (tmp_path / "setup.json").write_text('{"linear_range": [250, 5]}')
    with pytest.raises(FrameSetError, match="linear_range"):
        read_setup(tmp_path)
    (tmp_path / "setup.json").write_text("{not json")
    with pytest.raises(FrameSetError, match="not valid JSON"):
        read_setup(tmp_path)


def test_writer_round_trip_and_resume(tmp_path: Path) -> None:
    frame = (np.arange(64 * 48) % 251).astype(np.uint8).reshape(48, 64)
    row = ManifestRow(
        index=0,
        file="A_460_00001.png",
        camera="A",
        wavelength_nm=460,
        exposure_s=0.05,
        gain_db=8.0,
        seq=1,
        timestamp="2021-09-10T04:00:00Z",
    )
    with FrameSetWriter(tmp_path, Setup()) as w:
        w.add(frame, row)
    with FrameSetWriter(tmp_path) as w:  # re-open: continues the manifest
        assert len(w) == 1
        w.add(encode_png(frame), ManifestRow(**{**row.__dict__, "file": "A_460_00002.png", "seq": 2}))
    rows = read_manifest(tmp_path)
    assert [r.file for r in rows] == ["A_460_00001.png", "A_460_00002.png"]
    assert rows[0].timestamp == "2021-09-10T04:00:00Z"
    np.testing.assert_array_equal(read_frame(tmp_path / rows[1].file), frame)
    assert not list(tmp_path.glob(".*tmp*"))


def test_decode_reports_each_problem() -> None:
    with pytest.raises(FrameReadError) as info:
        decode_frame(b"")
    assert info.value.reason == "unreadable"
    png = encode_png(np.zeros((10, 10), np.uint8))
    with pytest.raises(FrameReadError, match="truncated"):
        decode_frame(png[: len(png) // 2])
    with pytest.raises(FrameReadError) as info:
        read_frame(Path("/nonexistent/x.png"))
    assert "file not found" in info.value.detail


def _frame(seed: int, shape: tuple[int, int] = (48, 64)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    frame = rng.poisson(6.0, shape).astype(np.uint8)  # a dark, noisy camera frame
    frame[10:20, 30:45] = 250  # and something bright
    return frame


def test_module_pngs_decode_fast_and_every_other_png_as_opencv_does() -> None:
    frame = _frame(1)
    png = encode_png(frame)
    fast = _decode_unfiltered_png(np.frombuffer(png, np.uint8))
    assert fast is not None
    np.testing.assert_array_equal(fast, frame)
    np.testing.assert_array_equal(decode_frame(png), frame)
    # OpenCV's default PNG filters its rows: not for the fast path, still decoded
    filtered = cv2.imencode(".png", frame)[1].tobytes()
    assert _decode_unfiltered_png(np.frombuffer(filtered, np.uint8)) is None
    np.testing.assert_array_equal(decode_frame(filtered), frame)
    tiff = cv2.imencode(".tiff", frame)[1].tobytes()
    np.testing.assert_array_equal(decode_frame(tiff), frame)
    deep = frame.astype(np.uint16) * 200  # a 16-bit frame decodes as it is (a Mono16 camera's)
    np.testing.assert_array_equal(decode_frame(cv2.imencode(".png", deep)[1].tobytes()), deep)
    for other, kind in (
        (cv2.imencode(".tiff", frame.astype(np.float32))[1].tobytes(), "float32"),
        (cv2.imencode(".png", cv2.merge([frame, frame, frame]))[1].tobytes(), "3-channel"),
    ):
        with pytest.raises(FrameReadError, match=kind) as info:
            decode_frame(other)
        assert info.value.reason == "bad_format"


@settings(max_examples=300, deadline=None)
@given(data=st.data())
def test_a_damaged_png_is_refused_or_decoded_exactly_as_opencv_decodes_it(data: st.DataObject) -> None:
    png = bytearray(encode_png(_frame(2)))
    at = data.draw(st.integers(0, len(png) - 1), label="byte")
    png[at] = data.draw(st.integers(0, 255).filter(lambda v: v != png[at]), label="value")
    cut = data.draw(st.integers(1, len(png)), label="length")
    damaged = bytes(png[:cut])
    fast = _decode_unfiltered_png(np.frombuffer(damaged, np.uint8))
    assert fast is None  # every byte is covered by a CRC, Adler-32 or the exact size
    try:
        got = decode_frame(damaged)
    except FrameReadError:
        return
    np.testing.assert_array_equal(got, cv2.imdecode(np.frombuffer(damaged, np.uint8), cv2.IMREAD_UNCHANGED))
