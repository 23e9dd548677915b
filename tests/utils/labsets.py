"""Factories for the lab-calibration tests: a small camera, lab frame sets, truth checks."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from lrm.labset import lab_spec, match_truth, truth_values, write_lab_set
from lrm.sim.camera import CameraModel

#: A 640 x 512 sensor with the T-REX 16° field of view: the LEM spans ~100 px
#: at 5 m and ~12 px at 41 m, so every lab experiment fits and renders fast.
SMALL_CAMERA = CameraModel(width_px=640, height_px=512, fov_deg=16.0)

#: Repeats per setting that keep each set small (a few seconds to render).
FAST_REPEATS = {"linearity": 1, "emission-ratio": 2, "air-scan": 1, "tank-scan": 1, "psf": 1}


def make_lab_set(folder: Path, kind: str, seed: int = 7, **values: Any) -> dict[str, Any]:
    """Write a small seeded lab set of ``kind`` into ``folder``; return its truth document."""
    values.setdefault("camera", SMALL_CAMERA)
    values.setdefault("repeats", FAST_REPEATS[kind])
    return write_lab_set(folder, lab_spec(kind, seed=seed, **values))


def render_in_memory(
    kind: str, seed: int = 7, **values: Any
) -> tuple[Any, list[Any], list[tuple[np.ndarray, dict]]]:
    """The spec, its shots and (frame, truth) pairs of a lab set, without touching the disk."""
    values.setdefault("camera", SMALL_CAMERA)
    values.setdefault("repeats", FAST_REPEATS[kind])
    spec = lab_spec(kind, seed=seed, **values)
    shots = spec.shots()
    cache: dict[Any, Any] = {}
    frames = [spec.render(s, np.random.default_rng([seed, s.index]), cache) for s in shots]
    return spec, shots, frames


def assert_recovers_truth(
    values: list[dict[str, Any]], truth_doc: dict[str, Any], n_sigma: float = 3.0
) -> int:
    """Assert every true value of a lab set is met by the result within ``n_sigma`` reported errors.

    Returns the number of values checked (so a test can assert it checked some).
    """
    pairs = match_truth(values, truth_values(truth_doc))
    misses = []
    for measured, true in pairs:
        assert measured["err"] is not None and measured["err"] > 0, measured
        pull = (measured["value"] - true["value"]) / measured["err"]
        if abs(pull) > n_sigma:
            misses.append(f"{true}: measured {measured['value']} ± {measured['err']} (pull {pull:+.2f})")
    assert not misses, "\n".join(misses)
    return len(pairs)
