"""The one adapter between the service and the viser viewer.

The viewer (:mod:`app.viewer`) knows nothing of the service: it calls a feed that returns a
plain :class:`~app.viewer.state.Snapshot`. This module builds that feed from the catalog and
the session registry (one ``registry.snapshot`` per pump tick, never per event), starts and
stops the viewer from the service's lifespan hook, and answers ``GET /viewer`` so pages can
link to it.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Awaitable, Callable
from typing import TYPE_CHECKING

from fastapi import APIRouter, FastAPI, Request
from pydantic import BaseModel, Field

from app.service.config import Settings
from app.service.data.domains import DomainState
from app.service.data.store import POOLED
from app.service.live.registry import SessionSnapshot
from app.service.metrics import viewer_tick
from app.service.state import ServiceState
from app.viewer.state import DomainView, Feed, SessionView, Snapshot

if TYPE_CHECKING:  # viser is imported only when the viewer starts
    from app.viewer.viewer import Viewer

log = logging.getLogger(__name__)

#: Sessions handed to the viewer per tick at most (the most recently active).
VIEWER_SESSIONS = 64

Stop = Callable[[], Awaitable[None]]


def session_view(s: SessionSnapshot) -> SessionView:
    return SessionView(
        session_id=s.id,
        domain=s.domain,
        steps=s.steps,
        position=s.position,
        p_normal=s.p_normal,
        advice_count=s.advice_count,
        total_cost=s.total_cost,
        kappa=s.kappa,
        path=s.path,
        p_normal_history=s.p_history,
        advice=s.advice,  # (step, cell, theta_s) triples, the shape AdviceGiven names
        agent_type=s.agent_type,
        strategy=s.strategy,
        goals=s.goals,
    )


class ServiceFeed:
    """A :data:`~app.viewer.state.Feed` over a running service's state.

    The pooled prior is shown. A domain's ``prior_version`` goes up whenever its prior view
    object is replaced (new trajectories), so the viewer redraws the arrows only then.
    """

    def __init__(self, state: ServiceState, max_sessions: int = VIEWER_SESSIONS):
        self.state = state
        self.max_sessions = max_sessions
        self._views: dict[str, tuple[DomainState, object, DomainView]] = {}

    def _domain_view(self, d: DomainState) -> DomainView:
        prior = d.view
        cached = self._views.get(d.name)
        if cached is not None and cached[0] is d and cached[1] is prior:
            return cached[2]
        version = cached[2].prior_version + 1 if cached is not None else 0
        view = DomainView(d.domain, prior.tables[POOLED].theta, version)
        self._views[d.name] = (d, prior, view)
        return view

    def __call__(self) -> Snapshot:
        domains = {d.name: self._domain_view(d) for d in self.state.catalog.states()}
        for gone in set(self._views) - set(domains):
            del self._views[gone]
        sessions = self.state.registry.snapshot(self.max_sessions)
        return Snapshot(domains, [session_view(s) for s in sessions])


def viewer_of(app: FastAPI) -> Viewer | None:
    viewer: Viewer | None = getattr(app.state, "viewer", None)
    return viewer


async def start_viewer(app: FastAPI, settings: Settings) -> Stop:
    """Start the viewer on ``settings.viewer_port`` (or the next free port, as viser does)."""
    from app.viewer.viewer import Viewer

    feed: Feed = ServiceFeed(app.state.service)
    on_tick = viewer_tick if settings.metrics_enabled else None
    viewer = Viewer(feed, host=settings.host, port=settings.viewer_port, on_tick=on_tick)
    await asyncio.to_thread(viewer.start)
    app.state.viewer = viewer
    if viewer.port != settings.viewer_port:
        log.warning("viewer port %d was busy; using %d", settings.viewer_port, viewer.port)

    async def stop() -> None:
        app.state.viewer = None
        await asyncio.to_thread(viewer.stop)

    return stop


class ViewerStatus(BaseModel):
    enabled: bool = Field(description="Whether the viser viewer runs beside the API.")
    port: int | None = Field(description="Its port on the same host (null when not running).")
    clients: int = Field(description="Browsers connected to it now.")
    ticks: int = Field(description="Scene updates (pump ticks) since the service started.")


router = APIRouter(tags=["pages"])


@router.get("/viewer")
async def viewer_status(request: Request) -> ViewerStatus:
    """Where the 3D viewer is: same host as this API, this port."""
    viewer = viewer_of(request.app)
    if viewer is None or viewer.server is None:
        return ViewerStatus(enabled=False, port=None, clients=0, ticks=0)
    clients = len(viewer.server.get_clients())
    return ViewerStatus(enabled=True, port=viewer.port, clients=clients, ticks=viewer.ticks)
