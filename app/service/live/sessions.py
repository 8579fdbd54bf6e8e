"""Live sessions as the routes, the MQTT bridge and the viewer's feed see them: one interface,
two forms.

* :class:`LocalSessions`, the embedded default: the :class:`SessionRegistry` of this process
  is where sessions live. A graceful shutdown writes them to the database and the next start
  reads them back (:mod:`app.service.live.codec`), so a restart keeps its explorers; a killed
  process loses them.
* ``SharedSessions`` (:mod:`app.service.live.shared`), with ``ADVISOR_REDIS_URL``: Redis is where
  sessions live and every worker answers every session; the registry of each worker only
  holds the sessions it used lately.

Every method that may reach Redis is a coroutine; the local form's run at once.
"""

from __future__ import annotations

import logging
import time
from typing import Protocol

from starlette.concurrency import run_in_threadpool

from app import strategies
from app.advice.advisor import Decision, DecisionBatch
from app.arrays import Moves
from app.service.data.domains import DomainCatalog, DomainNotFound, DomainState
from app.service.data.store import Store
from app.service.live import codec
from app.service.live.registry import (
    Aggregate,
    LiveSession,
    SessionRegistry,
    SessionSettings,
    SessionSnapshot,
)

log = logging.getLogger("advisor.sessions")


class StoreUnavailable(RuntimeError):
    """Where the live sessions are kept (Redis) does not answer: nothing was applied."""


class Sessions(Protocol):
    """The live sessions, as the routes, the MQTT bridge and the viewer's feed reach them:
    :class:`LocalSessions` (this process) or ``SharedSessions`` (Redis). Every method that may
    reach Redis is a coroutine."""

    shared: bool  # whether other workers serve the same sessions
    registry: SessionRegistry  # this process's sessions (with Redis: a cache of them)
    catalog: DomainCatalog

    @property
    def max_sessions(self) -> int: ...

    async def start(self) -> None:
        """At start: reach where the sessions are kept."""
        ...

    async def close(self) -> None:
        """At shutdown: let go of it."""
        ...

    # ---- domains as the routes read them ----------------------------------------------------
    async def domain(self, name: str) -> DomainState:
        """The domain ``name`` as the store holds it (DomainNotFound if there is none)."""
        ...

    async def sync_domain(self, name: str) -> None:
        """Before this process changes ``name``: its state as the store holds it."""
        ...

    async def sync_catalog(self) -> None:
        """Before listing domains: every one as the store holds it."""
        ...

    async def domain_changed(self, name: str, version: int, made_or_gone: bool) -> None:
        """After this process changed ``name`` (to data ``version``): tell the others."""
        ...

    # ---- sessions ---------------------------------------------------------------------------
    async def create(
        self, domain: DomainState, settings: SessionSettings, client: str | None
    ) -> tuple[LiveSession, Decision]:
        """A new session and its start decision (the registry's refusals as they are)."""
        ...

    async def get(self, session_id: str) -> LiveSession:
        """The live session (SessionNotFound when it never was, ended or expired)."""
        ...

    def touch(self, session: LiveSession) -> None:
        """``session`` was seen now (it is not idle)."""
        ...

    def current(self, session: LiveSession) -> LiveSession:
        """The copy of ``session`` that its last event left (this process's, after that
        event was answered): what an answer reads of its advisor besides the decision."""
        ...

    async def observe_one(
        self, session: LiveSession, state: int, action: int, next_state: int, step: int = -1
    ) -> Decision:
        """One checked move (``step``: the step it is meant to be, -1: the next)."""
        ...

    async def observe(
        self, session: LiveSession, moves: Moves, first_step: int | None = None
    ) -> DecisionBatch:
        """Checked moves, a long batch in slices (``first_step``: the first one's step)."""
        ...

    async def describe(self, session: LiveSession) -> SessionSnapshot: ...

    async def mute(self, session: LiveSession, muted: bool) -> None:
        """The visitor asks for no more advice (``muted``), or for advice again."""
        ...

    async def end(self, session: LiveSession) -> SessionSnapshot:
        """End the session; its final figures."""
        ...

    async def snapshot(self, limit: int | None, domain: str | None = None) -> list[SessionSnapshot]:
        """The ``limit`` most recently active sessions (of ``domain``)."""
        ...

    async def aggregates(self) -> dict[str, Aggregate]: ...

    async def count_by_domain(self) -> dict[str, int]: ...

    async def count(self) -> int: ...

    async def retable(self, domain: DomainState) -> None:
        """Sessions of ``domain`` follow its new prior (its map stayed)."""
        ...

    async def end_domain(self, name: str) -> int:
        """End every session of ``name`` (deleted, or its map replaced)."""
        ...

    async def sweep(self) -> None:
        """Idle sessions go; where explorers were is forgotten after the retention."""
        ...

    # ---- a graceful restart -----------------------------------------------------------------
    def save(self, store: Store) -> int:
        """*Worker thread, at shutdown.* Keep the live sessions for the next start (how many
        were kept)."""
        ...

    def restore(self, store: Store) -> int:
        """*Worker thread, at start.* Go on with what the last shutdown kept (how many)."""
        ...


class LocalSessions:
    """The sessions of this process (:class:`SessionRegistry`), kept over a graceful restart
    in the database (a :class:`Sessions`)."""

    shared = False

    def __init__(self, registry: SessionRegistry, catalog: DomainCatalog):
        self.registry = registry
        self.catalog = catalog

    async def start(self) -> None:
        """At start (the local form has nothing to reach)."""

    # ---- domains as the routes read them ----------------------------------------------------
    async def domain(self, name: str) -> DomainState:
        """The domain ``name`` (DomainNotFound if there is none)."""
        return self.catalog.get(name)

    async def sync_domain(self, name: str) -> None:
        """Before this process changes ``name``: its state as the store holds it (one
        process: it is)."""

    async def sync_catalog(self) -> None:
        """Before listing domains: every one as the store holds it (one process: they are)."""

    async def domain_changed(self, name: str, version: int, made_or_gone: bool) -> None:
        """After this process changed ``name`` (to data ``version``): nobody else to tell."""

    @property
    def max_sessions(self) -> int:
        return self.registry.max_sessions

    async def create(
        self, domain: DomainState, settings: SessionSettings, client: str | None
    ) -> tuple[LiveSession, Decision]:
        """A new session and its start decision (the registry's refusals as they are)."""
        return self.registry.create(domain, settings, client)

    async def get(self, session_id: str) -> LiveSession:
        """The live session (SessionNotFound when it never was, ended or expired)."""
        return self.registry.get(session_id)

    def touch(self, session: LiveSession) -> None:
        self.registry.touch(session)

    def current(self, session: LiveSession) -> LiveSession:
        return session  # the registry's own: events change it in place

    async def observe_one(
        self, session: LiveSession, state: int, action: int, next_state: int, step: int = -1
    ) -> Decision:
        return await self.registry.observe_after(session, state, action, next_state, step)

    async def observe(
        self, session: LiveSession, moves: Moves, first_step: int | None = None
    ) -> DecisionBatch:
        return await self.registry.observe_sliced(session, moves, first_step)

    async def describe(self, session: LiveSession) -> SessionSnapshot:
        return self.registry.describe(session)

    async def mute(self, session: LiveSession, muted: bool) -> None:
        self.registry.mute(session, muted)

    async def end(self, session: LiveSession) -> SessionSnapshot:
        """End the session; its final figures."""
        final = self.registry.describe(session)
        self.registry.end(session.id)
        return final

    async def snapshot(self, limit: int | None, domain: str | None = None) -> list[SessionSnapshot]:
        """The ``limit`` most recently active sessions (of ``domain``), made in a worker thread
        (the registry's lock is held only to copy numbers)."""
        return await run_in_threadpool(self.registry.snapshot, limit, domain)

    async def aggregates(self) -> dict[str, Aggregate]:
        return self.registry.aggregates()

    async def count_by_domain(self) -> dict[str, int]:
        return self.registry.count_by_domain()

    async def count(self) -> int:
        return len(self.registry)

    async def retable(self, domain: DomainState) -> None:
        """Sessions of ``domain`` follow its new prior (its map stayed)."""
        self.registry.retable(domain)

    async def end_domain(self, name: str) -> int:
        """End every session of ``name`` (deleted, or its map replaced)."""
        return self.registry.end_domain(name)

    async def sweep(self) -> None:
        """Idle sessions go; where explorers were is forgotten after the retention."""
        self.registry.expire()
        self.registry.forget_old()

    async def close(self) -> None:
        """At shutdown (the local form has nothing to let go)."""

    # ---- a graceful restart keeps live sessions ----------------------------------------------
    def save(self, store: Store) -> int:
        """*Worker thread, at shutdown.* Write every live session to the database (replacing
        what an earlier shutdown wrote); returns how many. Each is written under the
        registry's lock, between the events and the slices of a batch that may still run."""
        written = self.registry.written(codec.dump)
        store.save_sessions(written)
        return len(written)

    def restore(self, store: Store) -> int:
        """*Worker thread, at start.* Read back the sessions the last shutdown wrote (and
        forget them there): those still within the idle timeout whose domain has the same
        map go on where they were; returns how many."""
        now = time.time()
        kept = 0
        for raw in store.take_sessions():
            try:
                v = codec.peek(raw)
                if now - v["last_seen"] > self.registry.idle_seconds:
                    continue
                domain = self.catalog.get(v["domain"])
                self.catalog.prepare(domain, strategies.get(v["advisor"]["strategy"]).needs)
                session = codec.load(v, domain, self.registry.replay_steps)
                self.registry.put(session)
                kept += 1
            except (codec.CodecError, DomainNotFound, ValueError, KeyError, TypeError) as exc:
                log.warning("a saved session was not restored: %s", exc)
        return kept
