"""``python -m app viewer``: the 3D viewer, a process of its own reading a running service.

``serve`` starts it (unless ``--no-viewer``); it can also run by itself, beside a service
started elsewhere. It reads the service as a client (``app.viewer.remote``) with the operator
key, from ``ADVISOR_OPERATOR_KEY`` or a key file (never the command line, which others can
read), and serves the scene to browsers on loopback unless told otherwise: it shows where
explorers are and were, and asks no key of a browser.
"""

from __future__ import annotations

import logging
import os
import signal
import threading
from pathlib import Path
from typing import Annotated

import typer

from app.cli.local import URL_HELP, service_url, settings_or_exit

LOOPBACK = ("127.0.0.1", "localhost", "::1")
KEY_ENV = "ADVISOR_OPERATOR_KEY"


def viewer(
    api: Annotated[str | None, typer.Option(help=f"The service's URL ({URL_HELP}).")] = None,
    host: Annotated[
        str | None,
        typer.Option(help="Interface for browsers (default: ADVISOR_VIEWER_HOST, 127.0.0.1)."),
    ] = None,
    port: Annotated[
        int | None, typer.Option(help="Port for browsers (default: ADVISOR_VIEWER_PORT, 8080).")
    ] = None,
    key_file: Annotated[
        Path | None,
        typer.Option(help=f"File holding the operator key (default: ${KEY_ENV})."),
    ] = None,
    parent: Annotated[
        int | None, typer.Option(help="Exit when this process (the service) is gone.")
    ] = None,
    origin: Annotated[
        list[str] | None,
        typer.Option(
            help="Origin of a page a browser may open the viewer from, beyond its own "
            "address's (loopback ones for a loopback or 0.0.0.0 host), e.g. "
            "http://127.0.0.1:9090; repeat for more (default: ADVISOR_VIEWER_ORIGINS)."
        ),
    ] = None,
) -> None:
    """Serve the live 3D viewer of a running service (read with the operator key)."""
    import httpx

    from app.service.config import page_origin
    from app.service.logs import announce, json_logging
    from app.viewer.remote import RemoteFeed
    from app.viewer.viewer import Viewer

    log_format = os.environ.get("ADVISOR_LOG_FORMAT", "text").lower()  # as the service's

    def say(message: str, level: int = logging.INFO) -> None:
        announce(message, log_format, level, logger="app.viewer")

    try:
        origins = tuple(page_origin(o) for o in origin or ())
    except ValueError as exc:
        say(f"error: --origin: {exc}", logging.ERROR)
        raise typer.Exit(code=2) from None
    settings = settings_or_exit(viewer_host=host, viewer_port=port)  # what serve reads
    api = api or service_url(settings)
    host, port = settings.viewer_host, settings.viewer_port
    origins = origins or tuple(settings.viewer_origins)
    key = key_file.read_text(encoding="utf-8").strip() if key_file else os.environ.get(KEY_ENV)
    if not key:
        say(f"error: no operator key: set {KEY_ENV} or give --key-file", logging.ERROR)
        raise typer.Exit(code=2)
    if log_format == "json":
        json_logging()
        import rich

        # viser prints a banner and "Server stopped" with rich on stdout, whatever its
        # ``verbose``: not JSON, and the viewer's own lines say as much
        rich.reconfigure(file=open(os.devnull, "w"))  # noqa: SIM115  (for the process's life)
    else:
        logging.basicConfig(level=logging.INFO, format="viewer: %(message)s")
    http = httpx.Client(base_url=api, timeout=30.0)
    feed = RemoteFeed(http, key)
    view = Viewer(feed, host=host, port=port, on_tick=feed.report_tick, origins=origins)
    view.start()
    if view.port != port:
        view.stop()
        say(f"error: the viewer's port {port} is busy", logging.ERROR)
        raise typer.Exit(code=1)
    where = (
        "loopback only: it shows where explorers are and asks no key of a browser"
        if host in LOOPBACK
        else "NOT loopback: anyone who reaches this port sees where explorers are"
    )
    say(f"viewer on http://{host}:{view.port}/ ({where})")
    done = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: done.set())
    while not done.wait(1.0):
        if parent is not None and os.getppid() != parent:
            break  # the service is gone (killed): so is its viewer
    view.stop()
    http.close()
