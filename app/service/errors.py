"""Every client error as a 4xx JSON body ``{"detail": "..."}`` that says what was wrong.

* request validation: 422, ``detail`` one readable line (``where: what``), ``errors`` the list;
* our own checks (:class:`BadInput`), unknown domains/sessions, credentials: their status;
* bodies over the limit: 413 from :class:`BodyLimit` before the app reads them, bodies that say
  they are not JSON (a ``Content-Type`` other than ``application/json``; a form, what ``curl
  -d`` sends, says so and how to send JSON): 415, but for a map file's text (``text/plain``) to
  ``PUT /domains/{name}``;
* JSON nested too deeply for the parser: 400 (instead of the RecursionError's 500);
* a websocket to a path without a websocket route: 404 (:class:`NoWebSocketRoute`);
* Redis failing (:class:`~app.service.live.faults.RedisDown`) or the database not answering:
  503 with ``Retry-After``, the body naming which; a session lost with Redis' data: 410.
"""

from __future__ import annotations

import logging
import re
import time
from collections.abc import Callable
from typing import Any

from fastapi import FastAPI, Request, Response
from fastapi.exception_handlers import http_exception_handler
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from redis.exceptions import ConnectionError as RedisConnectionError
from redis.exceptions import TimeoutError as RedisTimeoutError
from sqlalchemy import exc as sa_exc
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.requests import ClientDisconnect
from starlette.routing import WebSocketRoute
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from app.service.data.domains import DomainChanged, DomainNotFound
from app.service.data.store import COUNT_MAX, CountsFull
from app.service.live.faults import RETRY_AFTER, RedisDown, SessionLost
from app.service.live.lanes import LaneError
from app.service.live.registry import SessionNotFound, SessionUnreadable
from app.service.live.sessions import StoreUnavailable
from app.service.problems import BadInput, describe_errors
from app.service.security import AuthError

log = logging.getLogger("advisor.errors")


def _json(
    status: int, detail: str, headers: dict[str, str] | None = None, **extra: Any
) -> JSONResponse:
    if status == 401:
        headers = (headers or {}) | {"WWW-Authenticate": "Bearer"}
    return JSONResponse({"detail": detail, **extra}, status_code=status, headers=headers)


def allowed_methods(app: FastAPI, path: str) -> list[str]:
    """Every documented method of the path (Starlette's own 405 names only the methods of
    the first route that matched the path)."""
    patterns: list[tuple[re.Pattern[str], list[str]]] | None = getattr(app.state, "allow", None)
    if patterns is None:
        patterns = [
            (re.compile("^" + re.sub(r"\{[^/]+\}", "[^/]+", template) + "$"), sorted(ops))
            for template, ops in app.openapi()["paths"].items()
        ]
        app.state.allow = patterns
    return [m.upper() for pattern, ops in patterns if pattern.match(path) for m in ops]


async def _http_error(request: Request, exc: Exception) -> Response:
    assert isinstance(exc, StarletteHTTPException)
    unreadable = _unreadable_body(request, exc.__cause__) if exc.status_code == 400 else None
    if unreadable is not None:
        return unreadable
    if exc.status_code == 405:
        allowed = allowed_methods(request.app, request.url.path)
        if allowed:
            detail = f"{request.method} is not allowed here: use {', '.join(allowed)}"
            return _json(405, detail, headers={"Allow": ", ".join(allowed)})
    return await http_exception_handler(request, exc)


def _unreadable_body(request: Request, cause: BaseException | None) -> JSONResponse | None:
    """Why FastAPI could not read a JSON body (it answers every such failure with one vague
    400): over the size limit while it was still arriving (413), nested too deeply for the
    parser, or not text."""
    if isinstance(cause, _TooLarge):
        limit = request.app.state.settings.max_body_bytes
        return _json(413, f"the request body is larger than {limit} bytes")
    if isinstance(cause, RecursionError):
        return _json(400, TOO_DEEP)
    if isinstance(cause, UnicodeDecodeError):
        return _json(400, f"the JSON body is not valid UTF-8 text: {cause.reason}")
    if isinstance(cause, ValueError) and "digits" in str(cause):  # Python's int() limit
        return _json(422, TOO_MANY_DIGITS)
    return None


async def _validation(_: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, RequestValidationError)
    errors = list(exc.errors())
    listed = [{"loc": list(e["loc"]), "msg": e["msg"], "type": e["type"]} for e in errors[:20]]
    return _json(422, describe_errors(errors), errors=listed)


async def _bad_input(_: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, BadInput)
    return _json(exc.status, exc.detail, exc.headers)


async def _auth(_: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, AuthError)
    return _json(exc.status, exc.detail)


async def _no_domain(_: Request, exc: Exception) -> JSONResponse:
    return _json(404, f"no domain named {exc.args[0]!r} (GET /domains lists them)")


async def _no_session(_: Request, exc: Exception) -> JSONResponse:
    return _json(404, f"no live session {exc.args[0]!r} (it never existed, ended or expired)")


async def _unreadable(_: Request, exc: Exception) -> JSONResponse:
    return _json(
        410,
        f"live session {exc.args[0]!r} was kept by a version of this service that this one "
        f"cannot read ({exc.args[1]}): start a new session",
    )


async def _lost(_: Request, exc: Exception) -> JSONResponse:
    return _json(410, lost_detail(exc.args[0]))


def lost_detail(session_id: str) -> str:
    return (
        f"live session {session_id!r} was lost: Redis, where live sessions are kept, came "
        "back without its data; start a new session"
    )


async def _domain_changed(_: Request, exc: Exception) -> JSONResponse:
    return _json(
        409,
        f"the map of domain {exc.args[0]!r} was replaced by another while these trajectories "
        "were on their way; nothing was stored: check them against the new map and send again",
    )


#: what Redis failing looks like (the live sessions' store, with workers): RedisDown, and
#: the errors it stands for should one reach a route as it is
STORE_DOWN: tuple[type[Exception], ...] = (
    StoreUnavailable, RedisConnectionError, RedisTimeoutError, LaneError,
)  # fmt: skip


def store_down_detail(exc: BaseException) -> str:
    """The words of a 503 for Redis failing: what failed, what was applied, what to do."""
    why = exc.why if isinstance(exc, RedisDown) else (str(exc) or type(exc).__name__)
    return (
        f"the live sessions are kept in Redis, which does not answer now ({why}): the request "
        "was not applied (or, if Redis stopped in the middle of it, is not known to be): send "
        f"it again in {RETRY_AFTER} s (events carrying their step are applied once)"
    )


async def _store_down(_: Request, exc: Exception) -> JSONResponse:
    _now_and_then("Redis does not answer: %s", exc)
    return _json(503, store_down_detail(exc), headers={"Retry-After": str(RETRY_AFTER)})


#: the database not answering (PostgreSQL down or past ADVISOR_DATABASE_TIMEOUT, a pool with
#: no connection free in time, SQLite locked past its wait)
DATABASE_DOWN: tuple[type[Exception], ...] = (
    sa_exc.OperationalError, sa_exc.InterfaceError, sa_exc.TimeoutError,
)  # fmt: skip
DATABASE_RETRY_AFTER = 2
DATABASE_DOWN_TEXT = (
    "the database does not answer now: send the request again in a few seconds (nothing is "
    "acknowledged before the database has stored it)"
)


async def _database_down(_: Request, exc: Exception) -> JSONResponse:
    cause = getattr(exc, "orig", None) or exc
    _now_and_then("the database does not answer: %s", f"{type(cause).__name__}: {cause}")
    return _json(503, DATABASE_DOWN_TEXT, headers={"Retry-After": str(DATABASE_RETRY_AFTER)})


_logged: dict[str, float] = {}


def _now_and_then(message: str, arg: object, every: float = 10.0) -> None:
    """A warning at most every ``every`` seconds per message (a store that is down refuses
    every request: one line says it)."""
    now = time.monotonic()
    if now - _logged.get(message, -every) >= every:
        _logged[message] = now
        text = str(arg).strip().splitlines()
        log.warning(message, text[0][:300] if text else type(arg).__name__)


async def _counts_full(_: Request, exc: Exception) -> JSONResponse:
    return _json(
        409,
        f"the stored counts of prior table {exc.args[0]!r} would pass {COUNT_MAX} (they are "
        "32-bit): nothing was stored",
    )


TOO_DEEP = "the JSON body is nested too deeply to parse"
TOO_MANY_DIGITS = (
    "the JSON body holds an integer of more than 4300 digits: no field takes one (a window, "
    "a cell or a parameter is a few digits long)"
)


async def _too_deep(_: Request, exc: Exception) -> JSONResponse:
    return _json(400, TOO_DEEP)


async def _gone(_: Request, exc: Exception) -> Response:
    """The client disconnected while its body was arriving: no one to answer (and nothing to
    log: a client may hang up whenever it likes)."""
    return Response(status_code=400)


def install_error_handlers(app: FastAPI) -> None:
    handlers: dict[type[Exception], Callable[..., Any]] = {
        StarletteHTTPException: _http_error,
        RequestValidationError: _validation,
        BadInput: _bad_input,
        AuthError: _auth,
        DomainNotFound: _no_domain,
        DomainChanged: _domain_changed,
        SessionNotFound: _no_session,
        SessionUnreadable: _unreadable,
        SessionLost: _lost,
        RecursionError: _too_deep,
        ClientDisconnect: _gone,
        CountsFull: _counts_full,
    }
    for exc, handler in handlers.items():
        app.add_exception_handler(exc, handler)
    for unavailable in STORE_DOWN:
        app.add_exception_handler(unavailable, _store_down)
    for unavailable in DATABASE_DOWN:
        app.add_exception_handler(unavailable, _database_down)


class _TooLarge(Exception):
    pass


BODY_METHODS = frozenset({"POST", "PUT", "PATCH"})
NOT_JSON = (
    "every request body is JSON: send it with 'Content-Type: application/json' (or without a "
    "Content-Type)"
)
FORM = (
    "this route reads JSON, and this body came as a form (Content-Type: "
    "application/x-www-form-urlencoded, which curl -d sends unless told otherwise): add "
    "-H 'Content-Type: application/json'"
)
#: the route that also reads a text body (PUT /domains/{name}: a map file as it is)
TEXT_ROUTE = re.compile(r"^/domains/[^/]+$")
MAP_FILE = (
    "; or send the map file as it is: -H 'Content-Type: text/plain' --data-binary @MAP.txt "
    "(curl -d drops its line breaks)"
)


def _media(kind: bytes) -> bytes:
    return kind.split(b";", 1)[0].strip().lower()


def _not_json(kind: bytes, scope: Scope) -> str | None:
    """Why a body of type ``kind`` is refused here (415), or None: JSON goes everywhere, a
    map file's text (text/plain) to PUT /domains/{name}."""
    if _is_json(kind):
        return None
    text_route = scope["method"] == "PUT" and TEXT_ROUTE.match(scope["path"]) is not None
    media = _media(kind)
    if text_route and media == b"text/plain":
        return None
    detail = FORM if media == b"application/x-www-form-urlencoded" else NOT_JSON
    return detail + (MAP_FILE if text_route else "")


def _is_json(kind: bytes) -> bool:
    """``application/json`` or a ``+json`` type, with any parameters (``; charset=utf-8``)."""
    media = _media(kind)
    return media == b"application/json" or (
        media.startswith(b"application/") and media.endswith(b"+json")
    )


class BodyLimit:
    """Refuse request bodies over ``max_bytes`` with 413, by Content-Length when given and by
    counting otherwise (chunked uploads)."""

    def __init__(self, app: ASGIApp, max_bytes: int):
        self.app = app
        self.max_bytes = max_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = dict(scope["headers"])
        kind = headers.get(b"content-type")
        if kind is not None and scope["method"] in BODY_METHODS:
            refused = _not_json(kind, scope)
            if refused is not None:
                await _json(415, refused)(scope, receive, send)
                return
        length = headers.get(b"content-length")
        if length is not None:
            if not length.isdigit() or int(length) > self.max_bytes:
                await self._refuse(scope, receive, send, length.isdigit())
                return
            # the server reads exactly Content-Length bytes: nothing to count (this keeps the
            # hot path free of two wrappers per message)
            await self.app(scope, receive, send)
            return
        seen = 0
        started = False

        async def counted() -> Message:
            nonlocal seen
            message = await receive()
            seen += len(message.get("body", b""))
            if seen > self.max_bytes:
                raise _TooLarge
            return message

        async def tracked(message: Message) -> None:
            nonlocal started
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, counted, tracked)
        except _TooLarge:
            if started:
                raise
            await self._refuse(scope, receive, send, True)

    async def _refuse(self, scope: Scope, receive: Receive, send: Send, too_large: bool) -> None:
        if too_large:
            response = _json(413, f"the request body is larger than {self.max_bytes} bytes")
        else:
            response = _json(400, "the Content-Length header is not a number")
        await response(scope, receive, send)


class NoWebSocketRoute:
    """A websocket to a path that no websocket route serves is answered 404
    ``{"detail": "no websocket route at /path"}``. Starlette's router (and its static files)
    close it before accepting, which uvicorn sends as 403 with an empty body; this answers
    such a close with HTTP instead, where the server can (the ASGI "websocket.http.response"
    extension, which uvicorn has). A close before accepting from a websocket route stands."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "websocket" or "websocket.http.response" not in scope.get(
            "extensions", {}
        ):
            await self.app(scope, receive, send)
            return
        first = True

        async def answer(message: Message) -> None:
            nonlocal first
            if first:
                first = False
                routed = isinstance(scope.get("route"), WebSocketRoute)
                if message["type"] == "websocket.close" and not routed:
                    detail = f"no websocket route at {scope['path']}"
                    await _json(404, detail)(scope, receive, send)
                    return
            await send(message)

        await self.app(scope, receive, answer)
