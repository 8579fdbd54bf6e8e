"""``python -m app serve``: run the advice service with uvicorn."""

from __future__ import annotations

import errno
import logging
import os
import socket
import subprocess
import sys
import threading
from pathlib import Path
from typing import Annotated, Any

import typer

from app.cli.local import settings_or_exit
from app.cli.options import choice
from app.service.config import Settings
from app.service.logs import announce

#: uvicorn's log levels (``uvicorn.config.LOG_LEVELS``), checked before anything is created
LOG_LEVELS = ("critical", "error", "warning", "info", "debug", "trace")


def serve(
    host: Annotated[str | None, typer.Option(help="Interface (default 127.0.0.1).")] = None,
    port: Annotated[
        int | None, typer.Option(help="HTTP port of the API (default 8000; ADVISOR_PORT).")
    ] = None,
    viewer_port: Annotated[
        int | None,
        typer.Option(help="Port of the 3D viewer (default 8080; ADVISOR_VIEWER_PORT)."),
    ] = None,
    data_dir: Annotated[Path | None, typer.Option(help="SQLite file and admin key.")] = None,
    database_url: Annotated[
        str | None, typer.Option(help="SQLAlchemy URL, e.g. postgresql+psycopg://...")
    ] = None,
    no_viewer: Annotated[
        bool, typer.Option("--no-viewer", help="Do not start the viewer (its own process).")
    ] = False,
    workers: Annotated[
        int | None,
        typer.Option(help="Worker processes, one per core (default 1); more needs --redis-url."),
    ] = None,
    redis_url: Annotated[
        str | None,
        typer.Option(help="Redis for live sessions, e.g. redis://127.0.0.1:6379/0 (workers)."),
    ] = None,
    log_level: Annotated[str, choice(LOG_LEVELS, help="uvicorn's log level.")] = "info",
) -> None:
    """Run the advice service (settings also from ADVISOR_* environment variables)."""
    import uvicorn

    from app.service.main import create_app

    given: dict[str, Any] = {
        "host": host, "port": port, "viewer_port": viewer_port, "data_dir": data_dir,
        "database_url": database_url, "workers": workers, "redis_url": redis_url,
    }  # fmt: skip
    overrides = {k: v for k, v in given.items() if v is not None}
    if no_viewer:
        overrides["viewer_enabled"] = False
    settings = settings_or_exit(**overrides)
    busy = ports_taken(settings)
    if busy:  # before anything is created (the data directory, a new admin key)
        announce(f"error: {busy}", settings.log_format, logging.ERROR)
        raise typer.Exit(code=2)
    viewer = start_viewer(settings) if settings.viewer_enabled else None
    try:
        if settings.workers == 1:
            app = create_app(settings)
            app.state.viewer_process = viewer  # GET /viewer: whether it is still alive
            uvicorn.run(app, **uvicorn_options(settings, log_level))
        else:
            run_workers(settings, overrides, log_level, viewer)
    finally:
        if viewer is not None:
            viewer.terminate()
            try:
                viewer.wait(10)
            except subprocess.TimeoutExpired:
                viewer.kill()


def run_workers(
    settings: Settings,
    overrides: dict[str, Any],
    log_level: str,
    viewer: subprocess.Popen[bytes] | None = None,
) -> None:
    """``settings.workers`` processes on one port (uvicorn's supervisor, which starts a new
    one when one dies), sharing live sessions through Redis and data through the database.
    The first start (the default domain, the keys) happens here, once, before they start;
    each worker reads the settings from the environment."""
    import tempfile

    import uvicorn

    from app.service.routes.viewer import VIEWER_PID
    from app.service.state import open_state

    for name, value in overrides.items():
        os.environ[f"ADVISOR_{name.upper()}"] = str(value)
    if viewer is not None:  # GET /viewer in each worker: whether it is alive
        os.environ[VIEWER_PID] = str(viewer.pid)
        threading.Thread(target=viewer.wait, name="viewer-reaper", daemon=True).start()
    state, messages = open_state(settings)  # made once: the workers find it all there
    state.close()
    for message in messages:
        announce(message, settings.log_format)
    if settings.metrics_enabled and "PROMETHEUS_MULTIPROC_DIR" not in os.environ:
        # prometheus-client's multiprocess mode: each worker writes its samples there,
        # /metrics sums them (a fresh directory for every start)
        os.environ["PROMETHEUS_MULTIPROC_DIR"] = tempfile.mkdtemp(prefix="advisor-metrics-")
    options = uvicorn_options(settings, log_level)
    options["http"] = "app.service.worker_http:WorkerHttp"
    uvicorn.run("app.service.main:create_app", factory=True, workers=settings.workers, **options)


def start_viewer(settings: Settings) -> subprocess.Popen[bytes]:
    """``python -m app viewer`` for this service, in a process of its own: it reads the API on
    loopback with the operator key (in its environment, not on its command line) and exits
    with this process."""
    from app.service.security import load_operator_key

    key, message = load_operator_key(settings)  # made here if new: the service reads it too
    if message:
        announce(message, settings.log_format)
    api = f"http://127.0.0.1:{settings.port}"
    cmd = [
        sys.executable, "-m", "app", "viewer", "--api", api, "--host", settings.viewer_host,
        "--port", str(settings.viewer_port), "--parent", str(os.getpid()),
    ]  # fmt: skip
    for origin in settings.viewer_origins:
        cmd += ["--origin", origin]
    env = {"ADVISOR_OPERATOR_KEY": key, "ADVISOR_LOG_FORMAT": settings.log_format}  # its lines
    return subprocess.Popen(cmd, env=os.environ | env)


def ports_taken(settings: Settings) -> str | None:
    """Why ``serve`` cannot listen where the settings say (the API's port, and the viewer's
    when it starts one), naming the port, its option and its setting; or None."""
    if settings.viewer_enabled and settings.port == settings.viewer_port != 0:
        return (
            f"the API and the 3D viewer both want port {settings.port}: give the viewer "
            "another with --viewer-port or ADVISOR_VIEWER_PORT (or --no-viewer)"
        )
    api = port_taken(
        settings.host, settings.port, "--port or ADVISOR_PORT", "--host or ADVISOR_HOST"
    )
    if api:
        return api
    if not settings.viewer_enabled:
        return None
    viewer = port_taken(
        settings.viewer_host, settings.viewer_port,
        "--viewer-port or ADVISOR_VIEWER_PORT", "ADVISOR_VIEWER_HOST",
    )  # fmt: skip
    return f"the 3D viewer's {viewer}, or start no viewer with --no-viewer" if viewer else None


def port_taken(host: str, port: int, port_setting: str = "", host_setting: str = "") -> str | None:
    """Why ``host:port`` cannot be listened on (in use, or not an address here), saying which
    option or setting picks another (``port_setting``, ``host_setting``), or None."""
    if port == 0:
        return None
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as uvicorn binds
        try:
            sock.bind((host, port))
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                fix = f": stop it, or pick another port with {port_setting}" if port_setting else ""
                return f"port {port} on {host} is in use (another advisor?){fix}"
            fix = f": pick another interface with {host_setting}" if host_setting else ""
            return f"cannot listen on {host}:{port}: {exc.strerror or exc}{fix}"
    return None


def uvicorn_options(settings: Settings, log_level: str = "info") -> dict[str, Any]:
    """How ``serve`` runs uvicorn (one worker); the benchmarks' baseline apps run the same.
    HTTP goes through :mod:`app.service.guard` (bounded headers, read deadlines, caps on
    connections, in all and per client), and so do websocket handshakes (refusals as JSON);
    uvicorn's switch for X-Forwarded-For is off (it would trust any from 127.0.0.1): the app
    puts uvicorn's ProxyHeadersMiddleware in front of itself with the proxies the settings
    trust (:mod:`app.service.clients`)."""
    from app.service.guard import JsonWebSocket, guarded_http_of

    options: dict[str, Any] = {
        "host": settings.host,
        "port": settings.port,
        "log_level": log_level,
        "ws_max_size": settings.max_body_bytes + 1024,
        "ws_per_message_deflate": False,  # compressing 100 kB frames costs more than it saves
        "proxy_headers": False,
        "http": guarded_http_of(settings),
        "ws": JsonWebSocket,
    }
    if settings.log_format == "json":
        from app.service.logs import json_log_config

        options["log_config"] = json_log_config(log_level)
    return options
