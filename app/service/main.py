"""The advice service: ``create_app`` wires settings, routes, errors and the lifespan."""

from __future__ import annotations

import asyncio
import gc
from collections.abc import AsyncIterator, Awaitable, Callable
from contextlib import asynccontextmanager

from fastapi import FastAPI
from fastapi.staticfiles import StaticFiles
from fastapi_offline import FastAPIOffline
from starlette.concurrency import run_in_threadpool
from uvicorn.middleware.proxy_headers import ProxyHeadersMiddleware

from app.service import metrics
from app.service.clients import trusted_hosts
from app.service.config import VERSION, Settings
from app.service.errors import (
    DATABASE_DOWN,
    STORE_DOWN,
    BodyLimit,
    NoWebSocketRoute,
    install_error_handlers,
)
from app.service.logs import announce, quiet_event_routes
from app.service.openapi import install_openapi, operation_id
from app.service.routes import ROUTERS, apidocs
from app.service.routes import metrics as metrics_route
from app.service.routes.sessions import add_event_route
from app.service.security import redact_access_log
from app.service.state import ServiceState, open_state
from app.service.wire.loops import warm_up

Stop = Callable[[], Awaitable[None]]


async def start_background(app: FastAPI, settings: Settings) -> list[Stop]:
    """The one hook for services that run beside the API in its process (the MQTT bridge when
    ``settings.mqtt_url``; the viewer runs in a process of its own, started by ``serve``);
    returns their stop functions, called at shutdown."""
    stops: list[Stop] = []
    if settings.mqtt_url:
        from app.service.mqtt import start_bridge

        stops.append(await start_bridge(app))
    return stops


async def _expire_idle(state: ServiceState) -> None:
    while True:
        await asyncio.sleep(state.settings.sweep_seconds)
        await state.sessions.sweep()  # idle sessions, and the retention of where explorers were


async def _surviving(run: Callable[[], Awaitable[None]], pause: float = 1.0) -> None:
    """The loop ``run`` makes, started again after Redis or the database failed it (they
    come back; the loop must not end with them)."""
    while True:
        try:
            await run()
        except (*STORE_DOWN, *DATABASE_DOWN):
            await asyncio.sleep(pause)


@asynccontextmanager
async def lifespan(app: FastAPI) -> AsyncIterator[None]:
    settings: Settings = app.state.settings
    redact_access_log()  # uvicorn has configured its loggers by now
    if not settings.access_log_events:
        quiet_event_routes()
    state, messages = await run_in_threadpool(open_state, settings)
    for message in messages:
        announce(message, settings.log_format)
    await run_in_threadpool(warm_up)
    await state.sessions.start()
    app.state.service = state
    # Everything alive now (modules, tables, priors) lives as long as the process: keep it out
    # of the collector, whose full passes over it would otherwise pause requests for ~100 ms.
    gc.collect()
    gc.freeze()
    sweeper = asyncio.create_task(_surviving(lambda: _expire_idle(state)))
    gauges = None
    if settings.metrics_enabled:
        metrics.forget_dead_workers()  # a worker that takes a killed one's place
        gauges = asyncio.create_task(_surviving(lambda: metrics.keep_gauges(state.sessions)))
    stops = await start_background(app, settings)
    try:
        yield
    finally:
        for stop in reversed(stops):
            await stop()
        sweeper.cancel()
        if gauges is not None:
            gauges.cancel()
        await state.sessions.close()
        # a graceful restart keeps the live sessions (Redis keeps them itself)
        kept = await run_in_threadpool(state.sessions.save, state.store)
        if kept:
            announce(f"Kept {kept} live sessions for the next start", settings.log_format)
        await run_in_threadpool(state.close)


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or Settings()
    # /docs and /redoc: Swagger UI and ReDoc from the fastapi-offline package, no CDN
    app = FastAPIOffline(
        redoc_url=None,  # apidocs serves it (its bundle patched to load nothing from outside)
        static_url=apidocs.STATIC_URL,
        title="Hidden-goal advisor",
        version=VERSION,
        description="Advice for explorers with hidden goals (Rosman & Ramamoorthy, ICRA 2014). "
        f"Request bodies are JSON of at most {settings.max_body_bytes} bytes (413 beyond, 415 "
        "for another Content-Type; PUT /domains/{name} also takes a map file as text/plain); "
        "request headers at most 16 KiB in all (431).",
        lifespan=lifespan,
        # a body without a Content-Type is read as JSON on every route, as the events and
        # trajectories routes (which read their bytes themselves) always did; a Content-Type
        # that is not JSON is refused (415) by BodyLimit on every route (but a map file's
        # text/plain to PUT /domains/{name})
        strict_content_type=False,
        # operationIds are the route functions' names (create_session, put_domain, ...): what
        # a client generated from the document calls its functions
        generate_unique_id_function=operation_id,
    )
    app.state.settings = settings
    install_error_handlers(app)
    add_event_route(app)  # the busiest route first, on the app's own router
    routers = [*ROUTERS, metrics_route.router] if settings.metrics_enabled else [*ROUTERS]
    for router in routers:
        app.include_router(router)
    app.add_middleware(BodyLimit, max_bytes=settings.max_body_bytes)
    app.add_middleware(NoWebSocketRoute)
    if settings.metrics_enabled:
        request_ids = settings.log_format == "json"
        methods = metrics.route_methods(app.router, *routers)  # the method label's values
        app.add_middleware(metrics.MetricsMiddleware, request_ids=request_ids, methods=methods)
    if settings.trusted_proxies:  # outermost: everything after it sees the forwarded client
        proxies = trusted_hosts(settings.trusted_proxies)
        app.add_middleware(ProxyHeadersMiddleware, trusted_hosts=proxies)
    if settings.static_dir.is_dir():
        app.mount("/static", StaticFiles(directory=settings.static_dir), "static")
    install_openapi(app)
    return app
