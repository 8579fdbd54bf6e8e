"""Answers built once for all who ask at the same time (:func:`once`), and kept for a short
while (:class:`Fresh`): what the big read answers (:mod:`app.service.answers`) and the answers
that change with every event (the overview, the viewer's feed) are made with."""

from __future__ import annotations

import asyncio
import inspect
import time
from collections.abc import Awaitable, Callable
from typing import Any

from starlette.concurrency import run_in_threadpool

_building: dict[object, asyncio.Future[bytes]] = {}


async def once(key: object, build: Callable[[], bytes | Awaitable[bytes]]) -> bytes:
    """``build()`` in a worker thread (or, a coroutine function, awaited), once for all who
    ask for ``key`` while it runs (a reader that goes away does not cancel it for the
    others)."""
    running = _building.get(key)
    if running is None:
        work = build() if inspect.iscoroutinefunction(build) else run_in_threadpool(build)
        running = asyncio.ensure_future(work)  # type: ignore[arg-type]
        _building[key] = running
        running.add_done_callback(lambda _: _building.pop(key, None))
    return await asyncio.shield(running)


class Fresh:
    """Answers made at most once per ``max_age`` seconds for each key (one per service)."""

    def __init__(self) -> None:
        self._made: dict[Any, tuple[float, bytes]] = {}

    async def get(self, key: Any, max_age: float, build: Callable[[], Awaitable[bytes]]) -> bytes:
        """``await build()`` (which makes its text in a worker thread), once for all who ask
        meanwhile, or its answer if made less than ``max_age`` ago."""
        made = self._made.get(key)
        if made is not None and time.monotonic() - made[0] < max_age:
            return made[1]
        text = await once(("fresh", id(self), key), build)
        self._made[key] = (time.monotonic(), text)
        if len(self._made) > 64:  # keys are few (limits and domains asked for): the newest
            for old in sorted(self._made, key=lambda k: self._made[k][0])[:32]:
                del self._made[old]
        return text
