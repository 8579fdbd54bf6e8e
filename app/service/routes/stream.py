"""``WS /sessions/{id}/stream``: events in (one or a list per text frame), decisions out.

Credentials: an ``Authorization: Bearer`` header, or, from a browser (which can set no header on
a websocket), the subprotocols ``advisor`` and ``token.<session token>`` (the server answers
``advisor``); ``?token=<session token>`` is still accepted, but a URL is what logs and proxies
keep (the service's own log writes ``token=***``). The connection is accepted first, so that a
refusal can say why: it is closed with code 4401 (no token), 4403 (another session's token) or
4404 (no such session), 4410 (the session was lost: Redis came back without its data), and
the reason in the close frame; when Redis (or the database) does not answer, with 1013 (try
again later) and a reason naming it.

Each text frame gets exactly one answer frame, in order: the decisions (an object for one event,
a list for a list), or for a bad frame an error ``{"detail": "...", "status": 422}`` (413 for
too many events or bytes, 409 for a step out of turn; 503 with ``retry_after``, in seconds,
when Redis or the database does not answer); a refused frame changes nothing and the
connection stays usable. Events carrying ``step`` are answered as on the REST route: a client
that reconnects resends its unanswered frames with their steps, and those already applied are
answered again, not applied twice. If
the session ends or expires while connected, the next frame closes the connection with 4404.

With ``?format=binary`` the decisions come as one binary frame per text frame instead (the
same decisions in about a tenth of the bytes, with no per-decision formatting: the layout is
in :mod:`advisor_client.protocol`); errors are still JSON text frames. Another ``format`` closes the
connection with 4422.
"""

from __future__ import annotations

import json
import logging

from fastapi import APIRouter, WebSocket, WebSocketDisconnect
from starlette.websockets import WebSocketState

from app.service import ops
from app.service.deps import service_of
from app.service.errors import (
    DATABASE_DOWN,
    DATABASE_DOWN_TEXT,
    DATABASE_RETRY_AFTER,
    STORE_DOWN,
    store_down_detail,
)
from app.service.live.faults import RETRY_AFTER, SessionLost
from app.service.live.registry import LiveSession, SessionNotFound
from app.service.problems import BadInput
from app.service.security import AuthError, check_session_token
from app.service.state import ServiceState

router = APIRouter(tags=["sessions"])
log = logging.getLogger("advisor.stream")
SUBPROTOCOL, TOKEN_PREFIX = "advisor", "token."
CLOSE_REASONS = {  # a close reason holds at most 123 bytes
    4401: "no token: send Authorization: Bearer <token>, or subprotocols advisor, token.<token>",
    4403: "this token does not belong to this session",
    4404: "no live session with this id (never created, ended or expired)",
    4410: "the live session was lost: Redis came back without its data; start a new session",
    4422: "format must be json (the default) or binary",
    1013: "the live sessions are kept in Redis, which does not answer now: connect again",
}
#: 1013 (try again later) when the database does not answer
DATABASE_CLOSE_REASON = "the database does not answer now: connect again"
FORMATS = ("json", "binary")


def offered_token(ws: WebSocket) -> str | None:
    """The token offered as the subprotocol ``token.<token>`` (browsers can set no header on
    a websocket; a subprotocol stays out of URLs and access logs)."""
    for value in ws.headers.getlist("sec-websocket-protocol"):
        for offered in value.split(","):
            name = offered.strip()
            if name.startswith(TOKEN_PREFIX):
                return name[len(TOKEN_PREFIX) :] or None
    return None


async def _authorize(state: ServiceState, session_id: str, ws: WebSocket) -> LiveSession:
    token = offered_token(ws)
    header = ws.headers.get("authorization", "")
    if not token and header.lower().startswith("bearer "):
        token = header[7:].strip()
    if not token:
        token = ws.query_params.get("token")
    if not token:
        check_session_token(None, b"", session_id)
    session = await state.sessions.get(session_id)
    check_session_token(token, session.token_digest, session_id)
    return session


def _error(status: int, detail: str, **extra: object) -> str:
    return json.dumps({"detail": detail, "status": status, **extra})


@router.websocket("/sessions/{session_id}/stream")
async def stream(websocket: WebSocket, session_id: str) -> None:
    try:
        await _serve(websocket, session_id)
    except WebSocketDisconnect:  # the client went away before its answer: nothing to say
        return


async def _serve(websocket: WebSocket, session_id: str) -> None:
    state = service_of(websocket)
    # a browser offering subprotocols needs one of them back (never the token's)
    offered = {p.strip() for v in websocket.headers.getlist("sec-websocket-protocol")
               for p in v.split(",")}  # fmt: skip
    await websocket.accept(SUBPROTOCOL if SUBPROTOCOL in offered else None)
    try:
        session = await _authorize(state, session_id, websocket)
    except (AuthError, SessionNotFound) as exc:
        code = 4400 + exc.status % 100 if isinstance(exc, AuthError) else 4404
        code = 4410 if isinstance(exc, SessionLost) else code
        await websocket.close(code, CLOSE_REASONS[code])
        return
    except STORE_DOWN as exc:  # 1013: try again later
        log.debug("Redis does not answer: %s", exc)
        await websocket.close(1013, CLOSE_REASONS[1013])
        return
    except DATABASE_DOWN as exc:
        log.debug("the database does not answer: %s", exc)
        await websocket.close(1013, DATABASE_CLOSE_REASON)
        return
    answer_format = websocket.query_params.get("format", "json")
    if answer_format not in FORMATS:
        await websocket.close(4422, CLOSE_REASONS[4422])
        return
    binary = answer_format == "binary"
    limit = state.settings.max_body_bytes
    while True:
        message = await websocket.receive()
        if message["type"] == "websocket.disconnect":
            return
        text = message.get("text")
        if text is None:
            await websocket.send_text(_error(422, "send events as JSON text frames, not binary"))
            continue
        if len(text) > limit:
            await websocket.send_text(_error(413, f"the message is larger than {limit} bytes"))
            continue
        try:
            answer = await ops.answer_events(state, session, text, binary)
            if binary:
                await websocket.send_bytes(answer)
            else:  # JSON is ASCII: decoding it is a copy
                await websocket.send_text(answer.decode())
        except BadInput as exc:
            await websocket.send_text(_error(exc.status, exc.detail))
        except STORE_DOWN as exc:  # not applied (or not known to be): send the frame again
            log.debug("Redis does not answer: %s", exc)
            detail = store_down_detail(exc)
            await websocket.send_text(_error(503, detail, retry_after=RETRY_AFTER))
        except DATABASE_DOWN as exc:
            log.debug("the database does not answer: %s", exc)
            text = _error(503, DATABASE_DOWN_TEXT, retry_after=DATABASE_RETRY_AFTER)
            await websocket.send_text(text)
        except SessionNotFound as exc:
            code = 4410 if isinstance(exc, SessionLost) else 4404
            if websocket.client_state == WebSocketState.CONNECTED:
                await websocket.close(code, CLOSE_REASONS[code])
            return
