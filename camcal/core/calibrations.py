"""Calibration records: the analysis inputs a dive depends on, built from lab results.

A record's ``values`` hold a complete setup (distances, I0'/I0, linear range,
as in setup.json, and optionally the PSF width and focal length), the rows
of the lab results it came from, and their sources.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from camcal.core.frameset import FrameSetError, Setup, parse_setup

#: The lab experiments of the paper's "Calibration" section, by the name every part uses: the
#: simulator (`lrm.labset`), ``camcal calibrate`` and ``camcal simulate-lab``, the bench, the tests.
LAB_EXPERIMENTS = ("linearity", "emission-ratio", "air-scan", "tank-scan", "psf")


class CalibrationError(ValueError):
    """A lab result or setup that cannot make a calibration."""


def merge_results(
    base: Setup, results: list[dict[str, Any]]
) -> tuple[Setup, list[dict[str, Any]], list[str]]:
    """Merge the setup fragments of `camcal calibrate` results onto a base setup.

    Returns the merged setup, the result rows (``values``) tagged with the
    result they came from, and one source line per result.
    """
    data = base.model_dump()
    rows: list[dict[str, Any]] = []
    sources: list[str] = []
    for res in results:
        if res.get("schema") != "camcal.calibration/1":
            raise CalibrationError(f"not a camcal calibration result (schema {res.get('schema')!r})")
        frag = res.get("setup") or {}
        if "linear_range" in frag:
            data["linear_range"] = frag["linear_range"]
        for wl, r in (frag.get("emission_ratio") or {}).items():
            data["emission_ratio"][int(wl)] = r
        for k in ("cameras",):
            for cam, v in (frag.get(k) or {}).items():
                data["cameras"][cam] = v
        for row in res.get("values") or []:
            rows.append({**row, "result": res.get("name"), "camera": res.get("camera")})
        src = res.get("source") or {}
        sources.append(
            f"{src.get('command', res.get('name'))} [{(src.get('frame_set') or {}).get('path', '')}]"
        )
    try:
        return parse_setup(data, "merged calibration"), rows, sources
    except FrameSetError as exc:
        raise CalibrationError(str(exc)) from None


def load_json(path: Path) -> dict[str, Any]:
    try:
        obj = json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise CalibrationError(f"{path}: {exc}") from None
    if not isinstance(obj, dict):
        raise CalibrationError(f"{path}: not a JSON object")
    return obj


def record_values(setup: Setup, rows: list[dict[str, Any]], sources: list[str]) -> dict[str, Any]:
    return {"setup": setup.to_json(), "rows": rows, "sources": sources}


def setup_of(record: dict[str, Any]) -> Setup:
    """The setup a calibration record holds."""
    return parse_setup(record["values"]["setup"], f"calibration {record['name']}@{record['version']}")
