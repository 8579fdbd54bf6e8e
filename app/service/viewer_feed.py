"""The API's side of the viewer, which runs in a process of its own (``python -m app viewer``,
started by ``serve``) and reads the service over HTTP like any client:

* ``GET /viewer/snapshot`` (the admin or the read-only operator key): the domains, each with
  the version of its prior (the viewer fetches a domain's map and prior, ``GET /domains/{name}``
  and ``/prior``, only when they change), and the 64 most recently active sessions with their
  recent history; made at most 20 times a second, in a worker thread;
* ``GET /viewer``: where the viewer runs, for pages that link to it.

Nothing a browser sends to the viewer reaches this process.
"""

from __future__ import annotations

from datetime import datetime
from functools import partial
from typing import Any

import orjson
from fastapi import APIRouter, Request, Response
from pydantic import BaseModel, Field

from app.service.deps import OperatorDep, StateDep
from app.service.live.registry import SessionSnapshot
from app.service.metrics import viewer_tick
from app.service.schemas import Cell, ErrorPublic, GoalBelief
from app.service.state import ServiceState

#: Sessions handed to the viewer per snapshot at most (the most recently active).
VIEWER_SESSIONS = 64


class ViewerDomain(BaseModel):
    name: str
    updated_at: datetime = Field(description="Changes when the domain is PUT again.")
    prior_version: int = Field(description="Changes whenever its prior does.")


class ViewerSession(BaseModel):
    session_id: str
    domain: str
    steps: int
    position: Cell
    p_normal: float
    advice_count: int
    total_cost: float
    kappa: float
    path: list[Cell] = Field(description="Recent cells within the retention, oldest first.")
    p_normal_history: list[float]
    advice: list[tuple[int, Cell, tuple[float, float, float, float]]] = Field(
        description="(step, cell, advice as N, E, S, W) of the recent advice, oldest first."
    )
    agent_type: str | None
    strategy: str
    goals: list[GoalBelief] | None


class ViewerSnapshot(BaseModel):
    domains: list[ViewerDomain]
    sessions: list[ViewerSession] = Field(description="Most recently active first.")


async def snapshot(state: ServiceState) -> bytes:
    """What the viewer draws now, as JSON (the sessions' copies made in a worker thread)."""
    domains = [
        {"name": d.name, "updated_at": d.updated_at, "prior_version": d.view.version}
        for d in state.catalog.states()
    ]
    sessions = [_session(s) for s in await state.sessions.snapshot(VIEWER_SESSIONS)]
    return orjson.dumps({"domains": domains, "sessions": sessions})


def _session(s: SessionSnapshot) -> dict[str, Any]:
    goals = None
    if s.goals is not None:
        goals = [{"goal": cell, "p": p, "ruled_out": out} for cell, p, out in s.goals]
    return {
        "session_id": s.id, "domain": s.domain, "steps": s.steps, "position": s.position,
        "p_normal": s.p_normal, "advice_count": s.advice_count, "total_cost": s.total_cost,
        "kappa": s.kappa, "path": s.path, "p_normal_history": s.p_history,
        "advice": s.advice, "agent_type": s.agent_type, "strategy": s.strategy, "goals": goals,
    }  # fmt: skip


class ViewerStatus(BaseModel):
    enabled: bool = Field(description="Whether `serve` starts the viser viewer beside the API.")
    port: int | None = Field(description="Its port (null when not enabled).")
    host: str | None = Field(description="The interface it listens on (null when not enabled).")


router = APIRouter(tags=["pages"])


@router.get(
    "/viewer/snapshot",
    dependencies=[OperatorDep],
    response_model=ViewerSnapshot,
    responses={code: {"model": ErrorPublic} for code in (401, 403)},
)
async def viewer_snapshot(state: StateDep, request: Request) -> Response:
    """What the viewer draws (the admin or the read-only operator key): the domains with the
    version of their prior, and the most recently active sessions with where each is and was.
    The viewer reports its last tick's duration in seconds as ``X-Viewer-Tick`` (counted in
    ``advisor_viewer_tick_seconds``; a value that is not a number from 0 to 3600 is ignored)."""
    tick = request.headers.get("x-viewer-tick")
    if tick is not None and state.settings.metrics_enabled:
        seconds = _seconds(tick)
        if seconds is not None:
            viewer_tick(seconds)
    age = min(0.05, state.settings.overview_seconds)
    text = await state.fresh.get(("viewer",), age, partial(snapshot, state))
    return Response(text, media_type="application/json")


def _seconds(text: str) -> float | None:
    try:
        value = float(text[:32])
    except ValueError:
        return None
    return value if 0.0 <= value <= 3600.0 else None  # NaN fails both comparisons


@router.get("/viewer")
async def viewer_status(request: Request) -> ViewerStatus:
    """Where the 3D viewer is: this host, this port (``serve`` starts it unless --no-viewer)."""
    settings = request.app.state.settings
    if not settings.viewer_enabled:
        return ViewerStatus(enabled=False, port=None, host=None)
    return ViewerStatus(enabled=True, port=settings.viewer_port, host=settings.viewer_host)
