"""GET /v1/robots and /v1/robots/{name}: the registered robots, as `tmoc robots`."""
# No `from __future__ import annotations`: FastAPI must see the real classes in signatures.
from typing import Annotated

from fastapi import APIRouter, HTTPException, Path

from .. import schemas as S
from ..errors import error_responses

router = APIRouter()


@router.get("/robots", response_model=S.RobotList, tags=["robots"])
async def list_robots():
    """Every registered robot (built-in and installed plugins): its joints and limits and,
    for an arm, what a client needs to check a trajectory with its own kinematics."""
    from coordinator.robots import broken, describe, names

    items = [describe(n) for n in names()]          # declarations: no I/O, microseconds
    return {"items": items, "total": len(items), "broken": broken()}


@router.get("/robots/{name}", response_model=S.RobotView, tags=["robots"], responses=error_responses(404))
async def get_robot(name: Annotated[str, Path(min_length=1, max_length=64)]):
    """One robot, as in the list."""
    from coordinator.robots import describe, names

    if name not in names():
        raise HTTPException(404, f"robot {name!r}: no such robot (known: {', '.join(names())})")
    return describe(name)


__all__ = ["router"]
