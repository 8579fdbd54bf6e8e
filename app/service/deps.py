"""Typed dependencies: route signatures read as plain typed parameters.

They only look things up in memory, so they are ``async``: FastAPI runs sync dependencies in
its threadpool, and the thread hops cost more than the lookups."""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from typing import Annotated, Any, Literal

from fastapi import Depends, Path
from fastapi.security import APIKeyHeader, HTTPAuthorizationCredentials, HTTPBearer
from starlette.requests import HTTPConnection

from app.service.clients import client_address
from app.service.data.domains import DomainState
from app.service.live.registry import LiveSession
from app.service.schemas import NAME_PATTERN
from app.service.security import (
    AuthError,
    check_admin,
    check_session_token,
    is_operator,
    key_role,
    same_secret,
)
from app.service.state import ServiceState

SESSION_ID_PATTERN = r"^[A-Za-z0-9_-]{1,64}$"
Role = Literal["admin", "operator"]
#: ``openapi_extra`` for routes that check the bearer token through :func:`get_session`.
BEARER: dict[str, Any] = {"security": [{"HTTPBearer": []}]}

api_key_header = APIKeyHeader(
    name="X-API-Key", auto_error=False,
    description="The admin key; on routes that read live sessions, or the operator key.",
)  # fmt: skip
bearer = HTTPBearer(auto_error=False, description="The session's token.")


def service_of(conn: HTTPConnection) -> ServiceState:
    state: ServiceState = conn.app.state.service
    return state


async def get_state(conn: HTTPConnection) -> ServiceState:
    return service_of(conn)


StateDep = Annotated[ServiceState, Depends(get_state)]
DomainName = Annotated[str, Path(pattern=NAME_PATTERN, description="Domain name.")]
SessionId = Annotated[str, Path(pattern=SESSION_ID_PATTERN, description="Session id.")]


async def require_admin(
    state: StateDep, key: Annotated[str | None, Depends(api_key_header)] = None
) -> None:
    check_admin(key, state.admin_key)


async def operator_view(
    state: StateDep, key: Annotated[str | None, Depends(api_key_header)] = None
) -> Role | None:
    """Which key the caller sent: ``admin`` or ``operator`` (the read-only key: both may see
    live positions and paths), None without one (403 for a key that is neither)."""
    return key_role(key, state.admin_key, state.operator_key)


async def require_operator(
    state: StateDep, key: Annotated[str | None, Depends(api_key_header)] = None
) -> None:
    if not key:
        raise AuthError(401, "send the admin key or the read-only operator key as X-API-Key")
    is_operator(key, state.admin_key, state.operator_key)


async def get_domain(name: DomainName, state: StateDep) -> DomainState:
    return await state.sessions.domain(name)


def bearer_token(conn: HTTPConnection) -> str | None:
    """The token of an ``Authorization: Bearer <token>`` header, if there is one (the first
    such header, as ``conn.headers.get`` gives it; read from the raw ASGI headers, which
    skips building a ``Headers`` object on the event route)."""
    for key, value in conn.scope["headers"]:
        if key == b"authorization":
            scheme, _, token = value.decode("latin-1").partition(" ")
            if scheme.lower() != "bearer":
                return None
            return token.strip() or None
    return None


async def get_session(conn: HTTPConnection, session_id: SessionId) -> LiveSession:
    """The session, if the bearer token is its own (401 without one, 403 for another's)."""
    return await session_for(conn, session_id)


async def session_for(
    conn: HTTPConnection, session_id: str, state: ServiceState | None = None
) -> LiveSession:
    """:func:`get_session` as a plain call, for the event route: it runs on every event, and
    a nested dependency costs FastAPI another resolution step on every request. It reads the
    header itself rather than through security sub-dependencies; routes using it declare the
    bearer scheme in OpenAPI with :data:`BEARER`. ``state``: the service, if the caller has
    it already."""
    state = state or service_of(conn)
    token = bearer_token(conn)
    if not token:
        check_session_token(None, b"", session_id)  # raises 401
    session = await state.sessions.get(session_id)
    check_session_token(token, session.token_digest, session_id)
    state.sessions.touch(session)
    return session


SessionLookup = Callable[..., Awaitable[LiveSession]]


def session_or_key(check: Callable[[str, ServiceState], object], who: str) -> SessionLookup:
    """A dependency: as :func:`get_session`, or any session for a key that passes ``check``
    (which raises for another key)."""

    async def lookup(
        conn: HTTPConnection,
        session_id: SessionId,
        state: StateDep,
        credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)] = None,
        key: Annotated[str | None, Depends(api_key_header)] = None,
    ) -> LiveSession:
        if key and not credentials:
            check(key, state)
            return await state.sessions.get(session_id)
        return await get_session(conn, session_id)

    lookup.__doc__ = f"As :func:`get_session`, or any session for {who}."
    return lookup


get_session_or_admin = session_or_key(
    lambda key, state: check_admin(key, state.admin_key), "the admin key (to read or end it)"
)
get_session_or_operator = session_or_key(
    lambda key, state: is_operator(key, state.admin_key, state.operator_key),
    "the admin or operator key (to read it)",
)


def client_of(conn: HTTPConnection, state: ServiceState) -> str | None:
    """Whom a new session's quota counts against: None for the admin key (no per-client
    quota); the name of a key the service knows (``"operator key"``, ``"key <name>"`` of
    ADVISOR_CLIENT_KEYS); else the client's address
    (:func:`app.service.clients.client_address`), also for a key the service does not know
    (anyone could invent keys to get a quota of their own)."""
    key = conn.headers.get("x-api-key")
    if key:
        if same_secret(key, state.admin_key):
            return None
        named = state.client_keys.client(key)
        if named is not None:
            return named
    return "address " + client_address(conn)


AdminDep = Depends(require_admin)
OperatorDep = Depends(require_operator)
#: which key a request sent (None: none), for a route that shows more to an operator
OperatorView = Annotated[Role | None, Depends(operator_view)]
DomainDep = Annotated[DomainState, Depends(get_domain)]
SessionDep = Annotated[LiveSession, Depends(get_session)]
SessionOrAdminDep = Annotated[LiveSession, Depends(get_session_or_admin)]
SessionOrOperatorDep = Annotated[LiveSession, Depends(get_session_or_operator)]

__all__ = [
    "AdminDep", "AuthError", "DomainDep", "OperatorDep", "OperatorView", "SessionDep",
    "SessionOrAdminDep", "SessionOrOperatorDep", "StateDep",
]  # fmt: skip
