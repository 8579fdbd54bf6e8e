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

import asyncio
import contextlib
from functools import partial
from subprocess import Popen

from fastapi import APIRouter, Request, Response

from app.service import ops
from app.service.deps import OperatorDep, StateDep
from app.service.metrics import viewer_tick
from app.service.schemas import ErrorPublic, ViewerSnapshot, ViewerStatus

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
    text = await state.fresh.get(("viewer",), age, partial(ops.viewer_snapshot, state))
    return Response(text, media_type="application/json")


def _seconds(text: str) -> float | None:
    try:
        value = float(text[:32])
    except ValueError:
        return None
    return value if 0.0 <= value <= 3600.0 else None  # NaN fails both comparisons


@router.get("/viewer")
async def viewer_status(request: Request) -> ViewerStatus:
    """Where the 3D viewer is: this host, this port (``serve`` starts it unless --no-viewer),
    and whether it is running now (pages show their link to it only then)."""
    settings = request.app.state.settings
    if not settings.viewer_enabled:
        return ViewerStatus(enabled=False, running=False, port=None, host=None)
    process = getattr(request.app.state, "viewer_process", None)
    running = await viewer_running(process, settings.viewer_host, settings.viewer_port)
    return ViewerStatus(
        enabled=True, running=running, port=settings.viewer_port, host=settings.viewer_host
    )


#: how long GET /viewer waits for the viewer's port to take a connection
PROBE_SECONDS = 0.5


async def viewer_running(process: Popen[bytes] | None, host: str, port: int) -> bool:
    """Whether the viewer runs: its process (``serve`` started it: the single worker holds
    it) has not exited, and its port takes a connection (with several workers, or a viewer
    started apart, the port alone says)."""
    if process is not None and process.poll() is not None:
        return False
    try:
        _, writer = await asyncio.wait_for(
            asyncio.open_connection(_loopback(host), port), PROBE_SECONDS
        )
    except (OSError, TimeoutError):
        return False
    writer.close()
    with contextlib.suppress(OSError):
        await writer.wait_closed()
    return True


def _loopback(host: str) -> str:
    """The address to reach a server listening on ``host`` from this machine."""
    return "127.0.0.1" if host in ("", "0.0.0.0") else "::1" if host in ("::", "[::]") else host
