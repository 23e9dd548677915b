"""How to store a 5 MP frame on the ship: write and read time and size per format, on realistic frames.

The module sends PNG. Storing those bytes as they are costs only the write;
any other format must first decode the PNG (the "read" of the PNG row) and
then encode. Every write ends with fsync, as the ingest's do; every read
ends with a 2-D uint8 array in memory (what the analysis needs). Frames come
from the 5 MP set of ``bench/bench_ingest.py`` (rendered there if missing).

Run: ``.venv/bin/python bench/bench_frame_storage.py [--frames N]``.
"""

from __future__ import annotations

import argparse
import io
import os
import statistics
import struct
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pyarrow as pa
from bench_ingest import frame_set  # bench/ is on the path when this file runs

from camcal.core.frameset import read_manifest
from camcal.core.images import PNG_PARAMS, decode_frame


def write_fsync(path: Path, data: bytes) -> None:
    with open(path, "wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())


def zstd(level: int) -> tuple[Callable[[np.ndarray], bytes], Callable[[bytes], np.ndarray]]:
    codec = pa.Codec("zstd", compression_level=level)

    def enc(f: np.ndarray) -> bytes:
        return struct.pack("<II", *f.shape) + codec.compress(f, asbytes=True)

    def dec(b: bytes) -> np.ndarray:
        h, w = struct.unpack("<II", b[:8])
        raw = codec.decompress(b[8:], decompressed_size=h * w, asbytes=True)
        return np.frombuffer(raw, np.uint8).reshape(h, w)

    return enc, dec


def npy_enc(f: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, f)
    return buf.getvalue()


def npy_dec(b: bytes) -> np.ndarray:
    return np.load(io.BytesIO(b))


def cv_enc(ext: str, params: list[int]) -> Callable[[np.ndarray], bytes]:
    return lambda f: cv2.imencode(ext, f, params)[1].tobytes()


def cv_dec(b: bytes) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(b, np.uint8), cv2.IMREAD_UNCHANGED)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=12, help="frames to measure (medians)")
    parser.add_argument("--repeats", type=int, default=3, help="timings per frame (the best is kept)")
    parser.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "camcal-bench")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    folder = frame_set(args.cache, 3)
    rows = read_manifest(folder)
    rows = rows[:: max(1, len(rows) // args.frames)][: args.frames]
    pngs = [(folder / r.file).read_bytes() for r in rows]
    frames = [cv_dec(b) for b in pngs]
    z1, z3 = zstd(1), zstd(3)
    camcal_png = cv_enc(".png", list(PNG_PARAMS))
    formats: list[tuple[str, Callable[[np.ndarray, bytes], bytes], Callable[[bytes], np.ndarray]]] = [
        ("PNG as the module sent it (the ingest; camcal's decoder)", lambda f, png: png, decode_frame),
        ("PNG as the module sent it, read by OpenCV", lambda f, png: png, cv_dec),
        ("PNG, no filter, zlib 1, encoded (a module)", lambda f, png: camcal_png(f), decode_frame),
        ("PNG, OpenCV default", lambda f, png: cv_enc(".png", [])(f), cv_dec),
        (".npy", lambda f, png: npy_enc(f), npy_dec),
        ("TIFF uncompressed", lambda f, png: cv_enc(".tiff", [cv2.IMWRITE_TIFF_COMPRESSION, 1])(f), cv_dec),
        ("TIFF LZW", lambda f, png: cv_enc(".tiff", [cv2.IMWRITE_TIFF_COMPRESSION, 5])(f), cv_dec),
        ("zstd level 1 (pyarrow)", lambda f, png: z1[0](f), z1[1]),
        ("zstd level 3 (pyarrow)", lambda f, png: z3[0](f), z3[1]),
    ]
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "frame"
        for name, enc, dec in formats:
            w, r, size = [], [], []
            for f, png in zip(frames, pngs, strict=True):
                tw, tr = [], []
                for _ in range(args.repeats):  # the best of a few: other processes only ever add time
                    t0 = time.perf_counter()
                    data = enc(f, png)
                    write_fsync(path, data)
                    tw.append(time.perf_counter() - t0)
                    t0 = time.perf_counter()
                    back = dec(path.read_bytes())
                    tr.append(time.perf_counter() - t0)
                assert np.array_equal(back, f), name
                w.append(min(tw))
                r.append(min(tr))
                size.append(len(data))
            results.append((name, statistics.median(w), statistics.median(r), statistics.mean(size)))
    print()
    h, w = frames[0].shape
    print(
        f"{len(frames)} frames of {w} x {h} px; median over frames of the best of {args.repeats}; "
        "every write ends with fsync"
    )
    print()
    print("| format | write ms | read ms | MB per frame |")
    print("| --- | --- | --- | --- |")
    for name, w, r, size in results:
        print(f"| {name} | {w * 1e3:.1f} | {r * 1e3:.1f} | {size / 1e6:.2f} |")


if __name__ == "__main__":
    main()
