from __future__ import annotations

import re
from typing import Annotated, Any

from fastapi import APIRouter, Body, FastAPI, Query, Request, Response
from fastapi.routing import APIRoute
from starlette.types import ASGIApp, Receive, Scope, Send

from app.service import ops
from app.service.deps import (
    BEARER,
    SESSION_ID_PATTERN,
    DomainDep,
    OperatorDep,
    SessionDep,
    SessionId,
    SessionOrAdminDep,
    SessionOrOperatorDep,
    StateDep,
    client_of,
    service_of,
    session_for,
)
from app.service.openapi import body
from app.service.public import session_created, session_public
from app.service.schemas import (
    DecisionPublic,
    ErrorPublic,
    MuteIn,
    PositionsIn,
    SessionCreate,
    SessionCreated,
    SessionList,
    SessionPublic,
)

router = APIRouter(tags=["sessions"])
ERRORS: dict[int | str, dict[str, Any]] = {
    code: {"model": ErrorPublic} for code in (401, 403, 404, 422)
}


@router.post(
    "/domains/{name}/sessions",
    status_code=201,
    responses={code: {"model": ErrorPublic} for code in (400, 404, 413, 415, 422, 429, 503)},
)
async def create_session(
    request: Request,
    domain: DomainDep,
    state: StateDep,
    body: Annotated[SessionCreate | None, Body()] = None,
) -> SessionCreated:
    """Start watching an explorer: returns its id, its token (keep it: every session route
    needs it) and the decision for its start cell."""
    body = body or SessionCreate()
    client = client_of(request, state)
    session, decision = await ops.open_session(state, domain, body, client)
    return session_created(session, decision)


async def post_events(request: Request, session_id: SessionId) -> Response:
    """One event, or a list: the decision for each, in order (one object for one event). A
    batch with a bad event is refused whole and changes nothing. Events may carry ``step``
    (the first event of a session is step 1): a retry of steps already applied is answered
    with their decisions and applies nothing; a step beyond the next one, or one applied with
    another move, is 409."""
    state = service_of(request)
    session = await session_for(request, session_id, state)  # not a dependency: see there
    text = await ops.answer_events(state, session, await request.body())
    return Response(text, media_type="application/json")


EVENTS_PATH = "/sessions/{session_id}/events"
#: ``SESSION_ID_PATTERN`` for ``fullmatch`` (``$`` would let a final newline through)
_SESSION_ID = re.compile(SESSION_ID_PATTERN.removeprefix("^").removesuffix("$"))


def add_event_route(app: FastAPI) -> None:
    """``POST /sessions/{session_id}/events`` on the app's own router rather than through an
    included one: FastAPI matches the routes of an included router in extra steps on every
    request (measured: about 50 of 275 us of CPU per one-event request). The route answers
    through :class:`DirectEvents` (FastAPI still documents it)."""
    app.add_api_route(
        EVENTS_PATH,
        post_events,
        methods=["POST"],
        tags=["sessions"],
        response_model=DecisionPublic | list[DecisionPublic],
        openapi_extra=body("Events") | BEARER,
        responses=ERRORS | {code: {"model": ErrorPublic} for code in (409, 413, 415)},
    )
    route = app.router.routes[-1]
    assert isinstance(route, APIRoute) and route.path == EVENTS_PATH
    route.app = DirectEvents(route.app)


class DirectEvents:
    """The event route's ASGI app: :func:`post_events` called at once for a valid session id.
    FastAPI's own handler (``framework``) resolves the route's parameters on every request (a
    Request, the query string, the path parameter through pydantic, two exit stacks, exception
    handling of its own): 60-67 us of CPU of a one-event request's 222-253 in process
    (docs/PERFORMANCE.md, "REST at 0.85 of bare FastAPI"). The same checks stay: the route's
    method was checked before (405); an id that is not ``SESSION_ID_PATTERN`` goes to
    ``framework``, which answers its 422, and so does every request while FastAPI's telemetry
    is on (it records the endpoint there); errors reach the same exception handlers (the
    app's own layer catches them). tests/service/test_routes_sessions.py compares both."""

    def __init__(self, framework: ASGIApp) -> None:
        self.framework = framework

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        session_id = scope["path_params"]["session_id"]
        if _SESSION_ID.fullmatch(session_id) is None or scope.get("fastapi.telemetry"):
            await self.framework(scope, receive, send)
            return
        response = await post_events(Request(scope, receive, send), session_id)
        await response(scope, receive, send)


@router.post(
    "/sessions/{session_id}/positions",
    response_model=list[DecisionPublic],
    openapi_extra=BEARER,
    # 400: a body that is not readable JSON (not UTF-8, nested too deeply), as FastAPI reads it
    responses=ERRORS | {code: {"model": ErrorPublic} for code in (400, 413, 415)},
)
async def post_positions(session: SessionDep, body: PositionsIn, state: StateDep) -> Response:
    """Positions in metres (domains with a resolution): each reading is snapped to its cell; a
    reading in the same cell as the one before adds no move, one up to ``max_jump`` moves away
    (ADVISOR_MAX_JUMP, default 8) is walked along a shortest path, one decision per cell; a
    farther jump, a wall or a point off the map refuses the batch whole (422)."""
    text = await ops.apply_positions(state, session, body)
    return Response(text, media_type="application/json")


@router.post(
    "/sessions/{session_id}/mute",
    openapi_extra=BEARER,
    # 400: a body that is not readable JSON, as FastAPI reads it
    responses=ERRORS | {code: {"model": ErrorPublic} for code in (400, 413, 415)},
)
async def mute_session(
    session: SessionDep, state: StateDep, body: Annotated[MuteIn | None, Body()] = None
) -> SessionPublic:
    """The visitor asks for no more advice (``{"muted": true}``, the default) or for advice
    again (``{"muted": false}``): while muted, no decision advises (the advisor still watches,
    and its figures go on). Its token only."""
    await state.sessions.mute(session, (body or MuteIn()).muted)
    return session_public(await state.sessions.describe(session))


@router.get("/sessions/{session_id}", responses=ERRORS)
async def read_session(session: SessionOrOperatorDep, state: StateDep) -> SessionPublic:
    """The session's figures (its token, or the admin or operator key)."""
    return session_public(await state.sessions.describe(session))


@router.delete("/sessions/{session_id}", responses=ERRORS)
async def end_session(session: SessionOrAdminDep, state: StateDep) -> SessionPublic:
    """End the session; returns its final figures."""
    return session_public(await state.sessions.end(session))


@router.get("/sessions", dependencies=[OperatorDep], responses=ERRORS)
async def list_sessions(
    state: StateDep,
    limit: Annotated[int, Query(ge=1, le=10_000)] = 100,
    domain: Annotated[str | None, Query(max_length=64)] = None,
) -> SessionList:
    """Live sessions, most recently active first (the admin or the operator key)."""
    sessions = state.sessions
    total = await sessions.count() if domain is None else (
        (await sessions.count_by_domain()).get(domain, 0)
    )  # fmt: skip
    listed = await sessions.snapshot(limit, domain)
    return SessionList(total=total, sessions=[session_public(s) for s in listed])
