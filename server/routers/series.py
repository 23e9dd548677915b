"""Time series: sensors, attitude, λ_att, linearity, events."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Query
from fastapi.concurrency import run_in_threadpool

from server.deps import MAX_ID, FloatQuery, IdQuery, ModuleId, StoreDep, WavelengthQuery
from server.errors import NotFound
from storage import queries

router = APIRouter(tags=["series"])
MaxPoints = Annotated[int, Query(ge=10, le=20000)]


def _dive(s: Any, dive: int | None) -> int | None:
    if dive is not None:
        return dive
    d = queries.dives(s)
    return d[0]["id"] if d else None


@router.get("/api/sensors")
async def sensors(
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

    def q() -> dict[str, Any]:
        with store.read() as s:
            return queries.sensor_series(
                s, module=module, dive_id=_dive(s, dive), t_from=t_from, t_to=t_to, max_points=max_points
            )

    return {"module": module, **await run_in_threadpool(q)}


@router.get("/api/attitude")
async def attitude(
    store: StoreDep,
    module: Annotated[str, Query(max_length=64)],
    dive: IdQuery = None,
    t_from: FloatQuery = None,
    t_to: FloatQuery = None,
    max_points: MaxPoints = 1000,
) -> dict[str, Any]:
    """Tilt, rotation rate and heave period of a module, derived from its sensors."""

    def q() -> dict[str, Any]:
        with store.read() as s:
            return queries.attitude_series(
                s, module=module, dive_id=_dive(s, dive), t_from=t_from, t_to=t_to, max_points=max_points
            )

    return {"module": module, **await run_in_threadpool(q)}


@router.get("/api/attenuation")
async def attenuation(
    store: StoreDep,
    dive: IdQuery = None,
    run: IdQuery = None,
    wavelength_nm: WavelengthQuery = None,
    t_from: FloatQuery = None,
) -> dict[str, Any]:
    """The λ_att series per wavelength: one point per LEM visit, with statistical and systematic errors
    and whether the visit is over (``final``)."""

    def q() -> dict[str, Any]:
        with store.read() as s:
            dive_id = _dive(s, dive)
            if dive_id is None:
                return {"dive_id": None, "run_id": None, "series": {}}
            rid = run or queries.live_run_id(s, dive_id)
            if rid is None:
                return {"dive_id": dive_id, "run_id": None, "series": {}}
            series = queries.attenuation_series(s, rid, wavelength_nm, t_from)
            return {"dive_id": dive_id, "run_id": rid, "series": {str(k): v for k, v in series.items()}}

    return await run_in_threadpool(q)


@router.get("/api/linearity")
async def linearity(
    store: StoreDep,
    dive: IdQuery = None,
    run: IdQuery = None,
    module: Annotated[str | None, Query(max_length=64)] = None,
) -> dict[str, Any]:
    """Linearity fits per module and wavelength: slope, R², saturation knee, the points."""

    def q() -> dict[str, Any]:
        with store.read() as s:
            dive_id = _dive(s, dive)
            rid = run or (queries.live_run_id(s, dive_id) if dive_id is not None else None)
            if rid is None:
                return {"run_id": None, "checks": []}
            return {"run_id": rid, "checks": queries.linearity(s, rid, module)}

    return await run_in_threadpool(q)


@router.get("/api/events")
async def events(
    store: StoreDep,
    after: Annotated[int, Query(ge=0, le=MAX_ID)] = 0,
    limit: Annotated[int, Query(ge=1, le=5000)] = 500,
) -> dict[str, Any]:
    """Stored events after an id: how a client catches up on what it missed."""

    def q() -> list[dict[str, Any]]:
        with store.read() as s:
            return queries.events_after(s, after, limit)

    items = await run_in_threadpool(q)
    return {"items": items, "last_id": items[-1]["id"] if items else after}


@router.get("/api/modules")
async def modules(store: StoreDep) -> list[dict[str, Any]]:
    def q() -> list[dict[str, Any]]:
        with store.read() as s:
            return queries.modules(s)

    return await run_in_threadpool(q)


@router.get("/api/modules/{module_id}")
async def module(module_id: ModuleId, store: StoreDep) -> dict[str, Any]:
    for m in await modules(store):
        if m["id"] == module_id:
            return m
    raise NotFound(f"no module {module_id!r}")
