"""Where this machine's service is, as ``serve`` reads it: the commands that talk to a running
service (``simulate``, ``viewer``, ``domain put``) take their defaults from the same
``ADVISOR_*`` settings as ``serve`` (``ADVISOR_HOST``, ``ADVISOR_PORT``, ``ADVISOR_DATA_DIR``,
``ADVISOR_ADMIN_KEY``, ``ADVISOR_VIEWER_*``), so that one variable set once moves them all."""

from __future__ import annotations

import logging
import os
from typing import Any

import typer
from pydantic import ValidationError

from app.service.config import Settings
from app.service.logs import announce
from app.service.security import ADMIN_KEY_FILE

#: addresses that listen on every interface: a client on this machine calls loopback
ANY_ADDRESS = ("", "0.0.0.0", "::", "[::]")


def setting_errors(exc: ValidationError) -> str:
    """Pydantic's errors as ``name (ADVISOR_NAME): what``, one line each, without the
    "Value error," that pydantic puts before a validator's own message."""
    lines = []
    for e in exc.errors():
        name = ".".join(str(part) for part in e["loc"])
        what = e["msg"].removeprefix("Value error, ")
        lines.append(f"{name} (ADVISOR_{name.upper()}): {what}" if name else what)  # a rule of
        # several settings names them itself
    return "; ".join(lines)


def settings_or_exit(**overrides: Any) -> Settings:
    """The settings as ``serve`` reads them (``overrides`` from options, the rest from
    ``ADVISOR_*``); a bad one is one line on stderr and exit status 2."""
    try:
        return Settings(**{k: v for k, v in overrides.items() if v is not None})
    except ValidationError as exc:
        wanted = os.environ.get("ADVISOR_LOG_FORMAT", "text").lower()  # if valid itself
        announce(f"error: bad setting: {setting_errors(exc)}", wanted, logging.ERROR)
        raise typer.Exit(code=2) from None


def loopback(host: str) -> str:
    """The address a client on this machine calls for a server listening on ``host``."""
    if host in ANY_ADDRESS:
        return "127.0.0.1"
    return f"[{host}]" if ":" in host and not host.startswith("[") else host


def service_url(settings: Settings) -> str:
    """``http://ADVISOR_HOST:ADVISOR_PORT``: where ``serve`` with these settings listens."""
    return f"http://{loopback(settings.host)}:{settings.port}"


def admin_key(settings: Settings) -> str | None:
    """The admin key ``serve`` with these settings uses: ``ADVISOR_ADMIN_KEY``, else the one it
    keeps in ``<data_dir>/admin_key`` (None when neither exists; nothing is created)."""
    if settings.admin_key is not None:
        return settings.admin_key.get_secret_value()
    path = settings.data_dir / ADMIN_KEY_FILE
    try:
        return path.read_text(encoding="utf-8").strip() or None
    except OSError:
        return None


#: how a command's --help names its default URL
URL_HELP = "default: http://ADVISOR_HOST:ADVISOR_PORT, as serve listens: http://127.0.0.1:8000"
