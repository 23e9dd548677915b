"""The tables of camcal's store (SQLAlchemy 2 declarative models).

Times of measurements are UTC seconds since the epoch (``*_unix_s``, float):
they sort, bucket and downsample the same way in SQLite and PostgreSQL.
Schema changes go through Alembic (``storage/migrations``).
"""

from __future__ import annotations

from typing import Any, ClassVar

from sqlalchemy import (
    JSON,
    BigInteger,
    Boolean,
    Float,
    ForeignKey,
    Index,
    Integer,
    String,
    Text,
    UniqueConstraint,
    text,
)
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column

from camcal.core.wire.sensors import SENSOR_SPEC

#: Integer primary keys that autoincrement on SQLite (INTEGER) and PostgreSQL (BIGINT).
BigId = BigInteger().with_variant(Integer(), "sqlite")


class Base(DeclarativeBase):
    type_annotation_map: ClassVar[dict[Any, Any]] = {dict[str, Any]: JSON, list[Any]: JSON}


class Dive(Base):
    """A deployment: everything between putting the modules in the water and recovering them."""

    __tablename__ = "dives"
    id: Mapped[int] = mapped_column(BigId, primary_key=True, autoincrement=True)
    name: Mapped[str] = mapped_column(String(120), unique=True)
    started_unix_s: Mapped[float] = mapped_column(Float)
    ended_unix_s: Mapped[float | None] = mapped_column(Float)
    #: Why it ended (an operator, the modules back on deck...; `storage.queries.divestate`).
    end_reason: Mapped[str | None] = mapped_column(String(300))
    notes: Mapped[str] = mapped_column(Text, default="")
    calibration_id: Mapped[int | None] = mapped_column(ForeignKey("calibrations.id"))
    setup: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)


class Module(Base):
    """A light receiver module as the ship last heard of it."""

    __tablename__ = "modules"
    id: Mapped[str] = mapped_column(String(64), primary_key=True)
    distance_m: Mapped[float | None] = mapped_column(Float)
    distance_err_m: Mapped[float | None] = mapped_column(Float)
    first_seen_unix_s: Mapped[float] = mapped_column(Float)
    last_seen_unix_s: Mapped[float] = mapped_column(Float)
    boot: Mapped[str] = mapped_column(String(64), default="")
    software: Mapped[str] = mapped_column(String(120), default="")
    schedule_name: Mapped[str] = mapped_column(String(80), default="")
    schedule_version: Mapped[int] = mapped_column(Integer, default=0)
    schedule_state: Mapped[str] = mapped_column(String(16), default="idle")
    #: What the module's camera is and can take, as its hello and heartbeats say (JSON of
    #: `camcal.core.wire.CameraInfo`; None: the module never said, the ship's limits apply).
    camera_json: Mapped[str | None] = mapped_column(Text)


class Frame(Base):
    """One stored frame. (module, boot, seq) identifies it: a resent frame is a no-op."""

    __tablename__ = "frames"
    __table_args__ = (
        UniqueConstraint("module_id", "boot", "seq", name="uq_frames_module_boot_seq"),
        Index("ix_frames_dive_time", "dive_id", "captured_unix_s"),
        Index("ix_frames_dive_ship_time", "dive_id", "captured_ship_unix_s"),
        Index("ix_frames_dive_setting", "dive_id", "module_id", "wavelength_nm", "exposure_s", "gain_db"),
    )
    id: Mapped[int] = mapped_column(BigId, primary_key=True, autoincrement=True)
    dive_id: Mapped[int] = mapped_column(ForeignKey("dives.id"))
    module_id: Mapped[str] = mapped_column(ForeignKey("modules.id"))
    boot: Mapped[str] = mapped_column(String(64))
    seq: Mapped[int] = mapped_column(BigInteger)
    captured_unix_s: Mapped[float] = mapped_column(Float)
    received_unix_s: Mapped[float] = mapped_column(Float)
    #: The capture time on the ship's clock (the module's mapped onto it, `camcal.core.clockmap`): the
    #: dive's one axis. Where no mapping is known (an import, a frame stored before migration 0010)
    #: the capture time stands for it.
    captured_ship_unix_s: Mapped[float | None] = mapped_column(Float)
    wavelength_nm: Mapped[int] = mapped_column(Integer)
    exposure_s: Mapped[float] = mapped_column(Float)
    gain_db: Mapped[float] = mapped_column(Float)
    depth_m: Mapped[float | None] = mapped_column(Float)
    width_px: Mapped[int] = mapped_column(Integer)
    height_px: Mapped[int] = mapped_column(Integer)
    path: Mapped[str] = mapped_column(String(400))
    size_bytes: Mapped[int] = mapped_column(BigInteger)
    sha256: Mapped[str] = mapped_column(String(64))
    #: `camcal.core.wire.content_sha256` of the message (None: imported, or before migration 0009):
    #: a resend with another header is a conflict, not a resend.
    content_sha256: Mapped[str | None] = mapped_column(String(64))
    schedule_version: Mapped[int] = mapped_column(Integer, default=0)
    source: Mapped[str] = mapped_column(String(16), default="live")


class AnalysisRun(Base):
    """One analysis of a dive's frames with one set of calibration inputs.

    A dive has at most one ``live`` run (a partial unique index), shared by
    every ingest process recording into it.
    """

    __tablename__ = "analysis_runs"
    __table_args__ = (
        Index(
            "uq_analysis_runs_live",
            "dive_id",
            unique=True,
            sqlite_where=text("kind = 'live'"),
            postgresql_where=text("kind = 'live'"),
        ),
    )
    id: Mapped[int] = mapped_column(BigId, primary_key=True, autoincrement=True)
    dive_id: Mapped[int] = mapped_column(ForeignKey("dives.id"))
    kind: Mapped[str] = mapped_column(String(16))  # live | reanalysis
    label: Mapped[str] = mapped_column(String(200), default="")
    calibration: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
    calibration_id: Mapped[int | None] = mapped_column(ForeignKey("calibrations.id"))
    software_version: Mapped[str] = mapped_column(String(40), default="")
    created_unix_s: Mapped[float] = mapped_column(Float)
    status: Mapped[str] = mapped_column(String(16), default="running")
    n_frames: Mapped[int] = mapped_column(Integer, default=0)
    # When the process that runs (or queues) a re-analysis last said it still does, and which
    # process that is (`camcal.core.owner`; see `storage.queries.runs.RUN_STALE_S`). None: live runs.
    heartbeat_unix_s: Mapped[float | None] = mapped_column(Float)
    owner: Mapped[str | None] = mapped_column(String(200))


class FrameResult(Base):
    """The I_center analysis of one frame in one run."""

    __tablename__ = "frame_results"
    __table_args__ = (
        UniqueConstraint("frame_id", "run_id", name="uq_results_frame_run"),
        Index("ix_results_run_status", "run_id", "status"),
    )
    id: Mapped[int] = mapped_column(BigId, primary_key=True, autoincrement=True)
    frame_id: Mapped[int] = mapped_column(ForeignKey("frames.id"))
    run_id: Mapped[int] = mapped_column(ForeignKey("analysis_runs.id"))
    status: Mapped[str] = mapped_column(String(16))
    reason: Mapped[str | None] = mapped_column(String(32))
    detail: Mapped[str | None] = mapped_column(Text)
    centroid_x_px: Mapped[float | None] = mapped_column(Float)
    centroid_y_px: Mapped[float | None] = mapped_column(Float)
    radius_px: Mapped[float | None] = mapped_column(Float)
    elongation: Mapped[float | None] = mapped_column(Float)
    center_gray: Mapped[float | None] = mapped_column(Float)
    center_err_gray: Mapped[float | None] = mapped_column(Float)
    background_gray: Mapped[float | None] = mapped_column(Float)
    background_err_gray: Mapped[float | None] = mapped_column(Float)
    i_center_gray: Mapped[float | None] = mapped_column(Float)
    i_center_err_gray: Mapped[float | None] = mapped_column(Float)
    fit: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    profile: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    analysed_unix_s: Mapped[float] = mapped_column(Float)


class AttenuationPoint(Base):
    """One point of the λ_att series of a wavelength: one LEM visit (`ingest.rolling`).

    ``t_unix_s`` and ``depth_m`` are the mean capture time and mean LEM depth
    of the frames used (``n_frames``, between ``t_first_unix_s`` and
    ``t_last_unix_s``); ``final`` is false while frames may still join the
    visit. ``visit_key`` names the visit within its run (points of runs made
    before visits existed have none). ``window_s`` is the visit's span.
    """

    __tablename__ = "attenuation_points"
    __table_args__ = (
        Index("ix_att_run_wl_time", "run_id", "wavelength_nm", "t_unix_s"),
        Index("ux_att_run_visit", "run_id", "visit_key", unique=True),
    )
    id: Mapped[int] = mapped_column(BigId, primary_key=True, autoincrement=True)
    run_id: Mapped[int] = mapped_column(ForeignKey("analysis_runs.id"))
    dive_id: Mapped[int] = mapped_column(ForeignKey("dives.id"))
    wavelength_nm: Mapped[int] = mapped_column(Integer)
    t_unix_s: Mapped[float] = mapped_column(Float)
    #: ``t_unix_s`` on the ship's clock (from its frames' mapped times; None: not known).
    t_ship_unix_s: Mapped[float | None] = mapped_column(Float)
    depth_m: Mapped[float | None] = mapped_column(Float)
    lambda_att_m: Mapped[float | None] = mapped_column(Float)
    stat_err_m: Mapped[float | None] = mapped_column(Float)
    sys_err_m: Mapped[float | None] = mapped_column(Float)
    n_pairs: Mapped[int] = mapped_column(Integer)
    chi2_ndof: Mapped[float | None] = mapped_column(Float)
    window_s: Mapped[float] = mapped_column(Float)
    details: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
    visit_key: Mapped[str | None] = mapped_column(String(80))
    t_first_unix_s: Mapped[float | None] = mapped_column(Float)
    t_last_unix_s: Mapped[float | None] = mapped_column(Float)
    n_frames: Mapped[int | None] = mapped_column(Integer)
    final: Mapped[bool] = mapped_column(Boolean, default=True, server_default=text("true"))


class ChiSquareFitRecord(Base):
    """A χ² fit of λ_abs and λ_sca over a span of a dive (``camcal fit --dive``).

    ``result`` is the fit's JSON document (per wavelength: the lengths, their
    errors, the I_center check, the Δχ² map and the fitted profiles; the
    inputs and the software version); ``span`` the frames it used.
    """

    __tablename__ = "chisq_fits"
    __table_args__ = (Index("ix_chisq_fits_dive", "dive_id", "id"),)
    id: Mapped[int] = mapped_column(BigId, primary_key=True, autoincrement=True)
    dive_id: Mapped[int] = mapped_column(ForeignKey("dives.id"))
    run_id: Mapped[int | None] = mapped_column(ForeignKey("analysis_runs.id"))
    calibration_id: Mapped[int | None] = mapped_column(ForeignKey("calibrations.id"))
    created_unix_s: Mapped[float] = mapped_column(Float)
    software_version: Mapped[str] = mapped_column(String(40), default="")
    label: Mapped[str] = mapped_column(String(200), default="")
    span: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
    result: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)


class ModuleClockRecord(Base):
    """A module's clock during one boot, mapped onto the ship's (`camcal.core.clockmap`): its rate
    and anchor from its handshake, the newest offset measured at its heartbeats, and when those
    arrived. Its frames, samples and λ_att points carry both times; this says how they relate."""

    __tablename__ = "module_clocks"
    __table_args__ = (UniqueConstraint("module_id", "boot", name="uq_module_clocks"),)
    id: Mapped[int] = mapped_column(BigId, primary_key=True, autoincrement=True)
    dive_id: Mapped[int | None] = mapped_column(ForeignKey("dives.id"))
    module_id: Mapped[str] = mapped_column(String(64))
    boot: Mapped[str] = mapped_column(String(64))
    rate: Mapped[float] = mapped_column(Float, default=1.0)
    module_at_unix_s: Mapped[float] = mapped_column(Float, default=0.0)
    real_at_unix_s: Mapped[float] = mapped_column(Float, default=0.0)
    offset_s: Mapped[float | None] = mapped_column(Float)
    n_readings: Mapped[int] = mapped_column(Integer, default=0)
    #: When (the ship's clock) the boot's first reading and its newest arrived.
    first_unix_s: Mapped[float] = mapped_column(Float)
    updated_unix_s: Mapped[float] = mapped_column(Float)


class SensorBatch(Base):
    """A received ``sensors`` message (for de-duplication of resends)."""

    __tablename__ = "sensor_batches"
    __table_args__ = (UniqueConstraint("module_id", "boot", "seq", name="uq_sensor_batches"),)
    id: Mapped[int] = mapped_column(BigId, primary_key=True, autoincrement=True)
    module_id: Mapped[str] = mapped_column(ForeignKey("modules.id"))
    boot: Mapped[str] = mapped_column(String(64))
    seq: Mapped[int] = mapped_column(BigInteger)
    count: Mapped[int] = mapped_column(Integer)
    received_unix_s: Mapped[float] = mapped_column(Float)
    sha256: Mapped[str | None] = mapped_column(String(64))  # of the payload; None before migration 0004
    content_sha256: Mapped[str | None] = mapped_column(String(64))  # as `Frame.content_sha256`
    #: False while a large batch is stored a part per turn (`storage.store.Store.commit_batch`): not
    #: acknowledged yet; a batch a crash left incomplete is removed at the next start and resent.
    complete: Mapped[bool] = mapped_column(Boolean, default=True, server_default=text("true"))


class SensorSample(Base):
    """Housing temperature and humidity, accelerometer, gyroscope and depth of a module."""

    __tablename__ = "sensor_samples"
    __table_args__ = (Index("ix_sensors_module_time", "module_id", "t_unix_s"),)
    id: Mapped[int] = mapped_column(BigId, primary_key=True, autoincrement=True)
    module_id: Mapped[str] = mapped_column(ForeignKey("modules.id"))
    dive_id: Mapped[int | None] = mapped_column(ForeignKey("dives.id"))
    t_unix_s: Mapped[float] = mapped_column(Float)
    t_ship_unix_s: Mapped[float | None] = mapped_column(Float)  # on the ship's clock (None: not known)
    #: The `SensorBatch` (row id) the sample came in (None before migration 0007).
    batch_id: Mapped[int | None] = mapped_column(BigInteger, index=True)
    # One nullable column per sensor of the wire's definition (`camcal.core.wire.sensors.SENSOR_SPEC`):
    # temperature_c, humidity_pct, acc_{x,y,z}_m_s2, gyro_{x,y,z}_dps, depth_m.
    locals().update(
        {c.name: mapped_column(Float, nullable=True) for c in SENSOR_SPEC if c.name != "t_unix_s"}
    )


class AttitudeSample(Base):
    """Attitude derived from the sensors: tilt, rotation rate, heave period."""

    __tablename__ = "attitude_samples"
    __table_args__ = (Index("ix_attitude_module_time", "module_id", "t_unix_s"),)
    id: Mapped[int] = mapped_column(BigId, primary_key=True, autoincrement=True)
    module_id: Mapped[str] = mapped_column(ForeignKey("modules.id"))
    dive_id: Mapped[int | None] = mapped_column(ForeignKey("dives.id"))
    t_unix_s: Mapped[float] = mapped_column(Float)
    t_ship_unix_s: Mapped[float | None] = mapped_column(Float)  # on the ship's clock (None: not known)
    tilt_deg: Mapped[float] = mapped_column(Float)
    tilt_x_deg: Mapped[float] = mapped_column(Float)
    tilt_y_deg: Mapped[float] = mapped_column(Float)
    rotation_rate_dps: Mapped[float] = mapped_column(Float)
    heave_period_s: Mapped[float | None] = mapped_column(Float)
    heave_amplitude_m_s2: Mapped[float | None] = mapped_column(Float)


class LinearityCheck(Base):
    """The latest linearity fit of a module at one wavelength (per run and sweep)."""

    __tablename__ = "linearity_checks"
    __table_args__ = (UniqueConstraint("run_id", "module_id", "wavelength_nm", "sweep", name="uq_linearity"),)
    id: Mapped[int] = mapped_column(BigId, primary_key=True, autoincrement=True)
    run_id: Mapped[int] = mapped_column(ForeignKey("analysis_runs.id"))
    module_id: Mapped[str] = mapped_column(ForeignKey("modules.id"))
    wavelength_nm: Mapped[int] = mapped_column(Integer)
    sweep: Mapped[str] = mapped_column(String(16))  # exposure | gain
    fixed_value: Mapped[float | None] = mapped_column(Float)
    slope: Mapped[float] = mapped_column(Float)
    slope_err: Mapped[float | None] = mapped_column(Float)
    intercept_gray: Mapped[float] = mapped_column(Float)
    r2: Mapped[float] = mapped_column(Float)
    n_used: Mapped[int] = mapped_column(Integer)
    linear_max_gray: Mapped[float] = mapped_column(Float)
    knee_x: Mapped[float | None] = mapped_column(Float)
    points: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
    updated_unix_s: Mapped[float] = mapped_column(Float)


class Event(Base):
    """The persistent event log; its id is the event sequence number subscribers see."""

    __tablename__ = "events"
    __table_args__ = (Index("ix_events_kind", "kind", "id"),)
    id: Mapped[int] = mapped_column(BigId, primary_key=True, autoincrement=True)
    t_unix_s: Mapped[float] = mapped_column(Float)
    kind: Mapped[str] = mapped_column(String(32))
    module_id: Mapped[str | None] = mapped_column(String(64))
    dive_id: Mapped[int | None] = mapped_column(Integer)
    payload: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)


class Alarm(Base):
    """A condition someone on deck must see; ``key`` identifies it while it is active."""

    __tablename__ = "alarms"
    __table_args__ = (Index("ix_alarms_active", "active", "key"),)
    id: Mapped[int] = mapped_column(BigId, primary_key=True, autoincrement=True)
    key: Mapped[str] = mapped_column(String(120))
    kind: Mapped[str] = mapped_column(String(40))
    module_id: Mapped[str | None] = mapped_column(String(64))
    severity: Mapped[str] = mapped_column(String(8))  # MINOR | MAJOR | INVALID
    message: Mapped[str] = mapped_column(Text)
    raised_unix_s: Mapped[float] = mapped_column(Float)
    cleared_unix_s: Mapped[float | None] = mapped_column(Float)
    acked_unix_s: Mapped[float | None] = mapped_column(Float)
    acked_by: Mapped[str | None] = mapped_column(String(120))
    active: Mapped[bool] = mapped_column(Boolean, default=True)
    details: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)


class Gap(Base):
    """Sequence numbers of a module that never arrived (yet)."""

    __tablename__ = "gaps"
    id: Mapped[int] = mapped_column(BigId, primary_key=True, autoincrement=True)
    module_id: Mapped[str] = mapped_column(String(64))
    boot: Mapped[str] = mapped_column(String(64))
    first_seq: Mapped[int] = mapped_column(BigInteger)
    last_seq: Mapped[int] = mapped_column(BigInteger)
    detected_unix_s: Mapped[float] = mapped_column(Float)
    filled_unix_s: Mapped[float | None] = mapped_column(Float)


class CommandRecord(Base):
    """An operator command to a module and where it stands."""

    __tablename__ = "commands"
    id: Mapped[str] = mapped_column(String(64), primary_key=True)
    module_id: Mapped[str] = mapped_column(String(64))
    action: Mapped[str] = mapped_column(String(32))
    target_version: Mapped[int] = mapped_column(Integer, default=0)
    payload: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
    apply: Mapped[str] = mapped_column(String(20), default="now")
    issued_by: Mapped[str] = mapped_column(String(120))
    issued_unix_s: Mapped[float] = mapped_column(Float)
    state: Mapped[str] = mapped_column(String(16), default="pending")
    reason: Mapped[str | None] = mapped_column(Text)
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    updated_unix_s: Mapped[float] = mapped_column(Float)


class AuditEntry(Base):
    """Append-only record of commands, acknowledgements and calibration changes."""

    __tablename__ = "audit_log"
    id: Mapped[int] = mapped_column(BigId, primary_key=True, autoincrement=True)
    t_unix_s: Mapped[float] = mapped_column(Float)
    actor: Mapped[str] = mapped_column(String(120))
    action: Mapped[str] = mapped_column(String(60))
    target: Mapped[str] = mapped_column(String(200), default="")
    details: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)


class Calibration(Base):
    """A versioned set of calibration inputs (distances, emission ratios, linear range, PSF)."""

    __tablename__ = "calibrations"
    __table_args__ = (UniqueConstraint("name", "version", name="uq_calibration_version"),)
    id: Mapped[int] = mapped_column(BigId, primary_key=True, autoincrement=True)
    name: Mapped[str] = mapped_column(String(120))
    version: Mapped[int] = mapped_column(Integer)
    source: Mapped[str] = mapped_column(Text, default="")
    valid_from_unix_s: Mapped[float | None] = mapped_column(Float)
    valid_to_unix_s: Mapped[float | None] = mapped_column(Float)
    values: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
    created_unix_s: Mapped[float] = mapped_column(Float)


class IngestCounter(Base):
    """An ingest's counters (messages received, stored, refused by reason...), kept across restarts."""

    __tablename__ = "ingest_counters"
    ingest_id: Mapped[str] = mapped_column(String(200), primary_key=True)
    name: Mapped[str] = mapped_column(String(120), primary_key=True)
    value: Mapped[int] = mapped_column(BigInteger, default=0)
    updated_unix_s: Mapped[float] = mapped_column(Float)
