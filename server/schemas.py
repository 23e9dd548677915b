"""API models: what the API returns and accepts, apart from the tables."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field, field_validator


class DivePublic(BaseModel):
    id: int
    name: str
    started_unix_s: float
    ended_unix_s: float | None
    notes: str = ""
    calibration_id: int | None = None
    n_frames: int = 0
    first_frame_unix_s: float | None = None
    last_frame_unix_s: float | None = None
    max_depth_m: float | None = None


class FramePublic(BaseModel):
    model_config = ConfigDict(extra="allow")
    id: int
    dive_id: int
    module: str
    boot: str
    seq: int
    captured_unix_s: float
    wavelength_nm: int
    exposure_s: float
    gain_db: float
    depth_m: float | None
    width_px: int
    height_px: int
    status: str = Field(description="ok, rejected, or pending (not analysed yet)")
    reason: str | None
    centroid_px: list[float] | None = Field(description="[x, y], origin at the centre of the top-left pixel")
    radius_px: float | None
    i_center_gray: float | None
    i_center_err_gray: float | None
    background_gray: float | None
    thumbnail_url: str
    image_url: str


class FramePage(BaseModel):
    items: list[FramePublic]
    total: int
    limit: int
    offset: int


class AlarmPublic(BaseModel):
    id: int
    key: str
    kind: str
    module: str | None
    severity: str
    message: str
    raised_unix_s: float
    cleared_unix_s: float | None
    acked_unix_s: float | None
    acked_by: str | None
    active: bool


class AttenuationPointPublic(BaseModel):
    """One LEM visit's λ_att: at the mean time and LEM depth of its frames; ``final`` false while
    the visit runs."""

    model_config = ConfigDict(extra="allow")
    id: int
    run_id: int
    wavelength_nm: int
    t_unix_s: float
    depth_m: float | None
    lambda_att_m: float | None
    stat_err_m: float | None
    sys_err_m: float | None
    total_err_m: float | None
    n_pairs: int
    n_frames: int | None = None
    visit_key: str | None = None
    t_first_unix_s: float | None = None
    t_last_unix_s: float | None = None
    final: bool = True


class RunPublic(BaseModel):
    id: int
    kind: str
    label: str
    calibration: dict[str, Any]
    calibration_id: int | None
    software_version: str
    created_unix_s: float
    status: str
    n_frames: int


class CameraDistance(BaseModel):
    distance_m: float = Field(gt=0, le=10000)
    distance_err_m: float = Field(0.0, ge=0, le=100)


class Ratio(BaseModel):
    value: float = Field(gt=0, le=100)
    err: float = Field(0.0, ge=0, le=100)


class ReanalysisCreate(BaseModel):
    """Calibration inputs for a re-analysis; anything left out keeps the live run's value."""

    model_config = ConfigDict(extra="forbid")
    label: str = Field("", max_length=200)
    cameras: dict[str, CameraDistance] | None = None
    emission_ratio: dict[int, Ratio] | None = None
    linear_range: tuple[float, float] | None = None
    calibration_id: int | None = None

    @field_validator("linear_range")
    @classmethod
    def _ordered(cls, v: tuple[float, float] | None) -> tuple[float, float] | None:
        if v is not None and not (0 <= v[0] < v[1] <= 255):
            raise ValueError("must satisfy 0 <= low < high <= 255")
        return v


class AckRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")
    note: str = Field("", max_length=500)
