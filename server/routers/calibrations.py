"""Calibration records: every version kept, changes audited."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Path
from pydantic import BaseModel, ConfigDict, Field

from camcal.core.calibrations import record_values
from camcal.core.frameset import FrameSetError, parse_setup
from camcal.core.numbers import Number
from server.deps import MAX_ID, OperatorDep, StoreDep
from server.errors import Invalid, NotFound
from server.schemas import CalibrationPublic
from storage import queries

router = APIRouter(tags=["calibrations"])


class CalibrationCreate(BaseModel):
    """A new version of a named calibration: a setup (distances, I0'/I0, linear range)."""

    model_config = ConfigDict(extra="forbid")
    name: str = Field(min_length=1, max_length=120, pattern=r"^[A-Za-z0-9_.-]+$")
    setup: dict[str, Any]
    source: str = Field("", max_length=2000)
    valid_from_unix_s: Number | None = Field(None, ge=0, le=1e11)
    valid_to_unix_s: Number | None = Field(None, ge=0, le=1e11)


@router.get("/api/calibrations", response_model=list[CalibrationPublic])
def list_calibrations(store: StoreDep) -> list[dict[str, Any]]:
    """Every calibration and version, oldest first within a name."""
    return store.call(queries.calibrations)


@router.get("/api/calibrations/{calibration_id}", response_model=CalibrationPublic)
def get_calibration(calibration_id: Annotated[int, Path(ge=0, le=MAX_ID)], store: StoreDep) -> dict[str, Any]:
    rec = store.call(queries.calibration, calibration_id)
    if rec is None:
        raise NotFound(f"no calibration {calibration_id}")
    return rec


@router.post("/api/calibrations", status_code=201, response_model=CalibrationPublic)
def add_calibration(body: CalibrationCreate, store: StoreDep, who: OperatorDep) -> dict[str, Any]:
    """Store a new version (operator token); the audit log records the change."""
    try:
        setup = parse_setup(body.setup, "setup")
    except FrameSetError as exc:
        raise Invalid(str(exc)) from None
    return store.add_calibration(
        body.name,
        record_values(setup, [], [body.source or f"API by {who}"]),
        actor=who,
        source=body.source,
        valid_from_unix_s=body.valid_from_unix_s,
        valid_to_unix_s=body.valid_to_unix_s,
    )
