"""Liveness and readiness.

* ``GET /health/live``: the process answers. Nothing else is touched: 200 as long as the
  event loop runs (the Docker ``HEALTHCHECK``; a supervisor restarts a process that fails it).
* ``GET /health/ready``: whether the service can do its work: 503 (with ``Retry-After``) when
  the database, or Redis where live sessions are kept in it, does not answer within
  :data:`CHECK_SECONDS` (at once while Redis is known to be down); the state of each
  dependency in the body, the MQTT bridge's and the viewer's too, which never fail it (the API
  works without them). A load balancer sends traffic elsewhere while it fails.
* ``GET /health``: readiness, as it always answered (the figures of the service, and the
  dependencies).

``HEAD`` of each answers the same status without a body.
"""

from __future__ import annotations

import asyncio
import time
from typing import Any

from fastapi import APIRouter, Request, Response
from fastapi.responses import JSONResponse
from starlette.concurrency import run_in_threadpool

from app.service.config import VERSION
from app.service.deps import StateDep
from app.service.live.sessions import StoreUnavailable
from app.service.schemas import HealthPublic, LivePublic, NotReadyPublic
from app.service.state import ServiceState

router = APIRouter(tags=["health"])
#: seconds each dependency may take to answer a readiness check
CHECK_SECONDS = 2.0
#: seconds a readiness probe is asked to wait after a 503
RETRY_AFTER = 2
NOT_READY: dict[int | str, dict[str, Any]] = {503: {"model": NotReadyPublic}}


def _dependency(state: str, required: bool, detail: str | None = None) -> dict[str, Any]:
    return {"state": state, "required": required, "detail": detail}


async def _database(request: Request, state: ServiceState) -> dict[str, Any]:
    """The database answers ``SELECT 1`` in time (one check at a time: a check that has not
    come back is waited for again rather than joined by others, each holding a thread)."""
    app_state = request.app.state
    running: asyncio.Future[None] | None = getattr(app_state, "database_check", None)
    if running is None or running.done():
        running = asyncio.ensure_future(run_in_threadpool(state.store.ping))
        running.add_done_callback(lambda f: f.cancelled() or f.exception())
        app_state.database_check = running
    try:
        await asyncio.wait_for(asyncio.shield(running), CHECK_SECONDS)
    except TimeoutError:
        return _dependency("down", True, f"no answer within {CHECK_SECONDS:g} s")
    except Exception as exc:  # any failure of the database means "not ready"
        return _dependency("down", True, f"{type(exc).__name__}")
    return _dependency("up", True)


async def _redis(state: ServiceState) -> dict[str, Any]:
    ready = getattr(state.sessions, "ready", None)
    if ready is None:  # the sessions of this process: no Redis
        return _dependency("not used", False)
    try:
        why = await asyncio.wait_for(ready(), CHECK_SECONDS)
    except TimeoutError:
        why = f"no answer within {CHECK_SECONDS:g} s"
    return _dependency("up", True) if why is None else _dependency("down", True, why)


def _mqtt(request: Request) -> dict[str, Any]:
    if not request.app.state.settings.mqtt_url:
        return _dependency("off", False)
    bridge = getattr(request.app.state, "bridge", None)
    if bridge is None:
        return _dependency("not connected", False, "the bridge is not running")
    if getattr(bridge, "_lock", None) is None:  # waiting for another worker's to stop
        return _dependency("standby", False, "another worker runs the bridge")
    if bridge.connected.is_set():
        return _dependency("connected", False)
    return _dependency("not connected", False, "reconnecting to the broker")


async def _viewer(request: Request) -> dict[str, Any]:
    """Whether something listens at the viewer's port (its own process)."""
    settings = request.app.state.settings
    if not settings.viewer_enabled:
        return _dependency("off", False)
    host = {"0.0.0.0": "127.0.0.1", "::": "::1", "": "127.0.0.1"}.get(
        settings.viewer_host, settings.viewer_host
    )
    if not await _answers_http(host, settings.viewer_port):
        why = f"nothing answers at port {settings.viewer_port}"
        return _dependency("not listening", False, why)
    return _dependency("listening", False)


async def _answers_http(host: str, port: int, timeout: float = 0.5) -> bool:
    """Whether an HTTP server answers a request at ``host:port`` (its status line, whatever
    the status). A request, not a bare connection: the viewer's websocket server logs a
    connection closed before its request as a failed handshake, with a traceback."""
    writer = None
    try:
        async with asyncio.timeout(timeout):
            reader, writer = await asyncio.open_connection(host, port)
            writer.write(f"GET / HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n".encode())
            await writer.drain()
            return (await reader.readline()).startswith(b"HTTP/")
    except (OSError, TimeoutError):
        return False
    finally:
        if writer is not None:
            writer.close()


async def readiness(request: Request, state: ServiceState) -> Response:
    """200 with the service's figures, or 503 naming what is down (see the module)."""
    database, redis, viewer = await asyncio.gather(
        _database(request, state), _redis(state), _viewer(request)
    )
    dependencies = {"database": database, "redis": redis, "mqtt": _mqtt(request),
                    "viewer": viewer}  # fmt: skip
    sessions = None
    if redis["state"] != "down":
        try:
            sessions = await asyncio.wait_for(state.sessions.count(), CHECK_SECONDS)
        except (StoreUnavailable, TimeoutError) as exc:
            why = getattr(exc, "why", None) or f"no answer within {CHECK_SECONDS:g} s"
            dependencies["redis"] = _dependency("down", True, why)
    down = [name for name, d in dependencies.items() if d["required"] and d["state"] != "up"]
    if down or sessions is None:
        named = ", ".join(f"{name} ({dependencies[name]['detail']})" for name in down)
        body = NotReadyPublic.model_validate({
            "detail": f"not ready: {named or 'Redis'} does not answer",
            "status": "unavailable", "dependencies": dependencies,
        })  # fmt: skip
        return JSONResponse(
            body.model_dump(), status_code=503, headers={"Retry-After": str(RETRY_AFTER)}
        )
    figures = HealthPublic.model_validate({
        "status": "ok", "version": VERSION, "database": state.store.dialect,
        "domains": len(state.catalog), "sessions": sessions,
        "uptime_seconds": time.monotonic() - state.started, "dependencies": dependencies,
    })  # fmt: skip
    return JSONResponse(figures.model_dump())


@router.get("/health", response_model=HealthPublic, responses=NOT_READY)
async def health(request: Request, state: StateDep) -> Response:
    """Readiness (as ``GET /health/ready``), with the service's figures: 503 when the
    database, or Redis where live sessions are kept, does not answer."""
    return await readiness(request, state)


@router.get("/health/ready", response_model=HealthPublic, responses=NOT_READY)
async def ready(request: Request, state: StateDep) -> Response:
    """Whether the service can work: 503 (``Retry-After``) when the database, or Redis where
    live sessions are kept, does not answer within 2 s; the state of every dependency (the
    MQTT bridge and the viewer are reported, never fail it)."""
    return await readiness(request, state)


@router.get("/health/live")
async def live(state: StateDep) -> LivePublic:
    """The process answers (nothing else is asked): 200 while its event loop runs."""
    return LivePublic(status="ok", version=VERSION, uptime_seconds=time.monotonic() - state.started)


@router.head("/health", include_in_schema=False)
@router.head("/health/ready", include_in_schema=False)
async def health_head(request: Request, state: StateDep) -> Response:
    """What load balancers and probes ask: readiness' status without its body."""
    return await readiness(request, state)


@router.head("/health/live", include_in_schema=False)
async def live_head(state: StateDep) -> LivePublic:
    return await live(state)
