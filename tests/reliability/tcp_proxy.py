"""A TCP proxy a test controls (its own asyncio loop in a thread), between the service and a
server it must not touch (the machine's shared PostgreSQL): it forwards, or pauses (holds
every byte both ways, the connections open: a database that stopped answering), or drops
(resets every connection and refuses new ones: a database that went away)."""

from __future__ import annotations

import asyncio
import threading
from typing import Any

from tests.client.conftest import free_port


class Proxy:
    def __init__(self, upstream: tuple[str, int]):
        self.upstream = upstream
        self.port = free_port()
        self.loop = asyncio.new_event_loop()
        self._flowing: asyncio.Event | None = None
        self._refusing = False
        self._writers: set[asyncio.StreamWriter] = set()
        self._started = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        self._started.wait(10)

    def _run(self) -> None:
        asyncio.set_event_loop(self.loop)
        self._flowing = asyncio.Event()
        self._flowing.set()
        self.loop.run_until_complete(self._listen())
        self._started.set()
        self.loop.run_forever()

    async def _listen(self) -> None:
        self._server = await asyncio.start_server(self._handle, "127.0.0.1", self.port)

    async def _handle(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if self._refusing:
            writer.transport.abort()
            return
        try:
            up_reader, up_writer = await asyncio.open_connection(*self.upstream)
        except OSError:
            writer.transport.abort()
            return
        self._writers |= {writer, up_writer}
        await asyncio.gather(
            self._pump(reader, up_writer), self._pump(up_reader, writer), return_exceptions=True
        )
        for w in (writer, up_writer):
            self._writers.discard(w)
            w.transport.abort()

    async def _pump(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        assert self._flowing is not None
        while data := await reader.read(1 << 16):
            await self._flowing.wait()  # paused: held here
            writer.write(data)
            await writer.drain()
        writer.transport.abort()

    def _call(self, fn: Any) -> None:
        done = threading.Event()

        def run() -> None:
            fn()
            done.set()

        self.loop.call_soon_threadsafe(run)
        done.wait(10)

    def pause(self) -> None:
        """Hold everything: the database stops answering, its connections stay open."""
        assert self._flowing is not None
        self._call(self._flowing.clear)

    def resume(self) -> None:
        assert self._flowing is not None
        self._call(self._flowing.set)

    def drop(self) -> None:
        """Reset every connection and refuse new ones: the database is gone."""

        def cut() -> None:
            self._refusing = True
            for w in list(self._writers):
                w.transport.abort()

        self._call(cut)

    def allow(self) -> None:
        def let() -> None:
            self._refusing = False

        self._call(let)

    def close(self) -> None:
        self.resume()
        self.drop()
        self.loop.call_soon_threadsafe(self.loop.stop)
        self._thread.join(10)
