"""What runs in the analysis processes: decode a stored frame, analyse it, make its thumbnail.

`analyse_batch` is what a re-analysis maps over its workers (a process pool
or a Dask cluster): a batch of frames, each read through fsspec.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from analysis import FrameAnalysis, FrameConfig, analyze_frame, rejected
from camcal.core.files import write_atomic
from camcal.core.images import FrameReadError, decode_frame_scaled, read_frame_scaled

THUMB_WIDTH_PX = 512


def _num(x: float | None, digits: int = 4) -> float | None:
    if x is None or not math.isfinite(x):
        return None
    return round(float(x), digits)


def thumbnail_jpeg(frame: np.ndarray, width_px: int = THUMB_WIDTH_PX, quality: int = 85) -> bytes:
    """A small JPEG of a frame: a quarter first by striding, then area resizes.

    An area resize by a whole factor (2 x 2 pixels into one) is OpenCV's fast
    path; by a fraction (1224 -> 512 px) it takes ~3x longer. So the strided
    frame is halved while it is at least twice the thumbnail's width, and only
    the last, small step is fractional (~2.4 instead of ~6 ms for 5 MP).
    """
    step = max(1, frame.shape[1] // (width_px * 2))
    small = frame[::step, ::step]
    if small.dtype == np.uint16:  # a 16-bit frame (MSB-aligned, as stored): its top 8 bits
        small = (small >> 8).astype(np.uint8)
    while small.shape[1] >= 2 * width_px and small.shape[0] >= 2:
        even = small[: small.shape[0] // 2 * 2, : small.shape[1] // 2 * 2]
        small = cv2.resize(even, (even.shape[1] // 2, even.shape[0] // 2), interpolation=cv2.INTER_AREA)
    height_px = max(1, round(small.shape[0] * width_px / small.shape[1]))
    small = cv2.resize(small, (width_px, height_px), interpolation=cv2.INTER_AREA)
    ok, buf = cv2.imencode(".jpg", small, [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise ValueError("JPEG encoding failed")
    return buf.tobytes()


def result_row(res: FrameAnalysis) -> dict[str, Any]:
    """A `FrameAnalysis` as the columns of a stored frame result."""
    row: dict[str, Any] = {
        "status": res.status,
        "reason": res.reason,
        "detail": res.detail,
        "centroid_x_px": _num(res.centroid_px[0], 3) if res.centroid_px else None,
        "centroid_y_px": _num(res.centroid_px[1], 3) if res.centroid_px else None,
        "radius_px": _num(res.radius_px, 3),
        "elongation": _num(res.elongation),
        "center_gray": _num(res.center_gray),
        "center_err_gray": _num(res.center_err_gray),
        "background_gray": _num(res.background_gray),
        "background_err_gray": _num(res.background_err_gray),
        "i_center_gray": _num(res.i_center_gray),
        "i_center_err_gray": _num(res.i_center_err_gray),
        "fit": None,
        "profile": None,
    }
    if res.fit is not None:
        f = res.fit
        row["fit"] = {
            "amplitude_gray": _num(f.amplitude_gray),
            "scale_px": _num(f.scale_px),
            "background_gray": _num(f.background_gray),
            "background_err_gray": _num(f.background_err_gray),
            "r_min_px": _num(f.r_min_px, 2),
            "chi2_ndof": _num(f.chi2_ndof, 3),
            "converged": f.converged,
        }
    if res.profile is not None:
        p = res.profile
        row["profile"] = {
            "radius_px": [_num(v, 1) for v in p.radius_px],
            "mean_gray": [_num(v, 3) for v in p.mean_gray],
            "sem_gray": [_num(v, 4) for v in p.sem_gray],
            "count": [int(c) for c in p.count],
        }
    return row


def warm_up() -> None:
    """Nothing: submitting it to a pool starts a worker process, which imports this module."""


def analyse_stored_frame(path: str, config: FrameConfig, thumb_path: str | None) -> dict[str, Any]:
    """Analyse the frame file at ``path``; write its thumbnail; return the result columns.

    Never raises for a bad file: an unreadable frame is a rejected result. A thumbnail that cannot
    be written (a full disk) is left out; the result is kept.
    """
    t0 = time.perf_counter()
    try:
        frame, top = read_frame_scaled(Path(path))
    except FrameReadError as exc:
        row = result_row(rejected(exc.reason, exc.detail))
        row["analysis_s"] = time.perf_counter() - t0
        return row
    res = analyze_frame(frame, config, full_scale=top)
    row = result_row(res)
    row["width_px"], row["height_px"] = frame.shape[1], frame.shape[0]
    if thumb_path:
        out = Path(thumb_path)
        try:
            out.parent.mkdir(parents=True, exist_ok=True)
            write_atomic(out, thumbnail_jpeg(frame), fsync=False)
        except OSError:  # a full or failing disk costs the cached thumbnail, never the result:
            pass  # the dashboard makes a missing thumbnail when it is asked for
    row["analysis_s"] = time.perf_counter() - t0
    return row


def analyse_batch(
    tasks: Sequence[tuple[int, str] | tuple[int, str, str]],
    config: FrameConfig | Mapping[str, FrameConfig],
    storage_options: dict[str, Any] | None = None,
) -> list[tuple[int, dict[str, Any]]]:
    """Analyse frames ``(frame_id, url)`` or ``(frame_id, url, module)``: each read through fsspec
    (a local path or any URL such as ``s3://bucket/key``), decoded and analysed with ``config`` (or
    its module's, when ``config`` maps modules to configs). Returns ``(frame_id, result columns)``
    in order.

    Never raises for a bad frame: a missing or unreadable one is a rejected result.
    """
    from storage.files import read_url

    out = []
    for task in tasks:
        frame_id, url = task[0], task[1]
        if isinstance(config, FrameConfig):
            cfg = config
        else:  # the module's config, else the one under "" (any module)
            cfg = config.get(str(task[2]) if len(task) > 2 else "") or config[""]
        t0 = time.perf_counter()
        name = url.rsplit("/", 1)[-1]
        try:
            frame, top = decode_frame_scaled(read_url(url, storage_options), name)
        except FileNotFoundError:
            row = result_row(rejected("unreadable", f"{name}: file not found"))
        except OSError as exc:
            row = result_row(rejected("unreadable", f"{name}: {exc}"))
        except FrameReadError as exc:
            row = result_row(rejected(exc.reason, exc.detail))
        else:
            row = result_row(analyze_frame(frame, cfg, full_scale=top))
            row["width_px"], row["height_px"] = frame.shape[1], frame.shape[0]
        row["analysis_s"] = time.perf_counter() - t0
        out.append((frame_id, row))
    return out
