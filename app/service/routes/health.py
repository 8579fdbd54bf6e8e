from __future__ import annotations

import time

from fastapi import APIRouter, HTTPException
from starlette.concurrency import run_in_threadpool

from app.service.config import VERSION
from app.service.deps import StateDep
from app.service.schemas import ErrorPublic, HealthPublic

router = APIRouter(tags=["health"])


@router.get("/health", responses={503: {"model": ErrorPublic}})
async def health(state: StateDep) -> HealthPublic:
    """Liveness and readiness: the database answers (``HEAD /health``: the same, no body)."""
    try:
        await run_in_threadpool(state.store.ping)
    except Exception as exc:  # any database failure means "not ready"
        raise HTTPException(503, f"the database does not answer: {type(exc).__name__}") from None
    return HealthPublic(
        status="ok",
        version=VERSION,
        database=state.store.dialect,
        domains=len(state.catalog),
        sessions=await state.sessions.count(),
        uptime_seconds=time.monotonic() - state.started,
    )


@router.head("/health", include_in_schema=False)
async def health_head(state: StateDep) -> HealthPublic:
    """What load balancers and probes ask: ``GET /health``'s status without its body."""
    return await health(state)
