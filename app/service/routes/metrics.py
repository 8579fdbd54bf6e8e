"""``GET /metrics``: Prometheus' text exposition of :mod:`app.service.metrics`."""

from __future__ import annotations

import contextlib

from fastapi import APIRouter, Response
from prometheus_client import CONTENT_TYPE_LATEST

from app.service.deps import StateDep
from app.service.errors import STORE_DOWN
from app.service.metrics import exposition, refresh_sessions

router = APIRouter(tags=["operations"])


@router.get("/metrics", response_class=Response, responses={200: {"content": {"text/plain": {}}}})
async def metrics(state: StateDep) -> Response:
    """Prometheus metrics in the text exposition format (README, "Operations"); while Redis
    does not answer, with the live-sessions gauge as it was last read."""
    with contextlib.suppress(*STORE_DOWN):
        await refresh_sessions(state.sessions)
    return Response(exposition(), media_type=CONTENT_TYPE_LATEST)
