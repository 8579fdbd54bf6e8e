"""Public pages: ``/overview`` (figures for dashboards, no tokens), ``/`` and ``/walk``."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, HTTPException, Query
from fastapi.responses import FileResponse

from app.service.deps import StateDep
from app.service.public import overview_domain, overview_session
from app.service.schemas import NAME_PATTERN, ErrorPublic, Overview

router = APIRouter(tags=["pages"])
PAGES = {"/": "index.html", "/walk": "walk.html"}


@router.get("/overview")
async def overview(
    state: StateDep,
    limit: Annotated[int, Query(ge=0, le=1000, description="Sessions listed at most.")] = 100,
    domain: Annotated[str | None, Query(pattern=NAME_PATTERN)] = None,
) -> Overview:
    """Domains and live sessions with their figures, most recently active first. Public:
    session ids are shown, tokens never."""
    counts = state.registry.count_by_domain()
    snaps = state.registry.snapshot(limit, domain)
    return Overview(
        domains=[overview_domain(d, counts.get(d.name, 0)) for d in state.catalog.states()],
        total_sessions=sum(counts.values()),
        sessions=[overview_session(s) for s in snaps],
    )


def _page(path: str, file: str) -> None:
    @router.get(path, include_in_schema=False, responses={404: {"model": ErrorPublic}})
    async def page(state: StateDep) -> FileResponse:
        page_file = state.settings.static_dir / file
        if not page_file.is_file():
            raise HTTPException(404, f"the page {file} is not installed in {page_file.parent}")
        return FileResponse(page_file, media_type="text/html")


for _path, _file in PAGES.items():
    _page(_path, _file)
