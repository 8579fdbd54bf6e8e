"""Live sessions: one advisor per explorer, with bounded recent history.

Sessions live in memory only (they are watchers, not data: an explorer that loses its session
opens a new one). The registry bounds them: at most ``max_sessions`` live at once, and a session
idle for ``idle_seconds`` is dropped. Each keeps its recent path, recent P(M1 | H) and recent
advice in bounded rings (:mod:`app.service.live.history`), so :meth:`SessionRegistry.snapshot`
(for ``/overview`` and the viewer) is cheap and safe to call from another thread: every change
and every snapshot holds one lock.

There is one path for one event (:meth:`SessionRegistry.observe_one`) and one for a batch
(:meth:`SessionRegistry.observe_batch`), whatever the strategy: what an advisor is (its
strategy, whether its advice is its own, its parameters and goal beliefs) it declares itself.
"""

from __future__ import annotations

import asyncio
import secrets
import threading
import time
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime
from typing import Any

import numpy as np
import numpy.typing as npt

from app import strategies
from app.advice.advisor import (
    DEFAULT_KAPPA,
    DEFAULT_STRATEGY,
    DEFAULT_WINDOW,
    NO_CAP,
    Advisor,
    Decision,
    DecisionBatch,
)
from app.advice.models import AdviceTables
from app.advice.params import StrategyParams
from app.arrays import Moves
from app.domain.building import Building
from app.service.data.domains import DomainState
from app.service.live.history import Advice, AdviceLog, Recent
from app.service.live.replay import DEFAULT_STEPS, Replay, retried
from app.service.security import token_digest
from app.strategies import AdvisorSettings
from app.strategies.beliefs import Beliefs, paper_beliefs

RECENT_ADVICE = 50


class SessionNotFound(KeyError):
    """No live session with that id (never created, ended, or expired)."""


class SessionUnreadable(SessionNotFound):
    """A session kept elsewhere (Redis) that this service cannot read: written by a version
    whose format, strategy or parameters it does not know (``args``: id, why)."""


class TooManySessions(RuntimeError):
    """The registry holds ``max_sessions`` live sessions already."""


class SessionMemoryFull(RuntimeError):
    """The live sessions have reserved the registry's memory budget (``args[0]`` bytes)."""


class ClientQuotaReached(RuntimeError):
    """One client holds as many sessions (``args[1] == "sessions"``) or as much session
    memory (``"memory"``) as one client may; ``args[0]`` is the client, ``args[2]`` the limit."""


#: What a session costs beside its advisor's arrays (:meth:`footprint`) and its history rings:
#: the session and advisor objects, their numbers and lists, the advice log (measured under
#: 10 kB for every strategy: tests/service/live/test_registry.py).
SESSION_OVERHEAD = 16 * 1024


@dataclass(frozen=True)
class Limits:
    """What the registry admits: live sessions in all, the bytes their state may reserve in
    all, and per client (None: no per-client limit)."""

    max_sessions: int
    max_memory: int | None = None
    client_sessions: int | None = None
    client_memory: int | None = None


@dataclass(frozen=True, slots=True)
class Budget:
    """A session's advice budget: at most ``total`` pieces of advice in all, and at most
    ``per_minute`` in any minute (a bucket of that many pieces, refilled at that rate); None:
    no such limit."""

    total: int | None = None
    per_minute: int | None = None


@dataclass(frozen=True, slots=True)
class SessionSettings:
    """A session's settings, checked, as one object from the request to the advisor: the
    advisor's (strategy, kappa, window, the strategy's parameters), the agent type whose prior
    serves it, and where it starts (None: the domain's start)."""

    advisor: AdvisorSettings = field(default_factory=AdvisorSettings)
    agent_type: str | None = None
    start: int | None = None
    budget: Budget | None = None

    @classmethod
    def of(
        cls, strategy: str = DEFAULT_STRATEGY, kappa: float = DEFAULT_KAPPA,
        window: int = DEFAULT_WINDOW,
        params: StrategyParams | Mapping[str, int | float] | None = None,
        agent_type: str | None = None, start: int | None = None, budget: Budget | None = None,
    ) -> SessionSettings:  # fmt: skip
        """Checked settings (ValueError: :meth:`Strategy.settings`)."""
        advisor = strategies.get(strategy).settings(kappa, window, params)
        return cls(advisor, agent_type, start, budget)


@dataclass(eq=False, slots=True)
class LiveSession:
    """One explorer watched by the advisor."""

    id: str
    token: str
    domain: DomainState
    agent_type: str | None
    table_key: str
    advisor: Advisor  # its strategy's service form (app.strategies)
    position: int
    p_normal: float
    created_at: datetime
    last_seen: float  # time.monotonic()
    sizes: tuple[int, int]  # how many recent cells and p_normal values to keep
    # recent cells and P(M1 | H), created at the first event (until then: the start alone)
    path: Recent | None = None
    p_history: Recent | None = None
    # (step, state, the tables that advised): theta_s is read at snapshot time, so an entry
    # costs three numbers (advisors whose advice is their own also keep the advice itself);
    # created at the first advice
    advice_log: AdviceLog | None = None
    closed: bool = False
    client: str | None = None  # who its quota counts against (None: no quota)
    reserved: int = 0  # bytes it reserved of the registry's budget
    busy: asyncio.Lock | None = None  # held while a batch runs in slices (made at the first)
    born: float = 0.0  # time.monotonic() at creation
    path_times: Recent | None = None  # seconds into the session of each cell of ``path``
    token_digest: bytes = b""  # SHA-256 of the token (``token`` is empty once it was loaded)
    replay: Replay = field(default_factory=lambda: Replay(0))  # its last decisions, for retries
    budget: Budget | None = None  # the advice it may be given (None: no budget)
    tokens: float = 0.0  # pieces left in its per-minute bucket, at ``tokens_at``
    tokens_at: float = 0.0  # wall-clock seconds (a session moves between workers)
    muted: bool = False  # the visitor asked for no more advice
    revision: int = 0  # changes of its state between events (a mute), for Redis' commits

    def state_step(self) -> str:
        """What the session's state is called where it is kept (Redis): its step, and how
        often it changed between events, so that a copy made before such a change is seen
        to be behind it."""
        steps = self.advisor.steps
        return str(steps) if self.revision == 0 else f"{steps}r{self.revision}"

    def limit_advice(self, now: float) -> int:
        """Set the advisor's cap for the next events (:attr:`Advisor.cap`): no more advice when
        muted, none past the budget's total, at most the pieces left in this minute's bucket
        (refilled up to ``now``, wall-clock seconds); returns the advice count before them."""
        adv = self.advisor
        count = adv.advice_count
        cap = count if self.muted else NO_CAP
        budget = self.budget
        if budget is not None and not self.muted:
            if budget.total is not None:
                cap = min(cap, budget.total)
            if budget.per_minute is not None:
                rate = budget.per_minute / 60.0
                elapsed = max(0.0, now - self.tokens_at)
                self.tokens = min(float(budget.per_minute), self.tokens + elapsed * rate)
                self.tokens_at = now
                cap = min(cap, count + int(self.tokens))
        adv.cap = cap
        return count

    def spent(self, count_before: int) -> None:
        """The advice given since :meth:`limit_advice` leaves this minute's bucket."""
        if self.budget is not None and self.budget.per_minute is not None:
            self.tokens -= self.advisor.advice_count - count_before

    def advice_left(self, now: float) -> tuple[int | None, int | None]:
        """(pieces left in all, pieces the bucket holds at ``now``); None where there is no
        limit."""
        b = self.budget
        if b is None:
            return None, None
        total = None if b.total is None else max(0, b.total - self.advisor.advice_count)
        minute = None
        if b.per_minute is not None:
            refilled = self.tokens + max(0.0, now - self.tokens_at) * b.per_minute / 60.0
            minute = int(min(float(b.per_minute), refilled))
        return total, minute

    def _rings(self) -> tuple[Recent, Recent]:
        """The recent path and P(M1 | H) rings, made at the first event (until then the
        session's start alone is its history)."""
        if self.path is None or self.p_history is None or self.path_times is None:
            self.path = Recent(self.sizes[0], np.int32, self.position)
            self.path_times = Recent(self.sizes[0], np.float32, self.last_seen - self.born)
            # for plots only: 7 significant digits are plenty, at half the memory
            self.p_history = Recent(self.sizes[1], np.float32, self.p_normal)
        return self.path, self.p_history

    def forget(self, now: float, retention: float) -> None:
        """Forget the cells it was at (recent path, where it was advised) more than
        ``retention`` seconds ago; its current cell stays (advice needs it)."""
        cutoff = now - self.born - retention
        path, path_times = self.path, self.path_times
        # the oldest first, without copies: this runs at every write of a session to Redis
        if path is not None and path_times is not None and path_times.oldest() < cutoff:
            times = path_times.array()
            keep = int(np.count_nonzero(times >= cutoff))  # times only grow along the ring
            if keep == 0:
                self.path = self.path_times = None
            elif keep < len(times):
                cells = path.array()[-keep:]
                self.path = Recent(self.sizes[0], np.int32, int(cells[0]))
                self.path.extend(cells[1:])
                self.path_times = Recent(self.sizes[0], np.float32, float(times[-keep]))
                self.path_times.extend(times[len(times) - keep + 1 :])
        if self.advice_log is not None:
            when, oldest = int(cutoff * 1000), self.advice_log.oldest_when()
            if (oldest is None or oldest < when) and not self.advice_log.forget_before(when):
                self.advice_log = None

    def _log(self) -> AdviceLog:
        """The advice log, made at the first piece of advice."""
        if self.advice_log is None:
            self.advice_log = AdviceLog(RECENT_ADVICE)
        return self.advice_log

    def record_one(self, d: Decision, tables: AdviceTables, now: float) -> None:
        """Remember one decision made with ``tables`` at ``now`` (recent path, posterior,
        advice)."""
        path, p_history = self._rings()
        self.position = d.state
        self.p_normal = d.p_normal
        path.push(d.state)
        at = now - self.born
        self.path_times.push(at)  # type: ignore[union-attr]  # made with the rings
        p_history.push(d.p_normal)
        self.replay.add_one(d)
        if d.advise:
            own = d.advice if self.advisor.own_advice else None
            self._log().add(d.step, d.state, tables, own, int(at * 1000))

    def record_batch(self, out: DecisionBatch, tables: AdviceTables, now: float) -> None:
        """:meth:`record_one` for a batch of decisions made with ``tables`` at ``now``."""
        n = len(out)
        if not n:
            return
        path, p_history = self._rings()
        self.position = int(out.state[-1])
        self.p_normal = float(out.p_normal[-1])
        path.extend(out.state)
        at = now - self.born
        self.path_times.extend(np.full(n, at, dtype=np.float32))  # type: ignore[union-attr]
        p_history.extend(out.p_normal)
        self.replay.add(out)
        advised = np.flatnonzero(out.advise)[-RECENT_ADVICE:]
        if len(advised):
            own = out.advice[-len(advised) :] if self.advisor.own_advice else None
            when = int(at * 1000)
            self._log().extend(advised + out.first_step, out.state[advised], tables, own, when)


@dataclass(frozen=True, slots=True)
class SessionSnapshot:
    """A copy of one session's figures in plain data (cells as (row, col))."""

    id: str
    domain: str
    agent_type: str | None
    table_key: str
    kappa: float
    window: int
    strategy: str
    params: dict[str, int | float]  # the strategy's parameters in force
    steps: int
    position: tuple[int, ...]
    p_normal: float
    advice_count: int
    total_cost: float
    benefit: float
    advice_per_100: float
    created_at: datetime
    idle_seconds: float
    path: list[tuple[int, ...]]
    p_history: list[float]
    advice: list[tuple[int, tuple[int, ...], Advice]]  # (step, cell, theta_s), oldest first
    # advisors with a goal posterior: (goal cell, P(goal | H), ruled out) per goal of the map
    goals: list[tuple[tuple[int, ...], float, bool]] | None = None
    budget: Budget | None = None  # its advice budget
    advice_left: tuple[int | None, int | None] = (None, None)  # in all, this minute
    muted: bool = False
    beliefs: Beliefs | None = None  # what its advisor believes, in plain words
    # the destination its advice leads to: (goal index, cell, name or None)
    leads_to: tuple[int, tuple[int, ...], str | None] | None = None
    # on a map of several floors, the name of the floor the explorer is on (None: one floor)
    floor: str | None = None


class SessionRegistry:
    """Every live session by id, bounded in number and idle time."""

    def __init__(
        self, limits: Limits | int, idle_seconds: float, recent_path: int = 100,
        recent_p: int = 200, replay_steps: int = DEFAULT_STEPS,
    ):  # fmt: skip
        self.limits = limits if isinstance(limits, Limits) else Limits(limits)
        self.idle_seconds = idle_seconds
        self.history_sizes = (recent_path, recent_p)
        self.replay_steps = replay_steps  # decisions each session keeps for retries
        self.lock = threading.Lock()
        self._sessions: dict[str, LiveSession] = {}
        self.reserved = 0  # bytes reserved by the live sessions
        self._clients: dict[str, list[int]] = {}  # client -> [sessions, bytes]
        #: seconds the cells an explorer was at are kept (None: as long as the rings hold them)
        self.retention: float | None = None
        #: a cache of sessions kept elsewhere (Redis): beyond the limits the least recently
        #: seen are dropped, rather than new ones refused
        self.evicts = False
        #: wall-clock seconds, for the sessions' per-minute advice budgets (a session moves
        #: between workers; tests give a clock of their own)
        self.wall: Callable[[], float] = time.time

    @property
    def max_sessions(self) -> int:
        return self.limits.max_sessions

    @max_sessions.setter
    def max_sessions(self, value: int) -> None:
        self.limits = replace(self.limits, max_sessions=value)

    def reservation(self, advisor: Advisor) -> int:
        """Bytes a session with ``advisor`` reserves: the most its advisor's arrays can take,
        its history rings (int32 cells, float32 P(M1 | H)), the decisions it keeps for retries
        and :data:`SESSION_OVERHEAD`."""
        width = advisor.tables.n_actions
        rings = 4 * sum(self.history_sizes) + Replay.footprint(self.replay_steps, width)
        return advisor.footprint() + rings + SESSION_OVERHEAD

    def client_usage(self, client: str) -> tuple[int, int]:
        """(live sessions, bytes reserved) of ``client``."""
        with self.lock:
            n, used = self._clients.get(client, (0, 0))
        return n, used

    def __len__(self) -> int:
        return len(self._sessions)

    def create(
        self, domain: DomainState, settings: SessionSettings, client: str | None = None
    ) -> tuple[LiveSession, Decision]:
        """A new session and the decision for its start state (empty history). The domain has
        what the strategy needs built (:meth:`DomainCatalog.prepare`).

        Admitted within the :class:`Limits` (idle sessions are expired first when one is
        reached): :class:`TooManySessions`, :class:`SessionMemoryFull` or, for ``client``,
        :class:`ClientQuotaReached` otherwise."""
        key = domain.view.resolve(settings.agent_type)
        data = domain.data(key)
        tables = data.tables
        advisor = strategies.get(settings.advisor.strategy).service_advisor(data, settings.advisor)
        agent_type = settings.agent_type
        start = domain.domain.start if settings.start is None else settings.start
        need = self.reservation(advisor)
        budget = settings.budget
        tokens = float(budget.per_minute or 0) if budget is not None else 0.0
        if budget is not None:  # the start decision within the budget too
            advisor.cap = min(budget.total if budget.total is not None else NO_CAP,
                              int(tokens) if budget.per_minute is not None else NO_CAP)  # fmt: skip
        decision = advisor.start(start)
        wall = self.wall()
        now = time.monotonic()
        with self.lock:
            self._admit(need, client, now)
            sid = secrets.token_hex(8)
            token = secrets.token_urlsafe(24)
            session = LiveSession(
                sid, token, domain, agent_type, key, advisor, start, decision.p_normal,
                datetime.now(UTC), now, self.history_sizes, client=client, reserved=need,
                born=now, token_digest=token_digest(token),
                replay=Replay(self.replay_steps, domain.domain.n_actions),
                budget=budget, tokens=tokens, tokens_at=wall,
            )  # fmt: skip
            session.spent(0)  # the start decision's advice, if any, left this minute's bucket
            session.replay.restart(decision.advice_count, decision.benefit)
            if decision.advise:
                own = decision.advice if advisor.own_advice else None
                session._log().add(0, start, tables, own)
            self._sessions[sid] = session
            self.reserved += need
            if client is not None:
                used = self._clients.setdefault(client, [0, 0])
                used[0] += 1
                used[1] += need
        return session, decision

    def put(self, session: LiveSession) -> None:
        """Hold a session made elsewhere (read back after a restart, or from Redis), within
        the limits as :meth:`create` admits one; one of the same id is replaced."""
        need = self.reservation(session.advisor)
        with self.lock:
            old = self._sessions.get(session.id)
            if old is not None:
                self._drop(old)
            self._admit(need, session.client, time.monotonic())
            session.reserved = need
            self._sessions[session.id] = session
            self.reserved += need
            if session.client is not None:
                used = self._clients.setdefault(session.client, [0, 0])
                used[0] += 1
                used[1] += need

    def _admit(self, need: int, client: str | None, now: float) -> None:
        """Under the lock: room for a session reserving ``need`` bytes for ``client``, idle
        sessions expired first; then, in a registry that :attr:`evicts` (a cache of sessions
        kept elsewhere), the least recently seen dropped; else the refusal raised."""
        if self._refusal(need, client) is None:
            return
        self._expire(now)
        refused = self._refusal(need, client)
        while refused is not None and self.evicts and self._sessions:
            self._drop(min(self._sessions.values(), key=lambda s: s.last_seen))
            refused = self._refusal(need, client)
        if refused is not None:
            raise refused

    def _refusal(self, need: int, client: str | None) -> RuntimeError | None:
        """Why a session reserving ``need`` bytes for ``client`` cannot be admitted now."""
        lim = self.limits
        if len(self._sessions) >= lim.max_sessions:
            return TooManySessions(lim.max_sessions)
        if lim.max_memory is not None and self.reserved + need > lim.max_memory:
            return SessionMemoryFull(lim.max_memory)
        if client is None:
            return None
        n, used = self._clients.get(client, (0, 0))
        if lim.client_sessions is not None and n >= lim.client_sessions:
            return ClientQuotaReached(client, "sessions", lim.client_sessions)
        if lim.client_memory is not None and used + need > lim.client_memory:
            return ClientQuotaReached(client, "memory", lim.client_memory)
        return None

    def _drop(self, session: LiveSession) -> None:
        """Under the lock: ``session`` leaves (ended, expired or its domain gone)."""
        session.closed = True
        del self._sessions[session.id]
        self.reserved -= session.reserved
        if session.client is not None:
            used = self._clients[session.client]
            used[0] -= 1
            used[1] -= session.reserved
            if used[0] == 0:
                del self._clients[session.client]

    def get(self, session_id: str) -> LiveSession:
        session = self._sessions.get(session_id)
        if session is None or session.closed:
            raise SessionNotFound(session_id)
        return session

    def observe_one(
        self, session: LiveSession, state: int, action: int, next_state: int, step: int = -1
    ) -> Decision:
        """Advance ``session`` by one checked (s, a, s'); ``step`` (-1: none) as
        :meth:`observe_batch` takes it."""
        with self.lock:
            if session.closed:
                raise SessionNotFound(session.id)
            adv = session.advisor
            if step >= 0 and step != adv.steps + 1:  # a retry (or a step out of turn)
                moves = tuple(np.array([v], dtype=np.int64) for v in (state, action, next_state))
                return self._observe(session, moves, step).decisions()[0]  # type: ignore[arg-type]
            tables = adv.tables
            before = session.limit_advice(self.wall())
            d = adv.observe(state, action, next_state)
            session.spent(before)
            now = time.monotonic()
            session.record_one(d, tables, now)
            session.last_seen = now
        return d

    def observe_batch(
        self, session: LiveSession, moves: Moves, first_step: int | None = None
    ) -> DecisionBatch:
        """Advance ``session`` by checked (s, a, s') arrays; its decisions as columns.
        ``first_step``: the step the first move is meant to be (None: the next one); steps
        already applied are answered with their decisions (:meth:`replayed`)."""
        with self.lock:
            if session.closed:
                raise SessionNotFound(session.id)
            return self._observe(session, moves, first_step)

    def _observe(self, session: LiveSession, moves: Moves, first_step: int | None) -> DecisionBatch:
        done, rest = self.replayed(session, moves, first_step)
        if rest is None:
            assert done is not None
            return done
        adv = session.advisor
        tables = adv.tables
        before = session.limit_advice(self.wall())
        out = adv.observe_batch(*rest)
        session.spent(before)
        now = time.monotonic()
        session.record_batch(out, tables, now)
        session.last_seen = now
        return out if done is None else joined([done, out])

    @staticmethod
    def replayed(
        session: LiveSession, moves: Moves, first_step: int | None
    ) -> tuple[DecisionBatch | None, Moves | None]:
        """(the decisions of the moves whose steps ``session`` applied already, the moves still
        to apply): a retry is answered what it was answered, and nothing is applied twice.
        StepConflict when the first step is beyond the next one, was applied with another
        move, or was applied and its decision is no longer kept."""
        adv, replay = session.advisor, session.replay
        return retried(
            session.id, adv.steps, first_step, moves,
            lambda first, n: replay.answer(first, n, adv.steps, adv.kappa), replay.kept,
        )  # fmt: skip

    async def observe_sliced(
        self, session: LiveSession, moves: Moves, first_step: int | None = None
    ) -> DecisionBatch:
        """:meth:`observe_batch` on the event loop without holding it long: a batch is run in
        slices of the advisor's :meth:`batch_slice` events (about 2 ms of work each), with
        the loop free for other clients between them. The session runs one batch at a time,
        and a single event sent meanwhile waits for the batch (:meth:`observe_after`), so a
        batch's decisions stay consecutive steps."""
        n, step = len(moves[0]), session.advisor.batch_slice()
        if n <= step and (session.busy is None or not session.busy.locked()):
            return self.observe_batch(session, moves, first_step)
        if session.busy is None:
            session.busy = asyncio.Lock()
        async with session.busy:
            with self.lock:
                if session.closed:
                    raise SessionNotFound(session.id)
                done, rest = self.replayed(session, moves, first_step)
            parts = [] if done is None else [done]
            if rest is not None:
                for lo in range(0, len(rest[0]), step):
                    if lo:
                        await asyncio.sleep(0)  # others' turn
                    part = (rest[0][lo : lo + step], rest[1][lo : lo + step],
                            rest[2][lo : lo + step])  # fmt: skip
                    parts.append(self.observe_batch(session, part))
        return joined(parts) if len(parts) != 1 else parts[0]

    async def observe_after(
        self, session: LiveSession, state: int, action: int, next_state: int, step: int = -1
    ) -> Decision:
        """:meth:`observe_one`, after the session's batch in progress, if there is one."""
        if session.busy is not None and session.busy.locked():
            async with session.busy:
                return self.observe_one(session, state, action, next_state, step)
        return self.observe_one(session, state, action, next_state, step)

    def mute(self, session: LiveSession, muted: bool) -> None:
        """The visitor asked for no more advice (``muted``), or for advice again."""
        with self.lock:
            if session.closed:
                raise SessionNotFound(session.id)
            session.muted = muted

    def touch(self, session: LiveSession) -> None:
        session.last_seen = time.monotonic()

    def cached(self, session_id: str) -> LiveSession | None:
        """The session if this registry holds it (None otherwise: no error)."""
        session = self._sessions.get(session_id)
        return None if session is None or session.closed else session

    def forget(self, session_id: str) -> None:
        """Drop the session if held (a cache letting go; nothing ends elsewhere)."""
        with self.lock:
            session = self._sessions.get(session_id)
            if session is not None:
                self._drop(session)

    def end(self, session_id: str) -> LiveSession:
        with self.lock:
            session = self._sessions.get(session_id)
            if session is None or session.closed:
                raise SessionNotFound(session_id)
            self._drop(session)
        return session

    def end_domain(self, name: str) -> int:
        """End every session of domain ``name`` (it was deleted or its map replaced)."""
        with self.lock:
            gone = [s for s in self._sessions.values() if s.domain.name == name]
            for s in gone:
                self._drop(s)
        return len(gone)

    def retable(self, domain: DomainState) -> None:
        """Point the sessions of ``domain`` at its current prior view (new tables and per-goal
        counts after new trajectories); each advisor's window stays exact."""
        view = domain.view
        with self.lock:
            for s in self._sessions.values():
                if s.domain.name == domain.name:
                    s.domain = domain
                    s.table_key = view.resolve(s.agent_type)
                    s.advisor.use_tables(view.tables[s.table_key], domain.goal_priors)

    def expire(self) -> int:
        with self.lock:
            return self._expire(time.monotonic())

    def _expire(self, now: float) -> int:
        idle = [s for s in self._sessions.values() if now - s.last_seen > self.idle_seconds]
        for s in idle:
            self._drop(s)
        return len(idle)

    def sessions(self) -> list[LiveSession]:
        with self.lock:
            return list(self._sessions.values())

    def written(self, write: Callable[[LiveSession], bytes]) -> list[tuple[str, bytes]]:
        """(id, ``write(session)``) of every live session, each written under the lock (so
        between events, and between the slices of a batch still running), without the cells
        older than the retention."""
        now = time.monotonic()
        with self.lock:
            out = []
            for s in self._sessions.values():
                if self.retention is not None:
                    s.forget(now, self.retention)
                out.append((s.id, write(s)))
            return out

    def write(self, session: LiveSession, write: Callable[[LiveSession], bytes]) -> bytes:
        """``write(session)`` under the lock, without the cells older than the retention
        (what is stored elsewhere, Redis, keeps no more of where an explorer was than an
        answer shows)."""
        with self.lock:
            if self.retention is not None:
                session.forget(time.monotonic(), self.retention)
            return write(session)

    def count_by_domain(self) -> dict[str, int]:
        with self.lock:
            return dict(Counter(s.domain.name for s in self._sessions.values()))

    def describe(self, session: LiveSession) -> SessionSnapshot:
        now = time.monotonic()
        with self.lock:
            raw = self._raw(session, now)
        return _snap(raw)

    def snapshot(
        self, limit: int | None = None, domain: str | None = None
    ) -> list[SessionSnapshot]:
        """Copies of the most recently active sessions (all if ``limit`` is None). Under the
        lock only the numbers are copied (every event waits for that lock); they are shaped
        into plain data after it."""
        now = time.monotonic()
        with self.lock:
            live = [s for s in self._sessions.values() if domain is None or s.domain.name == domain]
            live.sort(key=lambda s: s.last_seen, reverse=True)
            raws = [self._raw(s, now) for s in live[:limit]]
        return [_snap(r) for r in raws]

    def _raw(self, s: LiveSession, now: float) -> _Raw:
        if self.retention is not None:
            s.forget(now, self.retention)
        adv = s.advisor
        return _Raw(
            s, now - s.last_seen, adv.kappa, adv.window, adv.strategy, adv.params(), adv.steps,
            s.position, s.p_normal, adv.advice_count, adv.total_cost, adv.benefit,
            adv.advice_per_100, s.path.array() if s.path else None,
            s.p_history.array() if s.p_history else None,
            s.advice_log.items() if s.advice_log else [], adv.goal_beliefs(),
            s.advice_left(self.wall()), beliefs_of(adv, s.p_normal),
        )  # fmt: skip

    def forget_old(self) -> None:
        """Apply the retention to every session (the sweeper calls this)."""
        if self.retention is None:
            return
        now = time.monotonic()
        with self.lock:
            for s in self._sessions.values():
                s.forget(now, self.retention)

    def aggregates(self) -> dict[str, Aggregate]:
        """Per domain, figures over its live sessions (no session's own)."""
        out: dict[str, Aggregate] = {}
        with self.lock:
            for s in self._sessions.values():
                agg = out.setdefault(s.domain.name, Aggregate())
                adv = s.advisor
                agg.sessions += 1
                agg.steps += adv.steps
                agg.decisions += adv.decisions
                agg.advice += adv.advice_count
                agg.looking_lost += s.p_normal < 0.5
        return out


@dataclass(slots=True)
class Aggregate:
    """Figures over a domain's live sessions."""

    sessions: int = 0
    steps: int = 0
    decisions: int = 0
    advice: int = 0
    looking_lost: int = 0  # P(M1 | H) below 1/2


@dataclass(slots=True)
class _Raw:
    """What a snapshot copies under the registry's lock."""

    s: LiveSession
    idle: float
    kappa: float
    window: int
    strategy: str
    params: dict[str, int | float]
    steps: int
    position: int
    p_normal: float
    advice_count: int
    total_cost: float
    benefit: float
    advice_per_100: float
    path: npt.NDArray[np.int32] | None
    p_history: npt.NDArray[np.float32] | None
    advice: list[tuple[int, int, AdviceTables | Advice]]
    beliefs: list[tuple[int, float, bool]] | None
    advice_left: tuple[int | None, int | None]
    plain: Beliefs


def joined(parts: list[DecisionBatch]) -> DecisionBatch:
    """Consecutive batches of one session as one (advice from the tables of each part: kept
    as the parts' tables if they all had the same, else as the advice rows themselves)."""
    first = parts[0]
    source = first.advised_from
    same = source is not None and all(p.advised_from is source for p in parts)

    def column(name: str) -> npt.NDArray[Any]:
        return np.concatenate([getattr(p, name) for p in parts])

    return DecisionBatch(
        first.first_step, column("state"), column("advise"), column("kl"), column("p_normal"),
        column("advice_count"), column("benefit"), column("advice"), first.kappa,
        first.count_before, first.benefit_before, source if same else None,
    )  # fmt: skip


def _snap(r: _Raw) -> SessionSnapshot:
    s = r.s
    cells = s.domain.domain.cells

    def cell(state: int) -> tuple[int, ...]:
        return tuple(cells[state].tolist())

    path = cells[r.path if r.path is not None else [r.position]].tolist()
    grid = s.domain.domain
    leads, goal = None, r.plain.leads_to
    if goal is not None and 0 <= goal < len(grid.goals):
        leads = (goal, cell(grid.goals[goal]), grid.goal_names[goal] if grid.goal_names else None)
    return SessionSnapshot(
        s.id, s.domain.name, s.agent_type, s.table_key, r.kappa, r.window, r.strategy,
        r.params, r.steps, cell(r.position), r.p_normal, r.advice_count, r.total_cost,
        r.benefit, r.advice_per_100, s.created_at, r.idle, [tuple(c) for c in path],
        r.p_history.tolist() if r.p_history is not None else [r.p_normal],
        [(step, cell(st), _advice(tables, st)) for step, st, tables in r.advice],
        None if r.beliefs is None else [(cell(g), p, out) for g, p, out in r.beliefs],
        s.budget, r.advice_left, s.muted, r.plain, leads,
        grid.floors[int(cells[r.position, 0])].name if isinstance(grid, Building) else None,
    )  # fmt: skip


def beliefs_of(advisor: Advisor, p_normal: float) -> Beliefs:
    """What ``advisor`` believes, as its strategy's entry reads it (the paper's reading for
    a strategy no longer in the table)."""
    entry = strategies.STRATEGIES.get(advisor.strategy)
    return (entry.beliefs if entry is not None else paper_beliefs)(advisor, p_normal)


def _advice(source: AdviceTables | Advice, state: int) -> Advice:
    if not isinstance(source, AdviceTables):
        return source
    return tuple(source.theta[state].tolist())
