"""Credentials: the admin key (``X-API-Key``) and per-session bearer tokens.

The admin key comes from settings, else from ``<data_dir>/admin_key``; if neither exists one is
generated, written with mode 0600 and shown once. Comparisons are constant-time.
"""

from __future__ import annotations

import hmac
import logging
import os
import re
import secrets
import stat
from pathlib import Path

from app.service.config import Settings

ADMIN_KEY_FILE = "admin_key"


class AuthError(Exception):
    """Missing (401) or wrong (403) credentials, with what to send instead."""

    def __init__(self, status: int, detail: str):
        super().__init__(detail)
        self.status = status
        self.detail = detail


def same_secret(given: str, expected: str) -> bool:
    """Constant-time comparison (``compare_digest`` takes ASCII text as it is; other text,
    which no key or token is, is compared as UTF-8)."""
    if given.isascii() and expected.isascii():
        return hmac.compare_digest(given, expected)
    return hmac.compare_digest(given.encode(), expected.encode())


def load_admin_key(settings: Settings) -> tuple[str, str | None]:
    """(key, message to show once or None). Creates the key file on first start."""
    if settings.admin_key is not None:
        return settings.admin_key.get_secret_value(), None
    path = settings.data_dir / ADMIN_KEY_FILE
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    key = secrets.token_urlsafe(32)
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except FileExistsError:
        return _read_key(path), None
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(key + "\n")
    return key, (
        f"Generated the admin key (send it as X-API-Key); stored in {path} (mode 0600), "
        f"shown only now: {key}"
    )


def _read_key(path: Path) -> str:
    mode = stat.S_IMODE(path.stat().st_mode)
    if mode & 0o077:
        path.chmod(0o600)  # readable by others: close it before use
    key = path.read_text(encoding="utf-8").strip()
    if not key:
        raise RuntimeError(f"{path} is empty: delete it to generate a new admin key")
    return key


def check_admin(given: str | None, expected: str) -> None:
    if not given:
        raise AuthError(401, "admin route: send the admin key in the X-API-Key header")
    if not same_secret(given, expected):
        raise AuthError(403, "the X-API-Key is not the admin key")


def check_session_token(given: str | None, expected: str, session_id: str) -> None:
    if not given:
        raise AuthError(
            401,
            "session route: send the session's token as 'Authorization: Bearer <token>' "
            "(or ?token=<token> on the websocket)",
        )
    if not same_secret(given, expected):
        raise AuthError(403, f"this token does not belong to session {session_id}")


_TOKEN = re.compile(r"([?&](?:token|api_key|key)=)[^&#\s]*", re.IGNORECASE)


def redact(text: str) -> str:
    """``text`` with the value of every ``token=`` (and ``key=``, ``api_key=``) query parameter
    replaced by ``***``."""
    return _TOKEN.sub(r"\1***", text)


class RedactTokens(logging.Filter):
    """Keeps secrets out of uvicorn's access log: a websocket URL carries its session token as
    ``?token=...`` (browsers cannot set headers on a websocket), and the access log writes
    every URL. Rewrites the record's arguments; never drops a record."""

    def filter(self, record: logging.LogRecord) -> bool:
        if isinstance(record.args, tuple) and record.args:
            record.args = tuple(redact(a) if isinstance(a, str) else a for a in record.args)
        elif isinstance(record.msg, str):
            record.msg = redact(record.msg)
        return True


def redact_access_log() -> None:
    """Install :class:`RedactTokens` on uvicorn's access and error loggers (once)."""
    for name in ("uvicorn.access", "uvicorn.error"):
        logger = logging.getLogger(name)
        if not any(isinstance(f, RedactTokens) for f in logger.filters):
            logger.addFilter(RedactTokens())
