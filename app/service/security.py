"""Credentials: the admin key and the read-only operator key (``X-API-Key``), per-session
bearer tokens.

Each key comes from settings, else from ``<data_dir>/admin_key`` (``operator_key``); if neither
exists one is generated and written there with mode 0600, and the log says where it is kept,
never the key itself (logs are read by more people than keys should be). Comparisons are
constant-time.
"""

from __future__ import annotations

import hashlib
import hmac
import logging
import os
import re
import secrets
import stat
from pathlib import Path
from typing import Literal

from pydantic import SecretStr

from app.service.config import Settings

ADMIN_KEY_FILE = "admin_key"
OPERATOR_KEY_FILE = "operator_key"


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
    """(key, message saying where a new one is kept, or None). Creates the key file on first
    start."""
    return load_key(settings.admin_key, settings.data_dir / ADMIN_KEY_FILE, "the admin key")


def load_operator_key(settings: Settings) -> tuple[str, str | None]:
    """The read-only operator key (live positions and paths, the viewer): as the admin key."""
    path = settings.data_dir / OPERATOR_KEY_FILE
    return load_key(settings.operator_key, path, "the read-only operator key")


def load_key(given: SecretStr | None, path: Path, what: str) -> tuple[str, str | None]:
    """``given``, else the key kept in ``path``, else a new one written there (mode 0600):
    (key, a message saying where it is kept, never the key, or None)."""
    if given is not None:
        return given.get_secret_value(), None
    path.parent.mkdir(parents=True, exist_ok=True)
    key = secrets.token_urlsafe(32)
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except FileExistsError:
        return _read_key(path), None
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(key + "\n")
    return key, (
        f"Generated {what} (send it as X-API-Key): kept in {path} (mode 0600, readable by "
        f"this user only); read it with: cat {path}"
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


def is_operator(given: str | None, admin: str, operator: str) -> bool:
    """Whether ``given`` (an X-API-Key, or None) may see live positions and paths: the admin
    key or the operator key. A key that is neither is refused (403), not taken as none."""
    if not given:
        return False
    if same_secret(given, admin) | same_secret(given, operator):  # both compared, always
        return True
    raise AuthError(403, "the X-API-Key is neither the admin key nor the operator key")


def key_role(given: str | None, admin: str, operator: str) -> Literal["admin", "operator"] | None:
    """Which key ``given`` is: ``admin``, ``operator`` (the read-only key) or None (no key); a
    key that is neither is refused (403), as :func:`is_operator` refuses it."""
    if not given:
        return None
    is_admin, is_op = same_secret(given, admin), same_secret(given, operator)  # both compared
    if is_admin:
        return "admin"
    if is_op:
        return "operator"
    raise AuthError(403, "the X-API-Key is neither the admin key nor the operator key")


def token_digest(token: str) -> bytes:
    """What a session keeps of its token: the SHA-256 of it (a session written to Redis or
    the database holds no token a reader could use)."""
    return hashlib.sha256(token.encode()).digest()


def check_session_token(given: str | None, expected: bytes, session_id: str) -> None:
    """``given`` is the token whose digest is ``expected`` (401 without one, 403 otherwise)."""
    if not given:
        raise AuthError(
            401,
            "session route: send the session's token as 'Authorization: Bearer <token>' "
            "(or ?token=<token> on the websocket)",
        )
    if not hmac.compare_digest(token_digest(given), expected):
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
