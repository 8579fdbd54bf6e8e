"""``python -m app serve``: run the advice service with uvicorn."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer
from pydantic import ValidationError

from app.service.config import Settings


def serve(
    host: Annotated[str | None, typer.Option(help="Interface (default 127.0.0.1).")] = None,
    port: Annotated[int | None, typer.Option(help="HTTP port (default 8000).")] = None,
    data_dir: Annotated[Path | None, typer.Option(help="SQLite file and admin key.")] = None,
    database_url: Annotated[
        str | None, typer.Option(help="SQLAlchemy URL, e.g. postgresql+psycopg://...")
    ] = None,
    no_viewer: Annotated[
        bool, typer.Option("--no-viewer", help="Do not start the viewer.")
    ] = False,
    log_level: Annotated[str, typer.Option(help="uvicorn log level.")] = "info",
) -> None:
    """Run the advice service (settings also from ADVISOR_* environment variables)."""
    import uvicorn

    from app.service.main import create_app

    given: dict[str, Any] = {
        "host": host, "port": port, "data_dir": data_dir, "database_url": database_url,
    }  # fmt: skip
    overrides = {k: v for k, v in given.items() if v is not None}
    if no_viewer:
        overrides["viewer_enabled"] = False
    try:
        settings = Settings(**overrides)
    except ValidationError as exc:
        typer.echo(f"error: bad setting: {exc}", err=True)
        raise typer.Exit(code=2) from None
    uvicorn.run(create_app(settings), **uvicorn_options(settings, log_level))


def uvicorn_options(settings: Settings, log_level: str = "info") -> dict[str, Any]:
    """How ``serve`` runs uvicorn (one worker); the benchmarks' baseline apps run the same."""
    return {
        "host": settings.host,
        "port": settings.port,
        "log_level": log_level,
        "ws_max_size": settings.max_body_bytes + 1024,
        "ws_per_message_deflate": False,  # compressing 100 kB frames costs more than it saves
    }
