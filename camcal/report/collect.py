"""Everything a dive report shows, read from the store (through `storage.queries` and `Store`)."""

from __future__ import annotations

import platform
import sys
import time
from dataclasses import dataclass, field
from importlib import metadata
from typing import Any

from camcal.core import __version__
from camcal.core.frameset import Setup
from camcal.divefit import DiveLookupError, pick_run, run_calibration
from ingest.spans import Span, attenuation_over_span, table_rows
from storage import queries
from storage.store import Store

#: Points per time series in the report's figures (the store averages longer series into buckets).
MAX_POINTS = 1500


@dataclass(frozen=True)
class ReportData:
    """A dive's results as the report needs them; plain dicts and lists, as the queries return them.

    ``attenuation`` is the λ_att table over the station (the API's
    ``/api/dives/{id}/attenuation``), ``series`` the per-visit λ_att points per
    wavelength, ``fit`` the newest stored χ² fit (None: none kept yet).
    """

    dive: dict[str, Any]
    run: dict[str, Any]
    runs: list[dict[str, Any]]
    setup: Setup
    calibration: dict[str, Any] | None
    modules: list[dict[str, Any]]
    timeline: dict[str, Any]
    frames: list[dict[str, Any]] = field(repr=False)
    quality: dict[str, dict[str, int]]
    linearity: list[dict[str, Any]] = field(repr=False)
    sensors: dict[str, dict[str, Any]] = field(repr=False)
    attitude: dict[str, dict[str, Any]] = field(repr=False)
    series: dict[int, list[dict[str, Any]]] = field(repr=False)
    span: dict[str, Any]
    attenuation: list[dict[str, Any]]
    fit: dict[str, Any] | None = field(repr=False)
    data_dir: str
    software: dict[str, str]
    generated_unix_s: float


def software_versions() -> dict[str, str]:
    """camcal's version and those of the libraries the numbers depend on."""
    out = {"camcal": __version__, "python": sys.version.split()[0], "platform": platform.platform()}
    for dist in ("numpy", "scipy", "opencv-python-headless", "matplotlib", "sqlalchemy"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            continue
    return out


def collect(store: Store, dive_name: str, run_id: int | None = None) -> ReportData:
    """Read a dive's report from the store: its run (default the live one) and that run's inputs.

    Raises `DiveLookupError` for an unknown dive or run.
    """
    d = store.call(queries.dive_by_name, dive_name)
    if d is None:
        with store.read() as s:
            names = ", ".join(x["name"] for x in queries.dives(s)[:5]) or "none"
        raise DiveLookupError(f"no dive named {dive_name!r} (dives in the store: {names})")
    run = pick_run(store, d.id, run_id)
    setup, record = run_calibration(store, d.id, run)
    rows = store.call(queries.result_rows, run["id"], d.id)
    span, table = attenuation_over_span(rows, setup, Span())
    with store.read() as s:
        dive = queries.dive_record(s, d.id)
        assert dive is not None
        if record is None and dive.get("calibration_id"):
            record = store.call(queries.calibration, dive["calibration_id"])
        frames = queries.frame_outcomes(s, d.id, run["id"])
        module_ids = sorted({f["module"] for f in frames})
        series_kw = {"dive_id": d.id, "t_from": None, "t_to": None, "max_points": MAX_POINTS}
        sensors = {m: queries.sensor_series(s, module=m, **series_kw) for m in module_ids}
        attitude = {m: queries.attitude_series(s, module=m, **series_kw) for m in module_ids}
        fit = queries.latest_chisq_fit(s, d.id, run["id"]) or queries.latest_chisq_fit(s, d.id)
        return ReportData(
            dive=dive,
            run=run,
            runs=queries.runs(s, d.id),
            setup=setup,
            calibration=record,
            modules=[m for m in queries.modules(s) if m["id"] in module_ids],
            timeline=queries.timeline(s, d.id, MAX_POINTS),
            frames=frames,
            quality=queries.quality_counts(s, run["id"]),
            linearity=queries.linearity(s, run["id"]),
            sensors=sensors,
            attitude=attitude,
            series=queries.attenuation_series(s, run["id"]),
            span=span,
            attenuation=table_rows(table)["rows"],
            fit=fit,
            data_dir=str(store.files.root),
            software=software_versions(),
            generated_unix_s=time.time(),
        )
