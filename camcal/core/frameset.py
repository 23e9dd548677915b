"""The frame set: camcal's on-disk exchange format (``docs/frameset.md``).

A folder with ``manifest.csv``, an optional ``setup.json`` and 8- or 16-bit
grayscale images. This module is the one place that reads it, and
`camcal.core.framewriter` the one that writes it: the LRM outbox,
``camcal analyze``, ``camcal import`` and replay all use them.
"""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from camcal.core.images import FrameReadError, read_frame
from camcal.core.numbers import Number

MANIFEST = "manifest.csv"
SETUP = "setup.json"
#: The largest module clock offset a setup corrects, in seconds (~31 years: a clock reset to the
#: last shutdown's time, weeks behind, is in; one never set, reading 1970, is not: such frames are
#: not stored, and its card imports with `camcal import --clock-offset`).
CLOCK_OFFSET_MAX_S = 1e9
REQUIRED_COLUMNS = ("file", "camera", "wavelength_nm", "exposure_s", "gain_db")
OPTIONAL_COLUMNS = (
    "timestamp",
    "depth_m",
    "seq",
    "distance_m",
    "distance_err_m",
    "temperature_c",
    "medium",
    "boot",
    "schedule_version",
    "hemisphere",
)
#: Values of the ``medium`` column: what lies between the source and the camera.
MEDIA = ("air", "water")
#: Values of the ``hemisphere`` column: which side of the LEM faces the camera,
#: the one toward the near camera (I0) or toward the far camera (I0').
HEMISPHERES = ("near", "far")
MANIFEST_COLUMNS = REQUIRED_COLUMNS + OPTIONAL_COLUMNS


class FrameSetError(Exception):
    """A frame set cannot be read at all (no manifest, missing column, bad setup).

    Fatal for a command: it exits with status 2 and this one-line message.
    """


# ---------------------------------------------------------------- setup.json
#: Focal length in pixels of the T-REX cameras in water (25 mm lens, ~16° over 2448 px).
TREX_FOCAL_PX = 8709.0
#: Relative I_center repeatability between visits per wavelength (``bench/repeatability.py``).
TREX_REPEATABILITY: dict[int, float] = {405: 0.0014, 460: 0.0013, 525: 0.0007}


class CameraSetup(BaseModel):
    model_config = ConfigDict(extra="allow")
    distance_m: Number = Field(gt=0, description="LEM-to-camera distance in metres")
    distance_err_m: Number = Field(0.0, ge=0, description="its one-sigma error in metres")
    focal_px: Number | None = Field(
        None, gt=0, description="focal length in pixels (default: the setup's focal_px)"
    )
    clock_offset_s: Number = Field(
        0.0,
        ge=-CLOCK_OFFSET_MAX_S,
        le=CLOCK_OFFSET_MAX_S,
        description="how far the camera's module clock was ahead of true time [s] (behind: < 0); "
        "its frames' times are corrected by it where the two cameras' frames are paired by time "
        "(the λ_att series per LEM visit)",
    )


class SeriesSetup(BaseModel):
    """How the live λ_att series is cut into LEM visits and what errors its points carry.

    A visit is a run of one wavelength's frames of the two cameras, in
    capture order, ended by a frame of another wavelength, a gap longer than
    ``visit_gap_s`` or a jump of the LEM's depth between two frames larger
    than ``visit_depth_jump_m`` (the winch moved); a run longer than ``visit_max_s`` is cut at
    multiples of ``visit_max_s`` (UTC). ``repeatability`` is the relative
    I_center repeatability of a camera between visits beyond the frames'
    own noise, per wavelength (``repeatability_default`` for others): the
    floor of a point's statistical error (`analysis.visit`; the defaults
    were measured by ``bench/repeatability.py``, see ``docs/series.md``).
    ``trend_prior_per_s`` is the width of the prior on how fast a camera's
    signal can change within a visit (d ln I / dt), where the wavelength's
    two previous visits, each within ``trend_visits_max_s`` of the next,
    do not give a sharper one.
    """

    model_config = ConfigDict(extra="forbid")
    visit_gap_s: Number = Field(30.0, gt=0, le=86400, description="a gap that ends a visit [s]")
    visit_max_s: Number = Field(600.0, gt=0, le=86400, description="longest visit [s]")
    visit_depth_jump_m: Number = Field(
        50.0, gt=0, le=10000, description="a jump of the LEM's depth between frames that ends a visit [m]"
    )
    repeatability: dict[int, Number] = Field(
        default_factory=lambda: dict(TREX_REPEATABILITY),
        description="relative I_center repeatability per wavelength",
    )
    repeatability_default: Number = Field(
        0.0015, ge=0, le=0.5, description="relative I_center repeatability of other wavelengths"
    )
    trend_prior_per_s: Number = Field(0.001, gt=0, le=1.0, description="prior width on d ln I / dt [1/s]")
    trend_visits_max_s: Number = Field(
        900.0,
        ge=0,
        le=86400,
        description="longest gap between a wavelength's visits whose levels give the next visit's "
        "trend prior [s] (0: never, the fixed prior only)",
    )

    @field_validator("repeatability")
    @classmethod
    def _floors(cls, v: dict[int, float]) -> dict[int, float]:
        bad = {wl: x for wl, x in v.items() if not 0 <= x <= 0.5}
        if bad:
            raise ValueError(f"repeatability must lie in [0, 0.5], got {bad}")
        return v

    def repeatability_at(self, wavelength_nm: int) -> float:
        return self.repeatability.get(int(wavelength_nm), self.repeatability_default)


class RatioSetup(BaseModel):
    model_config = ConfigDict(extra="allow")
    value: Number = Field(gt=0, description="I0'/I0, far side over near side")
    err: Number = Field(0.0, ge=0, description="its one-sigma error")


def _trex_cameras() -> dict[str, CameraSetup]:
    return {
        "A": CameraSetup(distance_m=21.56, distance_err_m=0.02),
        "B": CameraSetup(distance_m=41.62, distance_err_m=0.04),
    }


def _trex_ratios() -> dict[int, RatioSetup]:
    return {
        405: RatioSetup(value=1.04, err=0.03),
        460: RatioSetup(value=1.27, err=0.04),
        525: RatioSetup(value=1.23, err=0.04),
    }


#: Beyond these a setup value is kept but questioned (`Setup.warnings`): the LEM is not seen farther
#: in sea water, and I0'/I0 is a ratio of two sides of one sphere.
PLAUSIBLE_DISTANCE_M = 300.0
PLAUSIBLE_RATIO = (0.2, 5.0)


class Setup(BaseModel):
    """The contents of ``setup.json``; anything missing takes the T-REX value."""

    model_config = ConfigDict(extra="allow")
    cameras: dict[str, CameraSetup] = Field(default_factory=_trex_cameras)
    emission_ratio: dict[int, RatioSetup] = Field(default_factory=_trex_ratios)
    linear_range: tuple[Number, Number] = (5.0, 240.0)
    focal_px: Number = Field(TREX_FOCAL_PX, gt=0, description="focal length of the cameras in pixels")
    lem_diameter_m: Number = Field(0.43, gt=0, description="diameter of the LEM sphere in metres")
    series: SeriesSetup = Field(default_factory=SeriesSetup)

    def disk_radius_px(self, camera: str) -> float | None:
        """The LEM's radius in pixels the pinhole model predicts for a camera, or None if unknown.

        ``f · a / sqrt(L² - a²)`` with ``f`` the camera's focal length, ``a``
        the LEM's radius and ``L`` its distance.
        """
        cam = self.cameras.get(camera)
        a = self.lem_diameter_m / 2.0
        if cam is None or cam.distance_m <= a:
            return None
        focal = cam.focal_px or self.focal_px
        return focal * a / math.sqrt(cam.distance_m**2 - a * a)

    def frame_settings(self, camera: str | None = None) -> dict[str, Any]:
        """The per-frame analysis settings for a camera's frames: linear range and disk size.

        Plain values, the keyword arguments of `analysis.frame.FrameConfig`
        (the kernel knows no analysis types): ``FrameConfig(**setup.frame_settings(cam))``.
        """
        lo, hi = self.linear_range
        return {
            "linear_range_gray": (lo, hi),
            "expected_radius_px": self.disk_radius_px(camera) if camera is not None else None,
        }

    @field_validator("linear_range")
    @classmethod
    def _range_ordered(cls, v: tuple[float, float]) -> tuple[float, float]:
        lo, hi = v
        if not (0 <= lo < hi <= 255):
            raise ValueError(f"must satisfy 0 <= low < high <= 255, got [{lo}, {hi}]")
        return v

    def warnings(self) -> list[str]:
        """What in this setup is kept but looks wrong: keys the format does not know (ignored, so
        a misspelt one leaves the T-REX value in force) and values far outside what the method can
        mean (a distance in centimetres, a ratio in per cent)."""
        out = [
            f"setup.json: unknown key {key!r} ignored (the keys: {', '.join(Setup.model_fields)})"
            for key in sorted(self.model_extra or {})
        ]
        for cam, c in sorted(self.cameras.items()):
            out += [
                f"setup.json: camera {cam}: unknown key {k!r} ignored" for k in sorted(c.model_extra or {})
            ]
            if c.distance_m > PLAUSIBLE_DISTANCE_M:
                out.append(
                    f"setup.json: camera {cam} {c.distance_m:g} m from the LEM: in metres? (the LEM is "
                    f"seen to ~{PLAUSIBLE_DISTANCE_M:g} m in sea water; λ_att scales with the distance)"
                )
        for wl, r in sorted(self.emission_ratio.items()):
            out += [
                f"setup.json: emission_ratio {wl}: unknown key {k!r} ignored"
                for k in sorted(r.model_extra or {})
            ]
            lo, hi = PLAUSIBLE_RATIO
            if not lo <= r.value <= hi:
                out.append(
                    f"setup.json: emission_ratio {wl} = {r.value:g}: I0'/I0 is a ratio near 1 (T-REX's "
                    f"1.04-1.27), not a percentage; outside {lo:g}-{hi:g} it rules λ_att"
                )
        return out

    def to_json(self) -> dict[str, Any]:
        data = self.model_dump(mode="json")
        data["emission_ratio"] = {str(k): v for k, v in data["emission_ratio"].items()}
        data["linear_range"] = list(self.linear_range)
        return data


def read_setup(folder: Path) -> Setup:
    """``setup.json`` of a frame set, or the T-REX defaults if there is none."""
    path = Path(folder) / SETUP
    if not path.exists():
        return Setup()
    try:
        data = json.loads(path.read_text(encoding="utf-8-sig"))  # a BOM, as a manifest may have
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise FrameSetError(f"{path}: not valid JSON ({exc})") from exc
    return parse_setup(data, str(path))


def parse_setup(data: Any, where: str = "setup") -> Setup:
    """Validate a setup mapping; errors name the field and the reason."""
    try:
        return Setup.model_validate(data)
    except ValidationError as exc:
        first = exc.errors()[0]
        loc = ".".join(str(p) for p in first["loc"])
        what = first["msg"] if loc else "must be a JSON object (cameras, emission_ratio...: docs/frameset.md)"
        raise FrameSetError(f"{where}: {loc + ': ' if loc else ''}{what}") from exc


# -------------------------------------------------------------- manifest.csv
@dataclass(frozen=True)
class ManifestRow:
    """One manifest row. ``error`` says why the row's metadata cannot be used."""

    index: int
    file: str
    camera: str
    wavelength_nm: int
    exposure_s: float
    gain_db: float
    timestamp: str | None = None
    depth_m: float | None = None
    seq: int | None = None
    distance_m: float | None = None
    distance_err_m: float | None = None
    temperature_c: float | None = None
    medium: str | None = None
    boot: str | None = None
    schedule_version: int | None = None
    hemisphere: str | None = None
    error: str | None = None
    extra: Mapping[str, str] = field(default_factory=dict, repr=False, compare=False)

    def to_csv(self) -> dict[str, str]:
        out: dict[str, str] = {}
        for col in MANIFEST_COLUMNS:
            v = getattr(self, col)
            out[col] = "" if v is None else (repr(v) if isinstance(v, float) else str(v))
        return out


def _number(value: str, column: str, *, integer: bool = False) -> float:
    try:
        x = float(value)
    except ValueError:
        raise ValueError(f"{column} {value!r} is not a number") from None
    if not math.isfinite(x):
        raise ValueError(f"{column} {value!r} is not finite")
    if integer and x != int(x):
        raise ValueError(f"{column} {value!r} is not an integer")
    return x


def _parse_row(index: int, raw: Mapping[str, str | None]) -> ManifestRow:
    get = {k.strip(): (v or "").strip() for k, v in raw.items() if k is not None}
    problems: list[str] = []
    if any(DAMAGED in v for v in get.values()):
        problems.append(DAMAGED_ROW)

    def num(col: str, *, integer: bool = False, required: bool = False) -> float | None:
        text = get.get(col, "")
        if text == "":
            if required:
                problems.append(f"{col} is empty")
            return None
        try:
            return _number(text, col, integer=integer)
        except ValueError as exc:
            problems.append(str(exc))
            return None

    file = get.get("file", "")
    if not file:
        problems.append("file is empty")
    elif Path(file).is_absolute() or ".." in Path(file).parts:
        problems.append(f"file {file!r} must be a path inside the frame set")
    camera = get.get("camera", "")
    if not camera:
        problems.append("camera is empty")
    wl = num("wavelength_nm", integer=True, required=True)
    exposure = num("exposure_s", required=True)
    gain = num("gain_db", required=True)
    if wl is not None and wl <= 0:
        problems.append(f"wavelength_nm {int(wl)} must be > 0")
    if exposure is not None and exposure <= 0:
        problems.append(f"exposure_s {exposure:g} must be > 0")
    depth = num("depth_m")
    seq = num("seq", integer=True)
    distance = num("distance_m")
    if distance is not None and distance <= 0:
        problems.append(f"distance_m {distance:g} must be > 0")
    distance_err = num("distance_err_m")
    if distance_err is not None and distance_err < 0:
        problems.append(f"distance_err_m {distance_err:g} must be >= 0")
    temperature = num("temperature_c")
    schedule_version = num("schedule_version", integer=True)
    if temperature is not None and temperature <= -273.15:
        problems.append(f"temperature_c {temperature:g} is below absolute zero")
    medium = get.get("medium") or None
    if medium is not None and medium not in MEDIA:
        problems.append(f"medium {medium!r} must be air or water")
    hemisphere = get.get("hemisphere") or None
    if hemisphere is not None and hemisphere not in HEMISPHERES:
        problems.append(f"hemisphere {hemisphere!r} must be near or far")
    known = set(MANIFEST_COLUMNS)
    return ManifestRow(
        index=index,
        file=file,
        camera=camera,
        wavelength_nm=int(wl) if wl is not None else 0,
        exposure_s=exposure if exposure is not None else float("nan"),
        gain_db=gain if gain is not None else float("nan"),
        timestamp=get.get("timestamp") or None,
        depth_m=depth,
        seq=int(seq) if seq is not None else None,
        distance_m=distance,
        distance_err_m=distance_err,
        temperature_c=temperature,
        medium=medium,
        boot=get.get("boot") or None,
        schedule_version=int(schedule_version) if schedule_version is not None else None,
        hemisphere=hemisphere,
        error="; ".join(problems) or None,
        extra={k: v for k, v in get.items() if k not in known},
    )


def read_manifest(folder: Path) -> list[ManifestRow]:
    """All rows of ``manifest.csv`` in order.

    A missing manifest or a missing required column raises `FrameSetError`
    (fatal). A row with a bad value is returned with ``error`` set, so the
    frame is reported rejected and the run goes on.
    """
    folder = Path(folder)
    path = folder / MANIFEST
    if not folder.is_dir():
        raise FrameSetError(f"{folder}: no such frame-set folder")
    if not path.is_file():
        raise FrameSetError(f"{path}: manifest missing (a frame set needs {MANIFEST})")
    try:
        text = decode_text(path.read_bytes())
    except OSError as exc:
        raise FrameSetError(f"{path}: cannot read the manifest ({exc})") from exc
    return parse_manifest(text, str(path))


#: What a byte that is not UTF-8 reads as (`decode_text`), and the error of a row holding one.
DAMAGED = "\ufffd"
DAMAGED_ROW = "damaged bytes in this row (not UTF-8: a failing card?)"


def decode_text(data: bytes) -> str:
    """A manifest's (or another text file of a frame set or SD card) bytes as text. A byte that is
    not UTF-8 (a failing SD card) reads as `DAMAGED`, so that only its row or line is rejected (a
    manifest row's ``error`` says so), not the whole file."""
    return data.decode("utf-8-sig", errors="replace")


def parse_manifest(text: str, where: str = MANIFEST) -> list[ManifestRow]:
    """The rows of a manifest's text (read from a folder, an object store...); see `read_manifest`."""
    try:
        reader = csv.DictReader(io.StringIO(text.removeprefix("\ufeff"), newline=""))
        header = [h.strip() for h in (reader.fieldnames or [])]
        known = set(REQUIRED_COLUMNS) | set(OPTIONAL_COLUMNS)
        twice = sorted({h for h in header if h in known and header.count(h) > 1})
        if twice:  # which of the two would be the frame's value? (csv keeps the last, silently)
            raise FrameSetError(
                f"{where}: column{'s' if len(twice) > 1 else ''} {', '.join(twice)} appear"
                f"{'' if len(twice) > 1 else 's'} twice in the header: keep one"
            )
        missing = [c for c in REQUIRED_COLUMNS if c not in header]
        if missing:
            raise FrameSetError(
                f"{where}: required column{'s' if len(missing) > 1 else ''} "
                f"{', '.join(missing)} missing (header: {', '.join(header) or 'empty'})"
            )
        return [_parse_row(i, raw) for i, raw in enumerate(reader)]
    except csv.Error as exc:
        raise FrameSetError(f"{where}: cannot read the manifest ({exc})") from exc


def iter_frames(folder: Path) -> Iterator[tuple[ManifestRow, np.ndarray | FrameReadError]]:
    """Rows with their decoded frames (or the error that kept the frame from loading)."""
    folder = Path(folder)
    for row in read_manifest(folder):
        if row.error:
            yield row, FrameReadError("bad_metadata", row.error)
            continue
        try:
            yield row, read_frame(folder / row.file)
        except FrameReadError as exc:
            yield row, exc
