"""``AdvisorClient`` (sync) and ``AsyncAdvisorClient``: the service's API over httpx, and its
websocket stream over ``websockets``. Talks HTTP only; imports nothing of the server.

>>> with AdvisorClient("http://127.0.0.1:8000") as client:
...     session = client.create_session("default", kappa=0.5)
...     with client.stream(session) as stream:
...         decision = stream.send({"state": [28, 0], "action": "E"})
"""

from __future__ import annotations

import json
import os
from collections.abc import Awaitable, Callable, Mapping, Sequence
from pathlib import Path
from types import TracebackType
from typing import Any, Self, cast

import httpx
from tenacity import (
    AsyncRetrying,
    RetryCallState,
    Retrying,
    retry_base,
    retry_if_exception,
    retry_if_exception_type,
    retry_if_result,
    stop_after_attempt,
    wait_exponential,
)
from websockets.asyncio.client import ClientConnection as AsyncConnection
from websockets.asyncio.client import connect as async_connect
from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidStatus
from websockets.sync.client import ClientConnection, connect

from advisor_client import api
from advisor_client.api import AdvisorError, AdvisorUnreachable, Call, Session
from advisor_client.types import (
    Accepted,
    Cell,
    Decision,
    DomainInfo,
    EventLike,
    Health,
    Overview,
    Prior,
    SessionInfo,
    SessionList,
)

DEFAULT_URL = "http://127.0.0.1:8000"
#: answers worth another try of an idempotent call (a proxy or the service restarting)
RETRY_STATUSES = frozenset({502, 503, 504})
#: failures in which nothing reached the service: any call may be sent again
NOT_SENT = (httpx.ConnectError, httpx.ConnectTimeout, httpx.PoolTimeout)
MAX_DELAY = 4.0


def _lost(exc: ConnectionClosed) -> bool:
    """Whether a closed stream is worth a new one: it went (a worker killed, the service
    restarting, its Redis not answering) rather than being refused by the service (4401-4422:
    no token, another session's token, no such session, a bad format)."""
    frame = exc.rcvd
    return not (frame is not None and 4000 <= frame.code < 5000)


def _last_outcome(state: RetryCallState) -> Any:
    """After the last try: its exception raised again, or its answer (a response that was
    worth another try, given back as it is)."""
    assert state.outcome is not None
    return state.outcome.result()


def _policy(
    retries: int, wait: Callable[[RetryCallState], float], retry: retry_base
) -> dict[str, Any]:
    """tenacity's arguments: ``retry`` says what is worth another try, at most ``retries``
    more, after ``wait``; after the last, :func:`_last_outcome`."""
    return {
        "stop": stop_after_attempt(retries + 1), "wait": wait, "retry": retry,
        "retry_error_callback": _last_outcome,
    }  # fmt: skip


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


def _problem(exc: BaseException) -> str:
    text = str(exc) or type(exc).__name__
    return f"{type(exc).__name__}: {text}" if type(exc).__name__ not in text else text


def _ws_failure(url: str, exc: Exception) -> AdvisorError:
    """A websocket that could not be opened, as an AdvisorError."""
    if isinstance(exc, ConnectionClosed):
        return _closed(exc)
    if isinstance(exc, InvalidStatus):
        status = exc.response.status_code
        return AdvisorError(status, f"the service refused the websocket: HTTP {status}")
    return AdvisorUnreachable(url, _problem(exc))


class _Base:
    """What both clients share: credentials, and when to try a call again (tenacity).

    ``retries``: how many more times a call is tried after a failure worth retrying, waiting
    ``backoff`` seconds, then twice that, and so on (at most 4 s): a call that could not
    connect (nothing was sent); an idempotent call (GET, PUT, DELETE) that got no answer or a
    502, 503 or 504. After the last, :class:`AdvisorUnreachable` (an :class:`AdvisorError`
    with ``status`` 0, the URL and a hint) or the service's own answer."""

    def __init__(
        self, base_url: str, admin_key: str | None, retries: int = 3, backoff: float = 0.25
    ):
        if retries < 0 or backoff < 0:
            raise ValueError("retries and backoff must be >= 0")
        self.base_url = base_url.rstrip("/")
        self.admin_key = admin_key
        self.retries = retries
        self.backoff = backoff

    def __deepcopy__(self, memo: dict[int, Any]) -> Self:
        """The same client: one holds connections, not values (Gymnasium copies the specs of
        environments, whose arguments name the client)."""
        return self

    def _delay(self, attempt: int) -> float:
        """The wait before try ``attempt + 2`` (``attempt`` 0 after the first failure)."""
        return float(min(self.backoff * 2**attempt, MAX_DELAY))

    def _wait(self) -> wait_exponential:
        return wait_exponential(multiplier=self.backoff, max=MAX_DELAY)  # = _delay

    def _call_policy(self, call: Call) -> dict[str, Any]:
        """When ``call`` is tried again: an error in which nothing was sent, or, if it is
        idempotent, any transport error and the statuses of :data:`RETRY_STATUSES`."""

        def failed(exc: BaseException) -> bool:
            return isinstance(exc, httpx.TransportError) and (
                call.idempotent or isinstance(exc, NOT_SENT)
            )

        def refused(response: httpx.Response) -> bool:
            return call.idempotent and response.status_code in RETRY_STATUSES

        return _policy(
            self.retries, self._wait(), retry_if_exception(failed) | retry_if_result(refused)
        )

    def _connect_policy(self) -> dict[str, Any]:
        """A websocket that could not be opened (refused, timed out: nothing was sent) is
        tried again; one the service refused (an HTTP answer, a close) is not."""
        return _policy(self.retries, self._wait(), retry_if_exception_type(OSError))

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
        if call.content is not None:
            kwargs["content"] = call.content
        return kwargs


def _stream_policy(stream: Stream | AsyncStream) -> dict[str, Any]:
    """A frame whose stream went (not one the service closed to refuse it) is sent again on a
    new stream, at most ``stream.retries`` times, after ``stream.delay(n)`` seconds."""

    def went(exc: BaseException) -> bool:
        return isinstance(exc, ConnectionClosed) and stream.reopen is not None and _lost(exc)

    def wait(state: RetryCallState) -> float:
        return stream.delay(state.attempt_number - 1)

    return _policy(stream.retries, wait, retry_if_exception(went))


class Stream:
    """A session's websocket: :meth:`send` events, get their decisions (in order). Events are
    numbered with their steps as over REST (:class:`~advisor_client.api.Session`), so a frame
    whose answer was lost with its stream is sent again on a new one, and the service answers
    the steps it applied already without applying them twice.

    ``reopen``: how to open a new stream (:meth:`AdvisorClient.stream` gives it), tried up to
    ``retries`` times per frame, waiting ``delay(attempt)`` seconds first; ``reconnects``
    counts the new streams opened."""

    def __init__(
        self,
        connection: ClientConnection,
        session: Session,
        reopen: Callable[[], ClientConnection] | None = None,
        retries: int = 0,
        delay: Callable[[int], float] = lambda attempt: 0.0,
    ):
        self.connection = connection
        self.session = session
        self.reopen, self.retries, self.delay = reopen, retries, delay
        self.reconnects = 0

    def send(self, events: EventLike | Sequence[EventLike]) -> Any:
        """One event -> one decision; a list -> a list (a binary stream: a
        :class:`~advisor_client.protocol.DecisionFrame` either way). A stream that went (not
        one the service closed to refuse it) is replaced and the frame sent again on the new
        one. AdvisorError for a refused batch (the stream stays usable), a stream the service
        closed, or one that could not be replaced."""
        body = json.dumps(api.numbered(self.session, events))
        attempts = 0

        def exchange() -> Any:
            nonlocal attempts
            attempts += 1
            if attempts > 1:  # the stream went: a new one (its own retries)
                assert self.reopen is not None
                self.connection = self.reopen()
                self.reconnects += 1
            self.connection.send(body)
            return api.frame_answer(self.connection.recv())

        try:
            answer = Retrying(**_stream_policy(self))(exchange)
        except ConnectionClosed as exc:
            raise _closed(exc) from None
        self.session.answered(answer)
        return answer

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
        retries: int = 3,
        backoff: float = 0.25,
    ):
        super().__init__(base_url, admin_key, retries, backoff)
        self.http = httpx.Client(base_url=self.base_url, timeout=timeout, transport=transport)

    def call(self, call: Call) -> Any:
        """Send ``call`` (tried again as :class:`_Base` says); its answer's body."""
        return _parse(self._respond(call))

    def _respond(self, call: Call) -> httpx.Response:
        """Send ``call`` (tried again as :class:`_Base` says); the service's last answer."""
        kwargs = self._request(call)
        attempts = 0

        def send() -> httpx.Response:
            nonlocal attempts
            attempts += 1
            return self.http.request(call.method, call.path, **kwargs)

        try:
            response: httpx.Response = Retrying(**self._call_policy(call))(send)
        except httpx.TransportError as exc:
            raise AdvisorUnreachable(self.base_url + call.path, _problem(exc), attempts) from exc
        return response

    def close(self) -> None:
        self.http.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self, t: type[BaseException] | None, e: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def health(self) -> Health:
        return cast(Health, self.call(api.health()))

    def domains(self) -> list[DomainInfo]:
        return cast(list[DomainInfo], self.call(api.domains()))

    def domain(self, name: str) -> DomainInfo:
        return cast(DomainInfo, self.call(api.domain(name)))

    def put_domain(
        self, name: str, rows: Sequence[str], alpha0: float = 1.0, **frame_and_experts: Any
    ) -> DomainInfo:
        """Create or replace a domain; keywords ``resolution``, ``origin`` (metres) and
        ``experts`` (``{"source", "per_goal", "seed"}``) as the PUT body has them, and
        ``destinations``, the names of destinations as ``{(row, col): name}``."""
        call = api.put_domain(name, rows, alpha0, **frame_and_experts)
        return cast(DomainInfo, self.call(call))

    def put_domain_created(
        self, name: str, rows: Sequence[str], alpha0: float = 1.0, **frame_and_experts: Any
    ) -> tuple[DomainInfo, bool]:
        """:meth:`put_domain`, and whether this PUT created the domain (201) rather than
        replacing one (200). A PUT retried after a lost answer finds the domain it made: it
        says False then."""
        response = self._respond(api.put_domain(name, rows, alpha0, **frame_and_experts))
        return cast(DomainInfo, _parse(response)), response.status_code == 201

    def put_domain_file(
        self,
        name: str,
        path: str | os.PathLike[str],
        alpha0: float | None = None,
        *,
        experts: str | Mapping[str, Any] | None = None,
    ) -> DomainInfo:
        """Create or replace a domain from a map file as the project writes it (``maze
        import``, ``maze generate``: header lines with the resolution and origin, then the
        rows), sent as it is. ``experts``: ``"start"``, ``"anywhere"`` or ``{"source",
        "per_goal", "seed"}``. A bad file raises :class:`AdvisorError` naming its line and
        column, as ``maze check`` does."""
        text = Path(path).read_bytes()
        return cast(DomainInfo, self.call(api.put_domain_file(name, text, alpha0, experts=experts)))

    def delete_domain(self, name: str) -> None:
        self.call(api.delete_domain(name))

    def add_trajectories(self, name: str, trajectories: Sequence[EventLike]) -> Accepted:
        return cast(Accepted, self.call(api.add_trajectories(name, trajectories)))

    def prior(self, name: str, agent_type: str | None = None) -> Prior:
        return cast(Prior, self.call(api.prior(name, agent_type)))

    def create_session(
        self,
        domain: str = "default",
        kappa: float | None = None,
        window: int | None = None,
        agent_type: str | None = None,
        start: Cell | None = None,
        strategy: str | None = None,
        params: Mapping[str, float | int] | None = None,
        budget: Mapping[str, int] | None = None,
    ) -> Session:
        """A new session (``strategy``: when to advise, default the paper's rule; ``params``:
        its parameters, see the service's docs; ``budget``: at most this much advice,
        ``{"total": n, "per_minute": m}``, either or both)."""
        call = api.create_session(
            domain, kappa, window, agent_type, start, strategy, params, budget
        )
        return Session.of(self.call(call))

    def events(self, session: Session, events: EventLike | Sequence[EventLike]) -> Any:
        """Decisions over REST: one event -> one decision, a list -> a list. The events carry
        their steps, so a call that got no answer is sent again (as :class:`_Base` says) and
        applied once."""
        answer = self.call(api.events(session, events))
        session.answered(answer)
        return answer

    def positions(self, session: Session, points: Sequence[Sequence[float]]) -> list[Decision]:
        """Positions in metres -> one decision per move they make (see the route)."""
        return cast(list[Decision], self.call(api.positions(session, points)))

    def step(self, session: Session, event: EventLike) -> Decision:
        return cast(Decision, self.events(session, event))

    def session(self, session: Session) -> SessionInfo:
        return cast(SessionInfo, self.call(api.read_session(session)))

    def mute(self, session: Session, muted: bool = True) -> SessionInfo:
        """No more advice for this session (the visitor asked), or advice again."""
        return cast(SessionInfo, self.call(api.mute(session, muted)))

    def end_session(self, session: Session) -> SessionInfo:
        return cast(SessionInfo, self.call(api.end_session(session)))

    def sessions(self, limit: int = 100) -> SessionList:
        return cast(SessionList, self.call(api.sessions(limit)))

    def overview(self, limit: int = 100) -> Overview:
        return cast(Overview, self.call(api.overview(limit)))

    def stream(self, session: Session, binary: bool = False) -> Stream:
        """The session's websocket (use as a context manager); ``binary``: decisions come as
        :class:`~advisor_client.protocol.DecisionFrame` arrays, about a tenth of the bytes of
        JSON. A stream that goes is replaced as :class:`Stream` says."""
        url = api.stream_url(self.base_url, session, binary)
        headers = api.stream_headers(session)
        return Stream(
            self._connect(url, headers), session, lambda: self._connect(url, headers),
            self.retries, self._delay,
        )  # fmt: skip

    def _connect(self, url: str, headers: dict[str, str]) -> ClientConnection:
        def open_() -> ClientConnection:
            return connect(url, compression=None, max_size=None, additional_headers=headers)

        try:
            connection: ClientConnection = Retrying(**self._connect_policy())(open_)
        except (OSError, ConnectionClosed, InvalidHandshake) as exc:
            raise _ws_failure(url, exc) from None
        return connection


class AsyncStream:
    """The async form of :class:`Stream` (``reopen`` a coroutine function)."""

    def __init__(
        self,
        connection: AsyncConnection,
        session: Session,
        reopen: Callable[[], Awaitable[AsyncConnection]] | None = None,
        retries: int = 0,
        delay: Callable[[int], float] = lambda attempt: 0.0,
    ):
        self.connection = connection
        self.session = session
        self.reopen, self.retries, self.delay = reopen, retries, delay
        self.reconnects = 0

    async def send(self, events: EventLike | Sequence[EventLike]) -> Any:
        body = json.dumps(api.numbered(self.session, events))
        attempts = 0

        async def exchange() -> Any:
            nonlocal attempts
            attempts += 1
            if attempts > 1:  # the stream went: a new one (its own retries)
                assert self.reopen is not None
                self.connection = await self.reopen()
                self.reconnects += 1
            await self.connection.send(body)
            return api.frame_answer(await self.connection.recv())

        try:
            answer: Any = await AsyncRetrying(**_stream_policy(self))(exchange)
        except ConnectionClosed as exc:
            raise _closed(exc) from None
        self.session.answered(answer)
        return answer

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
        retries: int = 3,
        backoff: float = 0.25,
    ):
        super().__init__(base_url, admin_key, retries, backoff)
        self.http = httpx.AsyncClient(base_url=self.base_url, timeout=timeout, transport=transport)

    async def call(self, call: Call) -> Any:
        """Send ``call`` (tried again as :class:`_Base` says); its answer's body."""
        return _parse(await self._respond(call))

    async def _respond(self, call: Call) -> httpx.Response:
        """Send ``call`` (tried again as :class:`_Base` says); the service's last answer."""
        kwargs = self._request(call)
        attempts = 0

        async def send() -> httpx.Response:
            nonlocal attempts
            attempts += 1
            return await self.http.request(call.method, call.path, **kwargs)

        try:
            response: httpx.Response = await AsyncRetrying(**self._call_policy(call))(send)
        except httpx.TransportError as exc:
            raise AdvisorUnreachable(self.base_url + call.path, _problem(exc), attempts) from exc
        return response

    async def aclose(self) -> None:
        await self.http.aclose()

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.aclose()

    async def health(self) -> Health:
        return cast(Health, await self.call(api.health()))

    async def domains(self) -> list[DomainInfo]:
        return cast(list[DomainInfo], await self.call(api.domains()))

    async def domain(self, name: str) -> DomainInfo:
        return cast(DomainInfo, await self.call(api.domain(name)))

    async def put_domain(
        self, name: str, rows: Sequence[str], alpha0: float = 1.0, **frame_and_experts: Any
    ) -> DomainInfo:
        call = api.put_domain(name, rows, alpha0, **frame_and_experts)
        return cast(DomainInfo, await self.call(call))

    async def put_domain_created(
        self, name: str, rows: Sequence[str], alpha0: float = 1.0, **frame_and_experts: Any
    ) -> tuple[DomainInfo, bool]:
        response = await self._respond(api.put_domain(name, rows, alpha0, **frame_and_experts))
        return cast(DomainInfo, _parse(response)), response.status_code == 201

    async def put_domain_file(
        self,
        name: str,
        path: str | os.PathLike[str],
        alpha0: float | None = None,
        *,
        experts: str | Mapping[str, Any] | None = None,
    ) -> DomainInfo:
        text = Path(path).read_bytes()  # a map file: small, read at once
        call = api.put_domain_file(name, text, alpha0, experts=experts)
        return cast(DomainInfo, await self.call(call))

    async def delete_domain(self, name: str) -> None:
        await self.call(api.delete_domain(name))

    async def add_trajectories(self, name: str, trajectories: Sequence[EventLike]) -> Accepted:
        return cast(Accepted, await self.call(api.add_trajectories(name, trajectories)))

    async def prior(self, name: str, agent_type: str | None = None) -> Prior:
        return cast(Prior, await self.call(api.prior(name, agent_type)))

    async def create_session(
        self,
        domain: str = "default",
        kappa: float | None = None,
        window: int | None = None,
        agent_type: str | None = None,
        start: Cell | None = None,
        strategy: str | None = None,
        params: Mapping[str, float | int] | None = None,
        budget: Mapping[str, int] | None = None,
    ) -> Session:
        call = api.create_session(
            domain, kappa, window, agent_type, start, strategy, params, budget
        )
        return Session.of(await self.call(call))

    async def events(self, session: Session, events: EventLike | Sequence[EventLike]) -> Any:
        answer = await self.call(api.events(session, events))
        session.answered(answer)
        return answer

    async def positions(
        self, session: Session, points: Sequence[Sequence[float]]
    ) -> list[Decision]:
        return cast(list[Decision], await self.call(api.positions(session, points)))

    async def session(self, session: Session) -> SessionInfo:
        return cast(SessionInfo, await self.call(api.read_session(session)))

    async def mute(self, session: Session, muted: bool = True) -> SessionInfo:
        return cast(SessionInfo, await self.call(api.mute(session, muted)))

    async def end_session(self, session: Session) -> SessionInfo:
        return cast(SessionInfo, await self.call(api.end_session(session)))

    async def sessions(self, limit: int = 100) -> SessionList:
        return cast(SessionList, await self.call(api.sessions(limit)))

    async def overview(self, limit: int = 100) -> Overview:
        return cast(Overview, await self.call(api.overview(limit)))

    async def stream(self, session: Session, binary: bool = False) -> AsyncStream:
        """The session's websocket (``async with await client.stream(s) as stream``);
        ``binary`` as in :meth:`AdvisorClient.stream`."""
        url = api.stream_url(self.base_url, session, binary)
        headers = api.stream_headers(session)

        async def reopen() -> AsyncConnection:
            return await self._connect(url, headers)

        return AsyncStream(await reopen(), session, reopen, self.retries, self._delay)

    async def _connect(self, url: str, headers: dict[str, str]) -> AsyncConnection:
        async def open_() -> AsyncConnection:
            return await async_connect(
                url, compression=None, max_size=None, additional_headers=headers
            )

        try:
            connection: AsyncConnection = await AsyncRetrying(**self._connect_policy())(open_)
        except (OSError, ConnectionClosed, InvalidHandshake) as exc:
            raise _ws_failure(url, exc) from None
        return connection
