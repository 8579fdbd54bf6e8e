"""The API's side of the viewer, which runs in a process of its own (``python -m app viewer``,
started by ``serve``) and reads the service over HTTP like any client:

* ``GET /viewer/snapshot`` (the admin or the read-only operator key): the domains, each with
  the version of its prior (the viewer fetches a domain's map and prior, ``GET /domains/{name}``
  and ``/prior``, only when they change), and the 64 most recently active sessions with their
  recent history; made at most 20 times a second, in a worker thread;
* ``GET /viewer``: where the viewer runs and whether it is alive, for pages that link to it.

Nothing a browser sends to the viewer reaches this process.
"""

from __future__ import annotations

import os
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
    return ViewerStatus(
        enabled=True,
        running=viewer_running(process, os.environ.get(VIEWER_PID)),
        port=settings.viewer_port,
        host=settings.viewer_host,
    )


#: the viewer's process id, which ``serve`` puts in its workers' environment (one worker holds
#: the process itself: ``app.state.viewer_process``)
VIEWER_PID = "ADVISOR_VIEWER_PID"


def viewer_running(process: Popen[bytes] | None, pid: str | None) -> bool:
    """Whether the viewer ``serve`` started is alive: its process (one worker: ``serve`` hands
    it to the app) has not exited, or the process of that id (workers: ``serve`` reaps it when
    it exits, so the id goes) exists. A viewer this service did not start (tests, one run
    apart) is taken to be running."""
    if process is not None:
        return process.poll() is None
    if pid is None or not pid.isdigit():
        return True
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process: it exists
        return True
    return True
