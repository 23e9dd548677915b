"""camcal's configuration: one typed, documented place.

Values come from, in order of precedence: command-line options, ``CAMCAL_``
environment variables (nested fields with ``__``, e.g.
``CAMCAL_ALARMS__TILT_MAJOR_DEG=8``), a TOML file named by ``CAMCAL_CONFIG``
(or ``--config``), then the defaults below. ``camcal config show`` prints the
effective configuration with secrets masked. Every field is documented in
``docs/configuration.md`` (a test checks it).
"""

from __future__ import annotations

import ipaddress
import os
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, SecretStr, field_validator
from pydantic_settings import (
    BaseSettings,
    PydanticBaseSettingsSource,
    SettingsConfigDict,
    TomlConfigSettingsSource,
)

from camcal.core.frameset import CameraSetup, RatioSetup, SeriesSetup, Setup


class AlarmSettings(BaseModel):
    """Limits of the alarm rules (`ingest.alarms.AlarmLimits`)."""

    model_config = ConfigDict(extra="forbid")
    link_timeout_s: float = Field(5.0, gt=0, description="no packet for this long: link lost (MAJOR)")
    tilt_minor_deg: float = Field(3.0, gt=0, description="tilt from vertical raising a MINOR alarm")
    tilt_major_deg: float = Field(6.0, gt=0, description="tilt from vertical raising a MAJOR alarm")
    humidity_minor_pct: float = Field(
        50.0, ge=0, le=100, description="housing humidity raising a MINOR alarm"
    )
    humidity_major_pct: float = Field(
        70.0, ge=0, le=100, description="housing humidity raising a MAJOR alarm"
    )
    humidity_rise_pct_per_min: float = Field(
        0.5, gt=0, description="humidity rise rate that means a leak (MAJOR)"
    )
    edge_margin_fraction: float = Field(
        0.08, ge=0, le=0.5, description="LEM this close to the frame edge: leaving the view"
    )
    reject_fraction: float = Field(
        0.8,
        gt=0,
        le=1,
        description="a wavelength with no usable frame among a module's last 60: the share of them "
        "saturated (or too dark) that raises the alarm",
    )
    gap_age_s: float = Field(30.0, ge=0, description="a sequence gap open this long raises an alarm")
    disk_min_free_gb: float = Field(
        5.0, ge=0, description="free disk below this in the data folder: MAJOR alarm"
    )
    no_frame_grace_s: float = Field(
        120.0,
        gt=0,
        description="a running module that takes pictures where it is and sends no frame for this long "
        "beyond the wait it names (the LEM's colour, the pause between passes): MAJOR alarm",
    )


class ModuleSetting(BaseModel):
    """A module the ship expects and its LEM distance."""

    model_config = ConfigDict(extra="forbid")
    id: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")
    distance_m: float = Field(gt=0)
    distance_err_m: float = Field(0.0, ge=0)


def _trex_modules() -> list[ModuleSetting]:
    return [
        ModuleSetting(id="A", distance_m=21.56, distance_err_m=0.02),
        ModuleSetting(id="B", distance_m=41.62, distance_err_m=0.04),
    ]


def _trex_ratios() -> dict[int, RatioSetup]:
    return dict(Setup().emission_ratio)


class Settings(BaseSettings):
    """Everything a camcal deployment can set."""

    model_config = SettingsConfigDict(
        env_prefix="CAMCAL_", env_nested_delimiter="__", extra="forbid", env_ignore_empty=True
    )

    data_dir: Path = Field(Path("camcal-data"), description="folder of the database (SQLite) and frame files")
    database_url: str | None = Field(None, description="SQLAlchemy URL; default SQLite in data_dir")
    ingest_bind: str = Field("tcp://*:5555", description="where modules connect (ZeroMQ ROUTER)")
    keys_dir: Path | None = Field(
        None, description="the module link's CURVE keys (`camcal keys create`); default <data_dir>/keys"
    )
    link_plaintext: bool = Field(
        False, description="module link without keys or encryption: a lab bench only (doctor warns)"
    )
    events_bind: str = Field("tcp://127.0.0.1:5556", description="the ingest's event publisher (bind)")
    dive: str | None = Field(
        None,
        min_length=1,
        max_length=120,
        description="the dive's name: the ingest records into it; a module refuses an ingest of another",
    )
    events_connect: str = Field(
        "tcp://127.0.0.1:5556",
        description="where the server subscribes to events (several ingests: comma-separated)",
    )
    events_curve: bool | None = Field(
        None,
        description="CURVE on the events port: unset, beyond loopback only; true: whatever the address "
        "(a subscriber reaching an ingest bound to tcp://*:PORT through 127.0.0.1)",
    )
    http_host: str = Field("127.0.0.1", description="dashboard address (0.0.0.0 for the ship's network)")
    http_port: int = Field(8000, ge=1, le=65535, description="dashboard port")
    http_tls_cert: Path | None = Field(None, description="TLS certificate (PEM) for the dashboard: HTTPS")
    http_tls_key: Path | None = Field(None, description="the TLS certificate's private key (PEM)")
    http_max_body_mb: float = Field(
        1.0, gt=0, le=1024, description="largest request body the API reads (MiB); larger: 413"
    )
    http_max_connections_per_client: int = Field(
        16, ge=1, le=10000, description="WebSocket connections one client address may hold at once"
    )
    http_trusted_proxies: list[str] = Field(
        default_factory=list,
        description="reverse proxies (IP addresses or networks) whose X-Forwarded-For names the client; "
        "none: the client is the connection's peer, whatever its headers say",
    )
    operator_tokens_file: Path | None = Field(
        None, description="a file of operator tokens (JSON name -> token, or NAME=TOKEN lines)"
    )
    modules: list[ModuleSetting] = Field(
        default_factory=_trex_modules, description="modules and LEM distances"
    )
    emission_ratio: dict[int, RatioSetup] = Field(
        default_factory=_trex_ratios, description="I0'/I0 per wavelength"
    )
    linear_range: tuple[float, float] = Field((5.0, 240.0), description="linear gray range of the cameras")
    calibration: str | None = Field(None, description="calibration record NAME[@VERSION] the ingest uses")
    operator_tokens: dict[str, SecretStr] = Field(default_factory=dict, description="operator name -> token")
    workers: int = Field(0, ge=0, le=256, description="analysis processes (0: one per core)")
    window: int = Field(8, ge=1, le=1024, description="credit: unacknowledged messages per module")
    max_payload_mb: float = Field(
        32.0, gt=0, le=1024, description="largest frame or sensor payload a module may send (MiB)"
    )
    module_queue_mb: float = Field(
        64.0,
        gt=0,
        le=65536,
        description="data of one module the ingest holds not yet stored (MiB); more is refused busy",
    )
    fsync: bool = Field(True, description="fsync frame files before acknowledging them")
    sqlite_synchronous: str = Field(
        "FULL", pattern="^(OFF|NORMAL|FULL|EXTRA)$", description="SQLite durability"
    )
    visit_gap_s: float = Field(
        30.0, gt=0, le=86400, description="a gap in the frames that ends a LEM visit of the λ_att series [s]"
    )
    visit_max_s: float = Field(600.0, gt=0, le=86400, description="longest LEM visit of the λ_att series [s]")
    station_depth_m: float | None = Field(
        None,
        gt=0,
        description="the dive plan's station depth: a stop within 50 m of it shows as the station, "
        "others as stops (unset: a stop near the deepest depth so far)",
    )
    deck_depth_m: float = Field(
        10.0,
        gt=0,
        le=1000,
        description="a module shallower than this is on deck: a dive whose modules all came back there "
        "and signed off (or sent no frame for dive_quiet_s) has ended [m]",
    )
    dive_quiet_s: float = Field(
        1800.0,
        gt=0,
        le=30 * 86400,
        description="every module back on deck and no frame received for this long: the dive has ended, "
        "and the next start begins a new one [s]",
    )
    retention_days: float | None = Field(
        None, gt=0, description="delete frame files older than this (None: keep)"
    )
    log_format: str = Field("text", pattern="^(text|json)$", description="log lines as text or JSON")
    log_level: str = Field("info", pattern="^(debug|info|warning|error)$", description="log level")
    alarms: AlarmSettings = Field(default_factory=AlarmSettings, description="alarm limits")

    @field_validator("linear_range")
    @classmethod
    def _range(cls, v: tuple[float, float]) -> tuple[float, float]:
        if not 0 <= v[0] < v[1] <= 255:
            raise ValueError("must satisfy 0 <= low < high <= 255")
        return v

    @field_validator("http_trusted_proxies")
    @classmethod
    def _proxies(cls, v: list[str]) -> list[str]:
        for entry in v:
            try:
                ipaddress.ip_network(entry.strip(), strict=False)
            except ValueError:
                raise ValueError(
                    f"{entry!r} is not an IP address or network (e.g. 10.0.0.5, 10.0.0.0/24)"
                ) from None
        return v

    @classmethod
    def settings_customise_sources(
        cls,
        settings_cls: type[BaseSettings],
        init_settings: PydanticBaseSettingsSource,
        env_settings: PydanticBaseSettingsSource,
        dotenv_settings: PydanticBaseSettingsSource,
        file_secret_settings: PydanticBaseSettingsSource,
    ) -> tuple[PydanticBaseSettingsSource, ...]:
        sources: list[PydanticBaseSettingsSource] = [init_settings, env_settings]
        path = os.environ.get("CAMCAL_CONFIG")
        if path:
            sources.append(TomlConfigSettingsSource(settings_cls, toml_file=Path(path)))
        return tuple(sources)

    def setup(self) -> Setup:
        """The calibration inputs as a frame-set `Setup` (distances, ratios, linear range)."""
        return Setup(
            cameras={
                m.id: CameraSetup(distance_m=m.distance_m, distance_err_m=m.distance_err_m)
                for m in self.modules
            },
            emission_ratio=self.emission_ratio,
            linear_range=self.linear_range,
            series=SeriesSetup(visit_gap_s=self.visit_gap_s, visit_max_s=self.visit_max_s),
        )

    def tokens(self) -> dict[str, str]:
        """The operator tokens: ``operator_tokens`` and those of ``operator_tokens_file``."""
        out = {name: tok.get_secret_value() for name, tok in self.operator_tokens.items()}
        if self.operator_tokens_file is not None:
            out.update(read_tokens_file(self.operator_tokens_file))
        return out

    def keys_path(self) -> Path:
        """The module link's keys folder."""
        return self.keys_dir or self.data_dir / "keys"

    def masked(self) -> dict[str, Any]:
        """The effective configuration with secrets (tokens, database passwords) masked."""
        data = self.model_dump(mode="json")
        data["operator_tokens"] = {k: "********" for k in self.operator_tokens}
        url = data.get("database_url")
        if url and "@" in url and "://" in url:
            scheme, rest = url.split("://", 1)
            creds, host = rest.rsplit("@", 1)
            user = creds.split(":", 1)[0]
            data["database_url"] = f"{scheme}://{user}:********@{host}"
        return data


def load_settings(config: Path | None = None, **overrides: Any) -> Settings:
    """Settings from the environment (and ``config`` TOML if given); ``overrides`` win."""
    if config is not None:
        os.environ["CAMCAL_CONFIG"] = str(config)
    return Settings(**{k: v for k, v in overrides.items() if v is not None})


def read_tokens_file(path: Path) -> dict[str, str]:
    """Operator tokens from a file: a JSON object (name -> token) or ``NAME=TOKEN`` lines (``#`` comments)."""
    import json

    try:
        text = Path(path).read_text()
    except OSError as exc:
        raise ValueError(f"operator_tokens_file {path}: {exc.strerror or exc}") from None
    if text.lstrip().startswith("{"):
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ValueError(f"operator_tokens_file {path}: not JSON: {exc.msg}") from None
        if not isinstance(data, dict) or not all(isinstance(v, str) for v in data.values()):
            raise ValueError(f"operator_tokens_file {path}: expected an object of name -> token")
        return {str(k): v for k, v in data.items()}
    out = {}
    for n, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        name, sep, token = line.partition("=")
        if not sep or not name.strip() or not token.strip():
            raise ValueError(f"operator_tokens_file {path}, line {n}: expected NAME=TOKEN")
        out[name.strip()] = token.strip()
    return out


def endpoint_list(text: str | None) -> list[str]:
    """ZeroMQ endpoints from a setting that may name several, comma-separated (``events_connect``)."""
    return [e.strip() for e in (text or "").split(",") if e.strip()]


def field_names(model: type[BaseModel], prefix: str = "") -> list[str]:
    """Every setting's dotted name, nested models included (for the documentation check)."""
    names = []
    for name, info in model.model_fields.items():
        full = f"{prefix}{name}"
        names.append(full)
        ann = info.annotation
        if isinstance(ann, type) and issubclass(ann, BaseModel) and ann is not ModuleSetting:
            names += field_names(ann, f"{full}.")
    return names
