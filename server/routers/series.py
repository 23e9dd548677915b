"""Time series: sensors, attitude, λ_att, linearity, events."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Query
from sqlalchemy.orm import Session

from server.deps import MAX_ID, FloatQuery, IdQuery, ModuleId, StoreDep, WavelengthQuery
from server.errors import NotFound
from server.schemas import AttenuationSeries, EventPage, LinearityPublic, ModulePublic, Series
from storage import queries

router = APIRouter(tags=["series"])
MaxPoints = Annotated[int, Query(ge=10, le=20000)]


def _dive(s: Session, dive: int | None) -> int | None:
    """The dive asked for (404 if there is none such), else the newest."""
    return queries.dive_and_run(s, dive, None)[0]


@router.get("/api/sensors", response_model=Series)
def sensors(
    store: StoreDep,
    module: Annotated[str, Query(max_length=64)],
    dive: IdQuery = None,
    t_from: FloatQuery = None,
    t_to: FloatQuery = None,
    max_points: MaxPoints = 1000,
) -> dict[str, Any]:
    """Housing temperature and humidity, accelerations, rotation rates and depth of a module.

    Long ranges are averaged in the database into at most ``max_points``
    buckets; ``downsampled`` says whether that happened.
    """

    def q(s: Session) -> dict[str, Any]:
        return queries.sensor_series(
            s, module=module, dive_id=_dive(s, dive), t_from=t_from, t_to=t_to, max_points=max_points
        )

    return {"module": module, **store.call(q)}


@router.get("/api/attitude", response_model=Series)
def attitude(
    store: StoreDep,
    module: Annotated[str, Query(max_length=64)],
    dive: IdQuery = None,
    t_from: FloatQuery = None,
    t_to: FloatQuery = None,
    max_points: MaxPoints = 1000,
) -> dict[str, Any]:
    """Tilt, rotation rate and heave period of a module, derived from its sensors."""

    def q(s: Session) -> dict[str, Any]:
        return queries.attitude_series(
            s, module=module, dive_id=_dive(s, dive), t_from=t_from, t_to=t_to, max_points=max_points
        )

    return {"module": module, **store.call(q)}


@router.get("/api/attenuation", response_model=AttenuationSeries)
def attenuation(
    store: StoreDep,
    dive: IdQuery = None,
    run: IdQuery = None,
    wavelength_nm: WavelengthQuery = None,
    t_from: FloatQuery = None,
) -> dict[str, Any]:
    """The λ_att series per wavelength: one point per LEM visit, with statistical and systematic errors
    and whether the visit is over (``final``)."""

    def q(s: Session) -> dict[str, Any]:
        dive_id, rid = queries.dive_and_run(s, dive, run)
        if dive_id is None:
            return {"dive_id": None, "run_id": None, "series": {}}
        if rid is None:
            return {"dive_id": dive_id, "run_id": None, "series": {}}
        series = queries.attenuation_series(s, rid, wavelength_nm, t_from)
        return {"dive_id": dive_id, "run_id": rid, "series": {str(k): v for k, v in series.items()}}

    return store.call(q)


@router.get("/api/linearity", response_model=LinearityPublic)
def linearity(
    store: StoreDep,
    dive: IdQuery = None,
    run: IdQuery = None,
    module: Annotated[str | None, Query(max_length=64)] = None,
) -> dict[str, Any]:
    """Linearity fits per module and wavelength: slope, R², saturation knee, the points."""

    def q(s: Session) -> dict[str, Any]:
        _, rid = queries.dive_and_run(s, dive, run)
        if rid is None:
            return {"run_id": None, "checks": []}
        return {"run_id": rid, "checks": queries.linearity(s, rid, module)}

    return store.call(q)


@router.get("/api/events", response_model=EventPage)
def events(
    store: StoreDep,
    after: Annotated[int, Query(ge=0, le=MAX_ID)] = 0,
    limit: Annotated[int, Query(ge=1, le=5000)] = 500,
) -> dict[str, Any]:
    """Stored events after an id: how a client catches up on what it missed."""

    items = store.call(queries.events_after, after, limit)
    return {"items": [e.as_dict() for e in items], "last_id": items[-1].id if items else after}


@router.get("/api/modules", response_model=list[ModulePublic])
def modules(store: StoreDep) -> list[dict[str, Any]]:
    """Every module the ship has heard of: distance, last seen, boot, software, schedule."""
    return store.call(queries.modules)


@router.get("/api/modules/{module_id}", response_model=ModulePublic)
def module(module_id: ModuleId, store: StoreDep) -> dict[str, Any]:
    for m in store.call(queries.modules):
        if m["id"] == module_id:
            return m
    raise NotFound(f"no module {module_id!r}")
