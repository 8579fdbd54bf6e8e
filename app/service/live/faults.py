"""Redis failing, as the service meets it: every failure one exception, :class:`RedisDown`
(answered 503 with ``Retry-After``, a websocket closed with 1013, an MQTT error message), and a
:class:`Breaker` so that a Redis known to be down costs a request nothing.

What counts as Redis failing (:func:`classify`): no connection (refused, reset, closed, no
route, TLS or AUTH refused), no answer within ``ADVISOR_REDIS_TIMEOUT`` (the lanes' watchdog,
redis-py's socket timeouts), and Redis' own refusals to work now: ``OOM`` (``maxmemory``
reached), ``LOADING`` (reading its data at start), ``BUSY`` (a script ran too long),
``MISCONF`` (it cannot persist and refuses writes), ``READONLY`` (a replica), ``MASTERDOWN``,
``NOAUTH``/``WRONGPASS``/``NOPERM`` (credentials). A script refused for ``OOM`` did nothing:
Redis refuses a script at its first write, never after one.

The breaker opens at a timeout or a connection that cannot be made (and at ``LOADING``,
``BUSY``, ``MASTERDOWN`` and credentials refused): from then on every call is refused at once
(:meth:`Breaker.check`, nothing sent) while one probe asks Redis at once and then at most once
a second (``every``); when a probe is answered the breaker closes and ``on_up`` runs (the
sessions check whether Redis kept its data: :mod:`app.service.live.shared`). A connection lost
in the middle of a call (Redis killed, or a connection it closed) fails that call only: the
next connects again, and if that fails, the breaker opens. Redis' quick refusals (``OOM``,
``MISCONF``, ``READONLY``, ``NOPERM``) leave it closed: Redis answers them at once.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Awaitable, Callable
from typing import Any

import hiredis
import redis.exceptions as rx

from app.service.live.lanes import LaneError, LaneTimeout, LaneUnreachable
from app.service.live.registry import SessionNotFound
from app.service.live.sessions import StoreUnavailable

log = logging.getLogger("advisor.redis")

#: seconds a client is asked to wait before sending a refused request again (the probe's pace)
RETRY_AFTER = 1
#: Redis' refusals by the first word of its error: (what it means, whether the breaker opens)
REFUSALS: dict[str, tuple[str, bool]] = {
    "OOM": ("Redis is out of memory (maxmemory)", False),
    "MISCONF": ("Redis cannot save its data and refuses writes (MISCONF)", False),
    "READONLY": ("Redis is a read-only replica", False),
    "NOPERM": ("Redis' user lacks a permission (NOPERM)", False),
    "LOADING": ("Redis is loading its data", True),
    "BUSY": ("Redis is busy running a script", True),
    "MASTERDOWN": ("Redis has lost its primary (MASTERDOWN)", True),
    "NOAUTH": ("Redis asks for a password (NOAUTH)", True),
    "WRONGPASS": ("Redis refused the password (WRONGPASS)", True),
}
#: redis-py's classes for those refusals (its parser takes the first word off the message)
TYPED: tuple[tuple[type[BaseException], str], ...] = (
    (rx.OutOfMemoryError, "OOM"), (rx.ReadOnlyError, "READONLY"),
    (rx.NoPermissionError, "NOPERM"), (rx.BusyLoadingError, "LOADING"),
    (rx.MasterDownError, "MASTERDOWN"), (rx.AuthenticationError, "WRONGPASS"),
    (rx.AuthorizationError, "NOPERM"),
)  # fmt: skip


class RedisDown(StoreUnavailable):
    """Redis failed this call, or is known to be down (the call was not sent): ``why`` in a
    few words. What the call was to write was not written, or, when Redis stopped answering
    while it ran, is not known to be: a request sent again with its steps is applied once."""

    retry_after = RETRY_AFTER

    def __init__(self, why: str):
        super().__init__(why)
        self.why = why


class SessionLost(SessionNotFound):
    """The session was live when Redis lost its data (it came back empty): 410."""


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return (text[0] if text else type(exc).__name__)[:200]


def classify(exc: BaseException) -> tuple[str, bool] | None:
    """(why, whether the breaker opens) if ``exc`` means Redis is failing; None if it does
    not (a bug, or a refusal that is not Redis')."""
    if isinstance(exc, RedisDown):
        return exc.why, False
    if isinstance(exc, LaneTimeout | LaneUnreachable):
        return _first_line(exc), True
    if isinstance(exc, LaneError):
        return _first_line(exc) or "Redis closed the connection", False
    for kind, word in TYPED:
        if isinstance(exc, kind):
            return REFUSALS[word]
    if isinstance(exc, rx.TimeoutError):
        return f"Redis did not answer in time ({_first_line(exc)})", True
    if isinstance(exc, rx.ConnectionError):
        return f"no connection to Redis ({_first_line(exc)})", True
    if isinstance(exc, rx.ResponseError | hiredis.ReplyError):
        word = str(exc).split(" ", 1)[0]
        return REFUSALS.get(word)
    if isinstance(exc, hiredis.ProtocolError | rx.InvalidResponse):
        return f"Redis sent what is not RESP ({_first_line(exc)})", True
    if isinstance(exc, TimeoutError):
        return "Redis did not answer in time", True
    if isinstance(exc, OSError):
        return f"no connection to Redis ({_first_line(exc)})", True
    return None


class Breaker:
    """Whether Redis is known to be down; while it is, calls are refused at once and one probe
    asks it again at once, then at most every ``every`` seconds (see the module)."""

    def __init__(
        self,
        probe: Callable[[], Awaitable[Any]],
        on_up: Callable[[Any], Awaitable[None]] | None = None,
        every: float = 1.0,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.probe = probe
        self.on_up = on_up
        self.every = every
        self.clock = clock
        self.down_since: float | None = None
        self.why = ""
        self.refused = 0  # calls refused without reaching Redis
        self.probes = 0  # probes sent
        self.opened = 0  # times it opened
        self._task: asyncio.Task[None] | None = None

    @property
    def up(self) -> bool:
        return self.down_since is None

    def check(self) -> None:
        """Refuse at once (RedisDown) while Redis is known to be down."""
        if self.down_since is not None:
            self.refused += 1
            raise RedisDown(self.why)

    def failed(self, exc: BaseException) -> RedisDown | None:
        """``exc`` from a call to Redis: the RedisDown to raise instead (the breaker opened if
        it says Redis is down), or None if it is not Redis failing (raise it as it is)."""
        if isinstance(exc, RedisDown):
            return exc
        got = classify(exc)
        if got is None:
            return None
        why, opens = got
        if opens:
            self.open(why)
        return RedisDown(why)

    def open(self, why: str) -> None:
        if self.down_since is not None:
            return
        self.down_since = self.clock()
        self.why = why
        self.opened += 1
        log.warning(
            "Redis is down (%s): requests that need it are answered 503 at once; trying it "
            "again every %g s", why, self.every,
        )  # fmt: skip
        self._task = asyncio.get_running_loop().create_task(self._probing(), name="redis-probe")

    async def _probing(self) -> None:
        while True:
            began = self.clock()
            self.probes += 1
            try:
                answer = await self.probe()
            except Exception as exc:  # any failure: still down
                got = classify(exc)
                self.why = got[0] if got else _first_line(exc)
                await asyncio.sleep(max(0.0, self.every - (self.clock() - began)))
                continue
            break
        assert self.down_since is not None
        log.warning("Redis answers again, after %.1f s", self.clock() - self.down_since)
        self.down_since = None
        self._task = None
        if self.on_up is not None:
            try:
                await self.on_up(answer)
            except Exception as exc:  # it failed again: the next call tells
                log.warning("after Redis came back: %s", _first_line(exc))

    async def close(self) -> None:
        task, self._task = self._task, None
        if task is not None:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
