"""Pages: ``/overview`` (figures for dashboards; live sessions for operators), ``/`` and
``/walk``."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, HTTPException, Query, Response
from fastapi.responses import FileResponse
from starlette.concurrency import run_in_threadpool

from app.service import ops
from app.service.deps import OperatorView, StateDep
from app.service.schemas import NAME_PATTERN, ErrorPublic, Overview

router = APIRouter(tags=["pages"])
PAGES = {"/": "index.html", "/walk": "walk.html"}


@router.get(
    "/overview",
    response_model=Overview,
    responses={403: {"model": ErrorPublic}},
    openapi_extra={"security": [{}, {"APIKeyHeader": []}]},  # a key is optional: it shows more
)
async def overview(
    state: StateDep,
    role: OperatorView,
    limit: Annotated[int, Query(ge=0, le=1000, description="Sessions listed at most.")] = 100,
    domain: Annotated[str | None, Query(pattern=NAME_PATTERN)] = None,
) -> Response:
    """Domains with figures over their live sessions. With the admin key or the read-only
    operator key (X-API-Key) also the live sessions, most recently active first, with where
    each explorer is and was: personal data in a building that tracks people. Made at most
    once a second (ADVISOR_OVERVIEW_SECONDS), in a worker thread."""
    key = ("overview", role, limit, domain)
    age = state.settings.overview_seconds

    async def build() -> bytes:
        aggregates = await state.sessions.aggregates()
        sessions = await state.sessions.snapshot(limit, domain) if role else []
        return await run_in_threadpool(ops.overview, state, role, aggregates, sessions)

    text = await state.fresh.get(key, age, build)
    return Response(text, media_type="application/json")


def _page(path: str, file: str) -> None:
    @router.get(path, include_in_schema=False, responses={404: {"model": ErrorPublic}})
    async def page(state: StateDep) -> FileResponse:
        page_file = state.settings.static_dir / file
        if not page_file.is_file():
            raise HTTPException(404, f"the page {file} is not installed in {page_file.parent}")
        return FileResponse(page_file, media_type="text/html")


for _path, _file in PAGES.items():
    _page(_path, _file)
