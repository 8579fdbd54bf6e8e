"""The connections that carry the events' scripts to Redis: pipelined, so that many sessions
share one without waiting for each other's answers.

Every event is one script call (:mod:`app.service.live.shared`). Through redis-py's asyncio
client a call cost this worker 110-250 us of CPU (its pool, its locks and checks: measured
in docs/PERFORMANCE.md, "Workers"), most of a REST event's budget; a :class:`Lane` packs the
command with hiredis (the C parser redis-py itself uses), writes it, and matches answers to
callers in the order Redis sends them, which is the order they were written. The commands
packed in one step of the event loop (the events of every request the step handled) go out in
one write at its end: Redis reads them together and answers them together (2.2 events a read
instead of one, one worker under 16 REST connections: ``benchmarks/bench_redis_costs.py``).
Everything else (reads, admin, the sweep) goes through redis-py.

A lane that loses its connection fails the calls in flight (:class:`LaneError`: the caller
answers 503, a retry with the same step is safe) and connects again at the next call; a
call that gets no answer within ``timeout`` seconds (checked every quarter of it: at most
1.25 ``timeout``) fails the same way (:class:`LaneTimeout`), since a late answer could no
longer be told apart, and so does a connection that cannot be made within ``timeout``
(:class:`LaneUnreachable`: refused, no route, TLS or AUTH refused). One watchdog a lane does
that check, not a timer a call (each timer is an entry in the event loop's heap, made and
cancelled at every event). A connection given up is aborted, not closed: what it had not
written yet (to a Redis that stopped reading) is dropped at once. Answers are parsed where the
bytes arrive (an asyncio protocol's ``data_received``), not by a reading task woken through a
stream: one step of the event loop less an answer.
"""

from __future__ import annotations

import asyncio
import collections
import ssl
import time
from typing import Any, cast

import hiredis
from redis.connection import parse_url


class LaneError(ConnectionError):
    """The lane's connection failed, or Redis did not answer in time."""


class LaneTimeout(LaneError):
    """Redis did not answer a call within the lane's timeout."""


class LaneUnreachable(LaneError):
    """The lane could not connect to Redis (refused, timed out, TLS or AUTH refused)."""


def tls_context(options: dict[str, Any]) -> ssl.SSLContext:
    """The TLS context of a ``rediss://`` URL, from the options redis-py reads in its query
    string: ``ssl_ca_certs`` (a CA file; default: the system's), ``ssl_cert_reqs`` (``none``,
    ``optional``, ``required``), ``ssl_certfile`` and ``ssl_keyfile`` (a client certificate),
    ``ssl_check_hostname``."""
    context = ssl.create_default_context(cafile=options.get("ssl_ca_certs"))
    check = options.get("ssl_check_hostname")
    if check is not None:
        context.check_hostname = check if isinstance(check, bool) else check.lower() in (
            "1", "true", "yes", "on",
        )  # fmt: skip
    reqs = str(options.get("ssl_cert_reqs") or "required").lower()
    if reqs == "none":
        context.check_hostname = False
        context.verify_mode = ssl.CERT_NONE
    elif reqs == "optional":
        context.verify_mode = ssl.CERT_OPTIONAL
    if options.get("ssl_certfile"):
        context.load_cert_chain(options["ssl_certfile"], options.get("ssl_keyfile"))
    return context


class _Wire(asyncio.Protocol):
    """A lane's connection: commands out, answers parsed as they arrive and handed to the
    lane in order."""

    def __init__(self, lane: Lane):
        self.lane = lane
        self.parser = hiredis.Reader()
        self.transport: asyncio.Transport | None = None
        self.drained: asyncio.Future[None] | None = None  # set while writing is paused

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = cast(asyncio.Transport, transport)
        self.transport.set_write_buffer_limits(high=1 << 20)  # callers wait beyond 1 MiB

    def data_received(self, data: bytes) -> None:
        try:
            self.parser.feed(data)
            while (reply := self.parser.gets()) is not False:
                self.lane._answer(reply)
        except hiredis.ProtocolError as exc:
            self.lane._lost(LaneError(f"Redis sent what is not RESP: {exc}"), self)

    def connection_lost(self, exc: Exception | None) -> None:
        self._resume()
        self.lane._lost(LaneError(str(exc) if exc else "Redis closed the connection"), self)

    def pause_writing(self) -> None:
        if self.drained is None:
            self.drained = asyncio.get_running_loop().create_future()

    def resume_writing(self) -> None:
        self._resume()

    def _resume(self) -> None:
        drained, self.drained = self.drained, None
        if drained is not None and not drained.done():
            drained.set_result(None)


class Lane:
    """One pipelined connection to the Redis of ``url`` (``redis://``, ``rediss://`` or
    ``unix://``, as redis-py reads them)."""

    def __init__(self, url: str, timeout: float = 10.0):
        self.options = parse_url(url)  # type: ignore[no-untyped-call]
        self.tls = url.startswith("rediss://")
        self._tls_context = tls_context(self.options) if self.tls else None
        self.timeout = timeout
        self._wire: _Wire | None = None
        self._waiting: collections.deque[asyncio.Future[Any]] = collections.deque()
        self._sent: collections.deque[float] = collections.deque()  # when each was written
        self._watchdog: asyncio.TimerHandle | None = None
        self._connecting = asyncio.Lock()
        self._out: list[bytes] = []  # commands packed this step of the event loop, not yet written

    @property
    def connected(self) -> bool:
        return self._wire is not None

    async def _connect(self) -> _Wire:
        async with self._connecting:
            if self._wire is not None:
                return self._wire
            o = self.options
            loop = asyncio.get_running_loop()
            wire = _Wire(self)
            try:
                async with asyncio.timeout(self.timeout):
                    if "path" in o:
                        await loop.create_unix_connection(lambda: wire, o["path"])
                    else:
                        await loop.create_connection(
                            lambda: wire, o.get("host", "127.0.0.1"), o.get("port", 6379),
                            ssl=self._tls_context,
                        )  # fmt: skip
            except (OSError, TimeoutError) as exc:  # ssl.SSLError is an OSError
                raise LaneUnreachable(f"cannot connect to Redis: {_reason(exc)}") from None
            hello: list[tuple[Any, ...]] = []
            if o.get("password"):
                user = o.get("username")
                hello.append(("AUTH", user, o["password"]) if user else ("AUTH", o["password"]))
            if o.get("db"):
                hello.append(("SELECT", o["db"]))
            self._wire = wire  # (a connection lost from here on fails what waits)
            answers = [self._write(wire, command) for command in hello]  # first on the wire
            try:
                for done in answers:
                    await done
            except (hiredis.ReplyError, LaneError) as exc:  # a wrong password, no answer
                refused = LaneUnreachable(f"Redis refused the connection: {exc}")
                if isinstance(exc, hiredis.ReplyError):
                    self._lost(refused, wire)
                for other in answers:  # their failure is this one
                    if other.done() and not other.cancelled():
                        other.exception()
                raise refused from None
            return wire

    async def call(self, *args: Any) -> Any:
        """Send one command; its answer (ReplyError from Redis is raised as is)."""
        wire = self._wire or await self._connect()
        done = self._write(wire, args)
        if wire.drained is not None:  # over the transport's high-water mark: wait for it
            await asyncio.shield(wire.drained)
        return await done

    def _write(self, wire: _Wire, args: tuple[Any, ...]) -> asyncio.Future[Any]:
        assert wire.transport is not None
        loop = asyncio.get_running_loop()
        done: asyncio.Future[Any] = loop.create_future()
        self._waiting.append(done)
        self._sent.append(time.monotonic())
        if not self._out:
            loop.call_soon(self._flush, wire)
        self._out.append(hiredis.pack_command(args))
        if self._watchdog is None:
            self._watchdog = loop.call_later(self.timeout / 4, self._watch)
        return done

    def _flush(self, wire: _Wire) -> None:
        """Write what this step of the event loop packed, in one write: Redis then reads the
        commands of every event this worker handled in the step at once, and answers them
        together."""
        if wire is not self._wire or wire.transport is None:
            return  # that connection was dropped, and the calls it had packed failed with it
        out, self._out = self._out, []
        if out:
            wire.transport.write(b"".join(out))

    def _answer(self, reply: Any) -> None:
        """The next answer, to the oldest call waiting (a caller that was cancelled left its
        answer to be skipped)."""
        if not self._waiting:
            self._lost(LaneError("Redis answered a command not sent"))
            return
        done = self._waiting.popleft()
        self._sent.popleft()
        if done.done():
            return
        if isinstance(reply, hiredis.ReplyError):
            done.set_exception(reply)
        else:
            done.set_result(reply)

    def _watch(self) -> None:
        """Every quarter of ``timeout`` while calls wait: the oldest waited too long?"""
        self._watchdog = None
        if not self._sent:
            return
        if time.monotonic() - self._sent[0] > self.timeout:
            self._lost(LaneTimeout(f"Redis did not answer within {self.timeout:g} s"))
            return
        self._watchdog = asyncio.get_running_loop().call_later(self.timeout / 4, self._watch)

    def _lost(self, why: LaneError, wire: _Wire | None = None) -> None:
        """Drop the connection (``wire``: only if it is still this lane's): every call in
        flight fails, the next one connects again."""
        if wire is not None and wire is not self._wire:
            return  # an older connection, already dropped
        wire, self._wire = self._wire, None
        if wire is not None:
            wire._resume()  # a caller waiting for the buffer to drain goes on (and fails)
            if wire.transport is not None:
                wire.transport.abort()  # what Redis did not read goes now, not at its return
        self._sent.clear()
        self._out.clear()
        if self._watchdog is not None:
            self._watchdog.cancel()
            self._watchdog = None
        while self._waiting:
            done = self._waiting.popleft()
            if not done.done():
                done.set_exception(why)

    async def close(self) -> None:
        self._lost(LaneError("closed"))


def _reason(exc: BaseException) -> str:
    """An exception in a few words (a TimeoutError says nothing of itself)."""
    if isinstance(exc, TimeoutError) and not str(exc):
        return "no answer in time"
    return str(exc) or type(exc).__name__
