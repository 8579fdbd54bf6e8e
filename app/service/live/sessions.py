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
from collections.abc import Callable

from starlette.concurrency import run_in_threadpool

from app.advice.advisor import Decision, DecisionBatch
from app.advice.strategies import StrategyParams
from app.arrays import Moves
from app.service.data.domains import DomainCatalog, DomainNotFound, DomainState
from app.service.data.store import Store
from app.service.live import codec
from app.service.live.registry import (
    Aggregate,
    LiveSession,
    SessionRegistry,
    SessionSnapshot,
)

log = logging.getLogger("advisor.sessions")


class StoreUnavailable(RuntimeError):
    """Where the live sessions are kept (Redis) does not answer: nothing was applied."""


#: what :meth:`LocalSessions.restore` needs of the catalog: a domain by name, and a domain made
#: ready for a strategy (its goal priors or guide map built, for the strategies that read them)
CatalogGet = Callable[[str], DomainState]
Prepare = Callable[[DomainState, str], None]


class LocalSessions:
    """The sessions of this process (:class:`SessionRegistry`), kept over a graceful restart
    in the database."""

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
        self, domain: DomainState, kappa: float, window: int, agent_type: str | None,
        start: int, strategy: str, params: StrategyParams, client: str | None,
    ) -> tuple[LiveSession, Decision]:  # fmt: skip
        """A new session and its start decision (the registry's refusals as they are)."""
        return self.registry.create(
            domain, kappa, window, agent_type, start, strategy, params, client
        )

    async def get(self, session_id: str) -> LiveSession:
        """The live session (SessionNotFound when it never was, ended or expired)."""
        return self.registry.get(session_id)

    def touch(self, session: LiveSession) -> None:
        self.registry.touch(session)

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

    def restore(self, store: Store, catalog_get: CatalogGet, prepare: Prepare) -> int:
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
                domain = catalog_get(v["domain"])
                prepare(domain, v["advisor"]["strategy"])
                session = codec.load(v, domain, self.registry.replay_steps)
                self.registry.put(session)
                kept += 1
            except (codec.CodecError, DomainNotFound, ValueError, KeyError, TypeError) as exc:
                log.warning("a saved session was not restored: %s", exc)
        return kept
