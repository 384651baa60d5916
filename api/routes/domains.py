"""GET /v1/domains and /v1/domains/{name}: the registered domains, as `tmoc domains`."""
# No `from __future__ import annotations`: FastAPI must see the real classes in signatures.
from typing import Annotated

from fastapi import APIRouter, HTTPException, Path
from starlette.concurrency import run_in_threadpool

from .. import schemas as S
from ..errors import error_responses

router = APIRouter()


@router.get("/domains", response_model=S.DomainList, tags=["domains"])
async def list_domains():
    """Every registered domain (built-in and installed plugins), as `tmoc domains`."""
    from coordinator.domains import broken, describe, names

    items, left_out = [], await run_in_threadpool(broken)
    for n in names():
        try:
            items.append(await run_in_threadpool(describe, n))
        except Exception as exc:  # noqa: BLE001 - one broken plugin must not hide the others
            left_out[n] = f"{type(exc).__name__}: {exc}"
    return {"items": items, "total": len(items), "broken": left_out}


@router.get("/domains/{name}", response_model=S.DomainView, tags=["domains"],
            responses=error_responses(404))
async def get_domain(name: Annotated[str, Path(min_length=1, max_length=64)]):
    """One domain: objects, L (names, units, prior), measurement channels, actions, T
    contexts and utility terms."""
    from coordinator.domains import describe, names

    if name not in names():
        raise HTTPException(404, f"domain {name!r}: no such domain (known: {', '.join(names())})")
    return await run_in_threadpool(describe, name)


__all__ = ["router"]
