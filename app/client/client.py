"""``AdvisorClient`` (sync) and ``AsyncAdvisorClient``: the service's API over httpx, and its
websocket stream over ``websockets``. Talks HTTP only; imports nothing of the server.

>>> with AdvisorClient("http://127.0.0.1:8000") as client:
...     session = client.create_session("default", kappa=0.5)
...     with client.stream(session) as stream:
...         decision = stream.send({"state": [28, 0], "action": "E"})
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from types import TracebackType
from typing import Any, Self, cast

import httpx
from websockets.asyncio.client import ClientConnection as AsyncConnection
from websockets.asyncio.client import connect as async_connect
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection, connect

from app.client import api
from app.client.api import AdvisorError, Call, Session
from app.client.types import Cell, Decision, EventLike

DEFAULT_URL = "http://127.0.0.1:8000"


def _closed(exc: ConnectionClosed) -> AdvisorError:
    frame = exc.rcvd
    code = frame.code if frame else 1006
    status = code - 4000 if 4000 <= code < 5000 else 503
    return AdvisorError(status, (frame.reason if frame else "") or "the stream was closed")


def _parse(response: httpx.Response) -> Any:
    body: Any = None
    if response.content:
        try:
            body = response.json()
        except ValueError:
            body = None
    return api.result(response.status_code, body, response.text)


class _Base:
    def __init__(self, base_url: str, admin_key: str | None):
        self.base_url = base_url.rstrip("/")
        self.admin_key = admin_key

    def _request(self, call: Call) -> dict[str, Any]:
        headers = dict(call.headers)
        if call.admin:
            if self.admin_key is None:
                raise AdvisorError(401, "this call needs the admin key: pass admin_key=...")
            headers["X-API-Key"] = self.admin_key
        elif call.key_if_any and self.admin_key is not None:
            headers["X-API-Key"] = self.admin_key
        kwargs: dict[str, Any] = {"params": call.params, "headers": headers}
        if call.json is not None:
            kwargs["json"] = call.json
        return kwargs


class Stream:
    """A session's websocket: :meth:`send` events, get their decisions (in order)."""

    def __init__(self, connection: ClientConnection):
        self.connection = connection

    def send(self, events: EventLike | Sequence[EventLike]) -> Any:
        """One event -> one decision; a list -> a list (a binary stream: a
        :class:`~app.protocol.DecisionFrame` either way). AdvisorError for a refused batch
        (the stream stays usable) or a closed stream."""
        body = dict(events) if isinstance(events, Mapping) else [dict(e) for e in events]
        try:
            self.connection.send(json.dumps(body))
            return api.frame_answer(self.connection.recv())
        except ConnectionClosed as exc:
            raise _closed(exc) from None

    def close(self) -> None:
        self.connection.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class AdvisorClient(_Base):
    """Synchronous client. Admin calls need ``admin_key``; session calls use the session's
    token, kept in the :class:`Session` that :meth:`create_session` returns."""

    def __init__(
        self,
        base_url: str = DEFAULT_URL,
        admin_key: str | None = None,
        timeout: float = 30.0,
        transport: httpx.BaseTransport | None = None,
    ):
        super().__init__(base_url, admin_key)
        self.http = httpx.Client(base_url=self.base_url, timeout=timeout, transport=transport)

    def call(self, call: Call) -> Any:
        response = self.http.request(call.method, call.path, **self._request(call))
        return _parse(response)

    def close(self) -> None:
        self.http.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self, t: type[BaseException] | None, e: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def health(self) -> dict[str, Any]:
        return cast(dict[str, Any], self.call(api.health()))

    def domains(self) -> list[dict[str, Any]]:
        return cast(list[dict[str, Any]], self.call(api.domains()))

    def domain(self, name: str) -> dict[str, Any]:
        return cast(dict[str, Any], self.call(api.domain(name)))

    def put_domain(
        self, name: str, rows: Sequence[str], alpha0: float = 1.0, **frame_and_experts: Any
    ) -> dict[str, Any]:
        """Create or replace a domain; keywords ``resolution``, ``origin`` (metres) and
        ``experts`` (``{"source", "per_goal", "seed"}``) as the PUT body has them."""
        call = api.put_domain(name, rows, alpha0, **frame_and_experts)
        return cast(dict[str, Any], self.call(call))

    def delete_domain(self, name: str) -> None:
        self.call(api.delete_domain(name))

    def add_trajectories(self, name: str, trajectories: Sequence[EventLike]) -> dict[str, int]:
        return cast(dict[str, int], self.call(api.add_trajectories(name, trajectories)))

    def prior(self, name: str, agent_type: str | None = None) -> dict[str, Any]:
        return cast(dict[str, Any], self.call(api.prior(name, agent_type)))

    def create_session(
        self,
        domain: str = "default",
        kappa: float | None = None,
        window: int | None = None,
        agent_type: str | None = None,
        start: Cell | None = None,
        strategy: str | None = None,
        params: Mapping[str, float | int] | None = None,
    ) -> Session:
        """A new session (``strategy``: when to advise, default the paper's rule; ``params``:
        its parameters, see the service's docs)."""
        call = api.create_session(domain, kappa, window, agent_type, start, strategy, params)
        return Session.of(self.call(call))

    def events(self, session: Session, events: EventLike | Sequence[EventLike]) -> Any:
        """Decisions over REST: one event -> one decision, a list -> a list."""
        return self.call(api.events(session, events))

    def positions(self, session: Session, points: Sequence[Sequence[float]]) -> list[Decision]:
        """Positions in metres -> one decision per move they make (see the route)."""
        return cast(list[Decision], self.call(api.positions(session, points)))

    def step(self, session: Session, event: EventLike) -> Decision:
        return cast(Decision, self.events(session, event))

    def session(self, session: Session) -> dict[str, Any]:
        return cast(dict[str, Any], self.call(api.read_session(session)))

    def end_session(self, session: Session) -> dict[str, Any]:
        return cast(dict[str, Any], self.call(api.end_session(session)))

    def sessions(self, limit: int = 100) -> dict[str, Any]:
        return cast(dict[str, Any], self.call(api.sessions(limit)))

    def overview(self, limit: int = 100) -> dict[str, Any]:
        return cast(dict[str, Any], self.call(api.overview(limit)))

    def stream(self, session: Session, binary: bool = False) -> Stream:
        """The session's websocket (use as a context manager); ``binary``: decisions come as
        :class:`~app.protocol.DecisionFrame` arrays, about a tenth of the bytes of JSON."""
        url = api.stream_url(self.base_url, session, binary)
        headers = api.stream_headers(session)
        try:
            return Stream(connect(url, compression=None, max_size=None, additional_headers=headers))
        except ConnectionClosed as exc:
            raise _closed(exc) from None


class AsyncStream:
    """The async form of :class:`Stream`."""

    def __init__(self, connection: AsyncConnection):
        self.connection = connection

    async def send(self, events: EventLike | Sequence[EventLike]) -> Any:
        body = dict(events) if isinstance(events, Mapping) else [dict(e) for e in events]
        try:
            await self.connection.send(json.dumps(body))
            return api.frame_answer(await self.connection.recv())
        except ConnectionClosed as exc:
            raise _closed(exc) from None

    async def close(self) -> None:
        await self.connection.close()

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()


class AsyncAdvisorClient(_Base):
    """The async form of :class:`AdvisorClient` (same methods, awaited)."""

    def __init__(
        self,
        base_url: str = DEFAULT_URL,
        admin_key: str | None = None,
        timeout: float = 30.0,
        transport: httpx.AsyncBaseTransport | None = None,
    ):
        super().__init__(base_url, admin_key)
        self.http = httpx.AsyncClient(base_url=self.base_url, timeout=timeout, transport=transport)

    async def call(self, call: Call) -> Any:
        response = await self.http.request(call.method, call.path, **self._request(call))
        return _parse(response)

    async def aclose(self) -> None:
        await self.http.aclose()

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.aclose()

    async def health(self) -> dict[str, Any]:
        return cast(dict[str, Any], await self.call(api.health()))

    async def domains(self) -> list[dict[str, Any]]:
        return cast(list[dict[str, Any]], await self.call(api.domains()))

    async def domain(self, name: str) -> dict[str, Any]:
        return cast(dict[str, Any], await self.call(api.domain(name)))

    async def put_domain(
        self, name: str, rows: Sequence[str], alpha0: float = 1.0, **frame_and_experts: Any
    ) -> dict[str, Any]:
        call = api.put_domain(name, rows, alpha0, **frame_and_experts)
        return cast(dict[str, Any], await self.call(call))

    async def delete_domain(self, name: str) -> None:
        await self.call(api.delete_domain(name))

    async def add_trajectories(
        self, name: str, trajectories: Sequence[EventLike]
    ) -> dict[str, int]:
        return cast(dict[str, int], await self.call(api.add_trajectories(name, trajectories)))

    async def prior(self, name: str, agent_type: str | None = None) -> dict[str, Any]:
        return cast(dict[str, Any], await self.call(api.prior(name, agent_type)))

    async def create_session(
        self,
        domain: str = "default",
        kappa: float | None = None,
        window: int | None = None,
        agent_type: str | None = None,
        start: Cell | None = None,
        strategy: str | None = None,
        params: Mapping[str, float | int] | None = None,
    ) -> Session:
        call = api.create_session(domain, kappa, window, agent_type, start, strategy, params)
        return Session.of(await self.call(call))

    async def events(self, session: Session, events: EventLike | Sequence[EventLike]) -> Any:
        return await self.call(api.events(session, events))

    async def positions(
        self, session: Session, points: Sequence[Sequence[float]]
    ) -> list[Decision]:
        return cast(list[Decision], await self.call(api.positions(session, points)))

    async def session(self, session: Session) -> dict[str, Any]:
        return cast(dict[str, Any], await self.call(api.read_session(session)))

    async def end_session(self, session: Session) -> dict[str, Any]:
        return cast(dict[str, Any], await self.call(api.end_session(session)))

    async def sessions(self, limit: int = 100) -> dict[str, Any]:
        return cast(dict[str, Any], await self.call(api.sessions(limit)))

    async def overview(self, limit: int = 100) -> dict[str, Any]:
        return cast(dict[str, Any], await self.call(api.overview(limit)))

    async def stream(self, session: Session, binary: bool = False) -> AsyncStream:
        """The session's websocket (``async with await client.stream(s) as stream``);
        ``binary`` as in :meth:`AdvisorClient.stream`."""
        url = api.stream_url(self.base_url, session, binary)
        headers = api.stream_headers(session)
        try:
            return AsyncStream(
                await async_connect(
                    url, compression=None, max_size=None, additional_headers=headers
                )
            )
        except ConnectionClosed as exc:
            raise _closed(exc) from None
