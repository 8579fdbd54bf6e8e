"""The connections that carry the events' scripts to Redis: pipelined, so that many sessions
share one without waiting for each other's answers.

Every event is one script call (:mod:`app.service.live.shared`). Through redis-py's asyncio
client a call cost this worker 110-250 us of CPU (its pool, its locks and checks: measured
in docs/PERFORMANCE.md, "Workers"), most of a REST event's budget; a :class:`Lane` packs the
command with hiredis (the C parser redis-py itself uses), writes it, and matches answers to
callers in the order Redis sends them, which is the order they were written. Everything else
(reads, admin, the sweep) goes through redis-py.

A lane that loses its connection fails the calls in flight (the caller answers 503, a retry
with the same step is safe) and connects again at the next call; a call that gets no answer
within ``timeout`` seconds (checked every quarter of it: at most 1.25 ``timeout``) fails the
same way, since a late answer could no longer be told apart. One watchdog a lane does that
check, not a timer a call (each timer is an entry in the event loop's heap, made and
cancelled at every event).
"""

from __future__ import annotations

import asyncio
import collections
import ssl
import time
from typing import Any

import hiredis
from redis.connection import parse_url


class LaneError(ConnectionError):
    """The lane's connection failed, or Redis did not answer in time."""


class Lane:
    """One pipelined connection to the Redis of ``url`` (``redis://``, ``rediss://`` or
    ``unix://``, as redis-py reads them)."""

    def __init__(self, url: str, timeout: float = 10.0):
        self.options = parse_url(url)  # type: ignore[no-untyped-call]
        self.tls = url.startswith("rediss://")
        self.timeout = timeout
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None
        self._waiting: collections.deque[asyncio.Future[Any]] = collections.deque()
        self._sent: collections.deque[float] = collections.deque()  # when each was written
        self._watchdog: asyncio.TimerHandle | None = None
        self._reading: asyncio.Task[None] | None = None
        self._connecting = asyncio.Lock()

    async def _connect(self) -> asyncio.StreamWriter:
        async with self._connecting:
            if self._writer is not None:
                return self._writer
            o = self.options
            if "path" in o:
                reader, writer = await asyncio.open_unix_connection(o["path"])
            else:
                context = ssl.create_default_context() if self.tls else None
                reader, writer = await asyncio.open_connection(
                    o.get("host", "127.0.0.1"), o.get("port", 6379), ssl=context
                )
            self._reader = reader
            self._reading = asyncio.get_running_loop().create_task(self._read(reader))
            hello: list[tuple[Any, ...]] = []
            if o.get("password"):
                user = o.get("username")
                hello.append(("AUTH", user, o["password"]) if user else ("AUTH", o["password"]))
            if o.get("db"):
                hello.append(("SELECT", o["db"]))
            answers = [self._write(writer, command) for command in hello]  # first on the wire
            self._writer = writer
            for done in answers:
                await self._wait(done)
            return writer

    async def call(self, *args: Any) -> Any:
        """Send one command; its answer (ReplyError from Redis is raised as is)."""
        writer = self._writer or await self._connect()
        return await self._send(writer, args)

    async def _send(self, writer: asyncio.StreamWriter, args: tuple[Any, ...]) -> Any:
        done = self._write(writer, args)
        if writer.transport.get_write_buffer_size() > 1 << 20:
            await writer.drain()
        return await self._wait(done)

    def _write(self, writer: asyncio.StreamWriter, args: tuple[Any, ...]) -> asyncio.Future[Any]:
        loop = asyncio.get_running_loop()
        done: asyncio.Future[Any] = loop.create_future()
        self._waiting.append(done)
        self._sent.append(time.monotonic())
        writer.write(hiredis.pack_command(args))
        if self._watchdog is None:
            self._watchdog = loop.call_later(self.timeout / 4, self._watch)
        return done

    async def _wait(self, done: asyncio.Future[Any]) -> Any:
        """The answer to ``done``'s command, or LaneError once it waited ``timeout`` seconds (a
        caller that is cancelled leaves its answer to be skipped when it comes)."""
        return await done

    def _watch(self) -> None:
        """Every quarter of ``timeout`` while calls wait: the oldest waited too long?"""
        self._watchdog = None
        if not self._sent:
            return
        if time.monotonic() - self._sent[0] > self.timeout:
            self._lost(LaneError(f"Redis did not answer within {self.timeout} s"))
            return
        self._watchdog = asyncio.get_running_loop().call_later(self.timeout / 4, self._watch)

    async def _read(self, reader: asyncio.StreamReader) -> None:
        parser = hiredis.Reader()
        try:
            while True:
                data = await reader.read(1 << 16)
                if not data:
                    raise LaneError("Redis closed the connection")
                parser.feed(data)
                while (reply := parser.gets()) is not False:
                    done = self._waiting.popleft()
                    self._sent.popleft()
                    if done.done():
                        continue  # its caller gave up (the connection is being dropped)
                    if isinstance(reply, hiredis.ReplyError):
                        done.set_exception(reply)
                    else:
                        done.set_result(reply)
        except (OSError, LaneError, asyncio.IncompleteReadError) as exc:
            self._lost(exc if isinstance(exc, LaneError) else LaneError(str(exc)))

    def _lost(self, why: LaneError) -> None:
        """Drop the connection: every call in flight fails, the next one connects again."""
        writer, self._writer, self._reader = self._writer, None, None
        if writer is not None:
            writer.close()
        reading, self._reading = self._reading, None
        if reading is not None and reading is not asyncio.current_task():
            reading.cancel()
        self._sent.clear()
        if self._watchdog is not None:
            self._watchdog.cancel()
            self._watchdog = None
        while self._waiting:
            done = self._waiting.popleft()
            if not done.done():
                done.set_exception(why)

    async def close(self) -> None:
        self._lost(LaneError("closed"))
