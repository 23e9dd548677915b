"""API models: what the API returns and accepts, apart from the tables."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

from camcal.core.events import EventKind
from camcal.core.frameset import CLOCK_OFFSET_MAX_S
from camcal.core.numbers import Integer, Number


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
    #: When the ship received the dive's first and last frame (its own clock).
    first_received_unix_s: float | None = None
    last_received_unix_s: float | None = None
    max_depth_m: float | None = None
    #: ``open`` or ``ended``, and why (`storage.queries.divestate`): an operator ended it, its modules
    #: came back on deck and signed off or sent nothing for the quiet time; or where it stands.
    state: Literal["open", "ended"] = "open"
    state_reason: str = ""
    #: When it ended (ship's clock); None while open.
    state_ended_unix_s: float | None = None
    #: The reason stored with its end (None: not recorded as ended yet).
    end_reason: str | None = None


class FramePublic(BaseModel):
    model_config = ConfigDict(extra="allow")
    id: int
    dive_id: int
    module: str
    boot: str
    seq: int
    captured_unix_s: float
    captured_ship_unix_s: float | None = Field(
        None, description="when it was captured, on the ship's clock (its module's time mapped onto it)"
    )
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
    #: ``t_unix_s`` on the ship's clock, the dive's one axis (None: not known; ``t_unix_s`` stands).
    t_ship_unix_s: float | None = None
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
    calibration: dict[str, Any] = Field(description="the calibration the run stores ({}: none of its own)")
    setup: dict[str, Any] = Field(
        description="the setup.json values the run was analysed with: its calibration, else the dive's "
        "own setup (an imported frame set's), else the defaults (T-REX's)"
    )
    setup_from: Literal["run", "dive", "defaults"]
    calibration_id: int | None
    software_version: str
    created_unix_s: float
    status: str = Field(
        description="live runs: running; re-analyses: queued, running, done, failed, cancelled (still "
        "queued when the server stopped) or interrupted (its process stopped while it ran)"
    )
    n_frames: int
    note: str | None = Field(None, description="what to do about the status, when it needs something")


class CameraDistance(BaseModel):
    distance_m: Number = Field(gt=0, le=10000)
    distance_err_m: Number = Field(0.0, ge=0, le=100)
    clock_offset_s: Number | None = Field(
        None,
        ge=-CLOCK_OFFSET_MAX_S,
        le=CLOCK_OFFSET_MAX_S,
        description="the module clock ahead of true time [s] (setup's)",
    )


class Ratio(BaseModel):
    value: Number = Field(gt=0, le=100)
    err: Number = Field(0.0, ge=0, le=100)


class ReanalysisCreate(BaseModel):
    """Calibration inputs for a re-analysis; anything left out keeps the live run's value."""

    model_config = ConfigDict(extra="forbid")
    label: str = Field("", max_length=200)
    cameras: dict[str, CameraDistance] | None = None
    emission_ratio: dict[int, Ratio] | None = None
    linear_range: tuple[Number, Number] | None = None
    calibration_id: Integer | None = None

    @field_validator("linear_range")
    @classmethod
    def _ordered(cls, v: tuple[float, float] | None) -> tuple[float, float] | None:
        if v is not None and not (0 <= v[0] < v[1] <= 255):
            raise ValueError("must satisfy 0 <= low < high <= 255")
        return v


class AckRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")
    note: str = Field("", max_length=500)


# ------------------------------------------------------------------ responses
# Every JSON route names one of these as its ``response_model``: /docs shows it and schemathesis
# checks each answer against it. Fields that only some rows carry are optional; objects whose keys
# are data (module ids, wavelengths) are dicts.

#: A JSON column as stored: an object as the API writes it, but any JSON value a row may hold.
Stored = Annotated[Any, Field(description="a JSON document as stored (normally an object)")]


class Open(BaseModel):
    """A response that may carry more fields than its model lists (documented where they come from)."""

    model_config = ConfigDict(extra="allow")


class Healthz(BaseModel):
    status: str
    version: str


class OperatorPublic(BaseModel):
    operator: str


class DiveSettings(BaseModel):
    """The distinct settings of a dive's frames (for the filter menus)."""

    modules: list[str]
    wavelengths_nm: list[int]
    exposures_s: list[float]
    gains_db: list[float]


class DepthSeries(BaseModel):
    t_unix_s: list[float]
    depth_m: list[float | None]


class FrameMark(BaseModel):
    t_unix_s: float = Field(description="when it was captured, on the ship's clock")
    depth_m: float | None
    module: str
    id: int
    captured_unix_s: float | None = Field(None, description="when it was captured, on its module's clock")


class ModuleClockPublic(BaseModel):
    """A module's clock during one boot, mapped onto the ship's (`camcal.core.clockmap`)."""

    module: str
    boot: str
    rate: float = Field(description="seconds of its clock per real second: 1 real, 10 a simulation at 10x")
    module_at_unix_s: float
    real_at_unix_s: float
    offset_s: float | None = Field(description="its clock against the mapping, newest (module seconds)")
    n_readings: int
    first_unix_s: float
    updated_unix_s: float


class Timeline(BaseModel):
    depth: DepthSeries = Field(description="every module's sensor depth together (downsampled)")
    depth_by_module: dict[str, DepthSeries] = Field(
        default_factory=dict, description="each module's own sensor depth (they hang apart)"
    )
    frames: list[FrameMark]
    frame_step: int = Field(description="every n-th frame is marked (at most ~2000 marks)")
    alarms: list[AlarmPublic]
    clocks: list[ModuleClockPublic] = Field(
        default_factory=list, description="each module's clock per boot: every time here is the ship's"
    )


class AttenuationRow(Open):
    """λ_att of one wavelength over a span, with the near/far setting pairs it combines."""

    wavelength_nm: int
    lambda_att_m: float | None
    stat_err_m: float | None
    sys_err_m: float | None
    total_err_m: float | None
    n_pairs: int
    pairs: list[dict[str, Any]]


class AttenuationBand(BaseModel):
    """λ_att of the frames of a span at one depth (the LEM's: a stop, the station, a slice)."""

    depth_min_m: float | None
    depth_max_m: float | None
    depth_m: float | None
    n_frames: int
    rows: list[AttenuationRow]


class AttenuationTable(BaseModel):
    run_id: int
    span: Stored
    calibration: dict[str, Any]
    rows: list[AttenuationRow]
    #: A table per depth band when the span crosses depths (else empty: ``rows`` is the one band).
    bands: list[AttenuationBand] = []


class ChisqFitSummary(BaseModel):
    id: int
    dive_id: int
    run_id: int | None
    calibration_id: int | None
    created_unix_s: float
    software_version: str
    label: str
    span: Stored


class ChisqFitPublic(ChisqFitSummary):
    result: Stored = Field(description="the fit's document: λ_abs, λ_sca per wavelength, Δχ² map")


class FrameDetail(FramePublic):
    """One frame with its full analysis (the fields after ``background_gray`` once it has a result)."""

    received_unix_s: float
    size_bytes: int
    sha256: str
    schedule_version: int
    source: str
    detail: str | None = None
    elongation: float | None = None
    center_gray: float | None = None
    center_err_gray: float | None = None
    background_err_gray: float | None = None
    fit: Stored = None
    profile: Stored = None
    run_id: int | None = None
    analysed_unix_s: float | None = None


class FrameAnalysis(BaseModel):
    id: int
    status: str
    reason: str | None
    detail: str | None
    centroid_px: list[float] | None
    radius_px: float | None
    elongation: float | None
    center_gray: float | None
    center_err_gray: float | None
    background_gray: float | None
    background_err_gray: float | None
    i_center_gray: float | None
    i_center_err_gray: float | None
    profile: Stored
    fit: Stored
    run_id: int | None


class ModuleSchedule(BaseModel):
    name: str | None
    version: int | None
    state: str | None


class ModuleCamera(Open):
    """What a module said of its camera (protocol revision 1.8: `camcal.core.wire.CameraInfo`)."""

    model: str = ""
    serial: str = ""
    pixel_format: str = ""
    bit_depth: int = 8
    exposure_range_s: tuple[float, float]
    gain_range_db: tuple[float, float]
    gain_step_db: float = 0.0


class ModulePublic(BaseModel):
    id: str
    distance_m: float | None
    last_seen_unix_s: float
    boot: str | None
    software: str | None
    schedule: ModuleSchedule
    camera: ModuleCamera | None = Field(
        None, description="its camera and the ranges the ship checks its schedules against; null: not said"
    )


class Series(Open):
    """A time series, averaged into buckets when long (then ``<first column>_min``/``_max`` too)."""

    module: str
    t_unix_s: list[float]
    downsampled: bool
    bucket_s: float | None
    n_samples: int


class AttenuationSeries(BaseModel):
    dive_id: int | None
    run_id: int | None
    series: dict[str, list[AttenuationPointPublic]] = Field(description="by wavelength in nm")


class LinearityCheckPublic(BaseModel):
    module: str
    wavelength_nm: int
    sweep: str
    fixed_value: float | None
    slope: float | None
    slope_err: float | None
    intercept_gray: float | None
    r2: float | None
    n_used: int | None
    linear_max_gray: float | None
    knee_x: float | None
    points: Stored
    updated_unix_s: float | None


class LinearityPublic(BaseModel):
    run_id: int | None
    checks: list[LinearityCheckPublic]


class AuditEntryPublic(BaseModel):
    id: int
    t_unix_s: float
    actor: str
    action: str
    target: str
    details: Stored
    what: str = Field(description="what happened, in words (as the review page and the CSV exports say it)")


class CalibrationPublic(BaseModel):
    id: int
    name: str
    version: int
    source: str
    valid_from_unix_s: float | None
    valid_to_unix_s: float | None
    values: Stored
    created_unix_s: float


class CommandPublic(BaseModel):
    id: str
    module: str
    action: str
    target_version: int
    payload: Stored
    apply: str
    issued_by: str
    issued_unix_s: float
    state: str
    reason: str | None
    attempts: int
    updated_unix_s: float


class PassEstimate(BaseModel):
    """One pass of a schedule against the LEM's colour cycle (`camcal.core.passplan`)."""

    pass_duration_s: float = Field(description="one pass in steady state, the waits for colours included")
    busy_share: float = Field(description="share of a pass the camera exposes or reads out")
    turns_per_pass: dict[str, float] = Field(
        description="per wavelength (nm), the LEM's turns of that colour one pass takes shots in"
    )
    lem_dwell_s: float | None = Field(description="the LEM's time on one colour; null: not known")
    warnings: list[str] = Field(description="what to know before sending; the module can run it")


class PresetPublic(Open, PassEstimate):
    """A named schedule (its fields as `camcal.core.schedule.Schedule`) with its size and duration."""

    n_frames: int


class Problem(BaseModel):
    field: str
    reason: str


class CameraLimitsPublic(BaseModel):
    """The ranges a schedule was checked against, and whose they are."""

    exposure_range_s: tuple[float, float]
    gain_range_db: tuple[float, float]
    gain_step_db: float
    source: str = Field(description="the module's camera as it said, or the ship's default limits")


class Preview(PassEstimate):
    ok: bool
    problems: list[Problem]
    camera_limits: CameraLimitsPublic
    n_frames: int
    predictions: dict[str, list[dict[str, Any]]] = Field(description="per module, per setting")
    summary: dict[str, dict[str, int]]


class Health(Open):
    """Per-module link state and the ingest's heartbeat (its queues, counters, refusals)."""

    status: str = Field(
        description="ok, or degraded without a recent heartbeat from every ingest or when the database "
        "cannot be used"
    )
    server: dict[str, Any]
    database: dict[str, Any] = Field(description="``ok``, and ``error``: what to do when it cannot be used")
    ingest: dict[str, Any]
    modules: dict[str, dict[str, Any]] = Field(
        description="per module: link, ages, frame rates, schedule, outbox and device counts, "
        "clock_offset_s (its clock minus the ship's, from its heartbeats; null before two), boot, "
        "distance_m, phase"
    )


class LiveSnapshot(Open):
    """What the live view shows: the dive, each module, λ_att, the alarms (``GET /api/live/snapshot``)."""

    server_time_unix_s: float
    dive: DivePublic | None
    run_id: int | None
    ingest: dict[str, Any]
    modules: dict[str, dict[str, Any]]
    attenuation: dict[str, list[AttenuationPointPublic]]
    alarms: list[AlarmPublic]
    last_event_id: int


class EventPublic(BaseModel):
    """One stored event (`camcal.core.events.Event`; its payload per kind in docs/protocol.md)."""

    id: int | None
    kind: EventKind
    t: float
    module: str | None
    dive_id: int | None
    payload: Stored


class EventPage(BaseModel):
    items: list[EventPublic]
    last_id: int = Field(description="ask again with after=last_id for what follows")
