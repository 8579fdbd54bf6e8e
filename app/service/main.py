"""The advice service: ``create_app`` wires settings, routes, errors and the lifespan."""

from __future__ import annotations

import asyncio
import gc
import sys
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from fastapi import FastAPI
from fastapi.staticfiles import StaticFiles
from starlette.concurrency import run_in_threadpool

from app.service import viewer_feed
from app.service.config import VERSION, Settings
from app.service.errors import BodyLimit, install_error_handlers
from app.service.openapi import install_openapi
from app.service.ops import warm_up
from app.service.routes import ROUTERS
from app.service.routes.sessions import add_event_route
from app.service.security import redact_access_log
from app.service.state import ServiceState, open_state


async def _expire_idle(state: ServiceState) -> None:
    while True:
        await asyncio.sleep(state.settings.sweep_seconds)
        state.registry.expire()
        state.registry.forget_old()  # the retention of where explorers were


@asynccontextmanager
async def lifespan(app: FastAPI) -> AsyncIterator[None]:
    settings: Settings = app.state.settings
    redact_access_log()  # uvicorn has configured its loggers by now
    state, messages = await run_in_threadpool(open_state, settings)
    for message in messages:
        print(message, file=sys.stderr, flush=True)
    await run_in_threadpool(warm_up)
    app.state.service = state
    # Everything alive now (modules, tables, priors) lives as long as the process: keep it out
    # of the collector, whose full passes over it would otherwise pause requests for ~100 ms.
    gc.collect()
    gc.freeze()
    sweeper = asyncio.create_task(_expire_idle(state))
    try:
        yield
    finally:
        sweeper.cancel()
        await run_in_threadpool(state.close)


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or Settings()
    app = FastAPI(
        title="Hidden-goal advisor",
        version=VERSION,
        description="Advice for explorers with hidden goals (Rosman & Ramamoorthy, ICRA 2014). "
        f"Request bodies are JSON of at most {settings.max_body_bytes} bytes (413 beyond, 415 "
        "for another Content-Type); request headers at most 16 KiB in all (431).",
        lifespan=lifespan,
        # a body without a Content-Type is read as JSON on every route, as the events and
        # trajectories routes (which read their bytes themselves) always did; a Content-Type
        # that is not JSON is refused (415) by BodyLimit on every route
        strict_content_type=False,
    )
    app.state.settings = settings
    install_error_handlers(app)
    app.add_middleware(BodyLimit, max_bytes=settings.max_body_bytes)
    add_event_route(app)  # the busiest route first, on the app's own router
    for router in ROUTERS:
        app.include_router(router)
    app.include_router(viewer_feed.router)
    if settings.static_dir.is_dir():
        app.mount("/static", StaticFiles(directory=settings.static_dir), "static")
    install_openapi(app)
    return app
