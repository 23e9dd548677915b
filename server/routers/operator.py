"""Who is the operator behind a token: lets the dashboard check a login before it is needed."""

from __future__ import annotations

from fastapi import APIRouter

from server.deps import OperatorDep
from server.schemas import OperatorPublic

router = APIRouter(tags=["operator"])


@router.get("/api/operator", response_model=OperatorPublic)
async def whoami(who: OperatorDep) -> dict[str, str]:
    """The operator's name for a valid ``Bearer`` token; 401 without one, 403 with a wrong one."""
    return {"operator": who}
