"""``/redoc`` from the ReDoc bundle that the fastapi-offline package ships (``/docs``, Swagger UI,
is fastapi-offline's own page), so neither page needs the internet.

ReDoc's bundle loads one image from its makers' CDN (the logo beside "API docs by Redocly"),
whatever its options say; offline that is a failed request in the browser's console. The bundle
is served here with that image's address replaced by an empty inline picture.
"""

from __future__ import annotations

import functools
from pathlib import Path

import fastapi_offline
from fastapi import APIRouter, Request
from fastapi.openapi.docs import get_redoc_html
from fastapi.responses import HTMLResponse, Response

ASSETS = Path(fastapi_offline.__file__).parent / "static"
STATIC_URL = "/static-offline-docs"  # where fastapi-offline serves its assets
LOGO = "https://cdn.redoc.ly/redoc/logo-mini.svg"
EMPTY_SVG = "data:image/svg+xml,%3Csvg xmlns='http://www.w3.org/2000/svg'/%3E"

router = APIRouter(include_in_schema=False)


@functools.cache
def redoc_bundle() -> bytes:
    return (ASSETS / "redoc.standalone.js").read_bytes().replace(LOGO.encode(), EMPTY_SVG.encode())


@router.get("/redoc")
async def redoc(request: Request) -> HTMLResponse:
    root = request.scope.get("root_path", "")
    app = request.app
    return get_redoc_html(
        openapi_url=f"{root}{app.openapi_url}",
        title=f"{app.title} - ReDoc",
        redoc_js_url=f"{root}/redoc.standalone.js",
        redoc_favicon_url=f"{root}{STATIC_URL}/favicon.png",
        with_google_fonts=False,
    )


@router.get("/redoc.standalone.js")
async def redoc_js() -> Response:
    headers = {"Cache-Control": "public, max-age=86400"}
    return Response(redoc_bundle(), media_type="text/javascript", headers=headers)
