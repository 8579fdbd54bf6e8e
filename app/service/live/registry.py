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

import secrets
import threading
import time
from collections import Counter
from dataclasses import dataclass
from datetime import UTC, datetime

import numpy as np
import numpy.typing as npt

from app.advice.advisor import Advisor, Decision, DecisionBatch
from app.advice.guide import GuideMap
from app.advice.models import AdviceTables
from app.advice.priors import GoalPriors
from app.advice.strategies import StrategyParams, guide_params, make_advisor
from app.service.data.domains import DomainState
from app.service.live.history import Advice, AdviceLog, Recent
from app.service.live.stream import StreamAdvisor, StreamGuide

IntArray = npt.NDArray[np.int64]
RECENT_ADVICE = 50


class SessionNotFound(KeyError):
    """No live session with that id (never created, ended, or expired)."""


class TooManySessions(RuntimeError):
    """The registry holds ``max_sessions`` live sessions already."""


def new_advisor(
    strategy: str, tables: AdviceTables, kappa: float, window: int,
    params: StrategyParams | None, goal_priors: GoalPriors | None,
    guide_map: GuideMap | None = None,
) -> Advisor:  # fmt: skip
    """The advisor of a session: the paper's rule and guide with compiled batches, or the
    core's advisor of the strategy (one call per event)."""
    if strategy == "paper":
        return StreamAdvisor(tables, kappa, window)
    if strategy == "guide":
        if guide_map is None:
            raise ValueError("guide advice needs the map's destinations (a guide map)")
        return StreamGuide(tables, guide_map, kappa, window, params=guide_params(params))
    return make_advisor(strategy, tables, kappa, window, params, goal_priors)


@dataclass(eq=False, slots=True)
class LiveSession:
    """One explorer watched by the advisor."""

    id: str
    token: str
    domain: DomainState
    agent_type: str | None
    table_key: str
    advisor: Advisor
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

    def _rings(self) -> tuple[Recent, Recent]:
        """The recent path and P(M1 | H) rings, made at the first event (until then the
        session's start alone is its history)."""
        if self.path is None or self.p_history is None:
            self.path = Recent(self.sizes[0], np.int32, self.position)
            # for plots only: 7 significant digits are plenty, at half the memory
            self.p_history = Recent(self.sizes[1], np.float32, self.p_normal)
        return self.path, self.p_history

    def _log(self) -> AdviceLog:
        """The advice log, made at the first piece of advice."""
        if self.advice_log is None:
            self.advice_log = AdviceLog(RECENT_ADVICE)
        return self.advice_log

    def record_one(self, d: Decision, tables: AdviceTables) -> None:
        """Remember one decision made with ``tables`` (recent path, posterior, advice)."""
        path, p_history = self._rings()
        self.position = d.state
        self.p_normal = d.p_normal
        path.push(d.state)
        p_history.push(d.p_normal)
        if d.advise:
            own = d.advice if self.advisor.own_advice else None
            self._log().add(d.step, d.state, tables, own)

    def record_batch(self, out: DecisionBatch, tables: AdviceTables) -> None:
        """:meth:`record_one` for a batch of decisions made with ``tables``."""
        n = len(out)
        if not n:
            return
        path, p_history = self._rings()
        self.position = int(out.state[-1])
        self.p_normal = float(out.p_normal[-1])
        path.extend(out.state)
        p_history.extend(out.p_normal)
        advised = np.flatnonzero(out.advise)[-RECENT_ADVICE:]
        if len(advised):
            own = out.advice[-len(advised) :] if self.advisor.own_advice else None
            self._log().extend(advised + out.first_step, out.state[advised], tables, own)


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
    position: tuple[int, int]
    p_normal: float
    advice_count: int
    total_cost: float
    benefit: float
    advice_per_100: float
    created_at: datetime
    idle_seconds: float
    path: list[tuple[int, int]]
    p_history: list[float]
    advice: list[tuple[int, tuple[int, int], Advice]]  # (step, cell, theta_s), oldest first
    # advisors with a goal posterior: (goal cell, P(goal | H), ruled out) per goal of the map
    goals: list[tuple[tuple[int, int], float, bool]] | None = None


class SessionRegistry:
    """Every live session by id, bounded in number and idle time."""

    def __init__(
        self, max_sessions: int, idle_seconds: float, recent_path: int = 100, recent_p: int = 200
    ):
        self.max_sessions = max_sessions
        self.idle_seconds = idle_seconds
        self.history_sizes = (recent_path, recent_p)
        self.lock = threading.Lock()
        self._sessions: dict[str, LiveSession] = {}

    def __len__(self) -> int:
        return len(self._sessions)

    def create(
        self,
        domain: DomainState,
        kappa: float,
        window: int,
        agent_type: str | None,
        start: int,
        strategy: str = "paper",
        params: StrategyParams | None = None,
    ) -> tuple[LiveSession, Decision]:
        """A new session and the decision for its start state (empty history). A goal_aware
        session needs ``domain.goal_priors`` built (:meth:`DomainCatalog.goal_priors`), a guide
        session ``domain.guide_map`` too (:meth:`DomainCatalog.guide_map`)."""
        view = domain.view
        key = view.resolve(agent_type)
        tables = view.tables[key]
        advisor = new_advisor(
            strategy, tables, kappa, window, params, domain.goal_priors, domain.guide_map
        )
        decision = advisor.start(start)
        now = time.monotonic()
        with self.lock:
            if len(self._sessions) >= self.max_sessions:
                self._expire(now)
            if len(self._sessions) >= self.max_sessions:
                raise TooManySessions(self.max_sessions)
            sid = secrets.token_hex(8)
            session = LiveSession(
                sid, secrets.token_urlsafe(24), domain, agent_type, key, advisor, start,
                decision.p_normal, datetime.now(UTC), now, self.history_sizes,
            )  # fmt: skip
            if decision.advise:
                own = decision.advice if advisor.own_advice else None
                session._log().add(0, start, tables, own)
            self._sessions[sid] = session
        return session, decision

    def get(self, session_id: str) -> LiveSession:
        session = self._sessions.get(session_id)
        if session is None or session.closed:
            raise SessionNotFound(session_id)
        return session

    def observe_one(
        self, session: LiveSession, state: int, action: int, next_state: int
    ) -> Decision:
        """Advance ``session`` by one checked (s, a, s')."""
        with self.lock:
            if session.closed:
                raise SessionNotFound(session.id)
            adv = session.advisor
            tables = adv.tables
            d = adv.observe(state, action, next_state)
            session.record_one(d, tables)
            session.last_seen = time.monotonic()
        return d

    def observe_batch(
        self, session: LiveSession, moves: tuple[IntArray, IntArray, IntArray]
    ) -> DecisionBatch:
        """Advance ``session`` by checked (s, a, s') arrays; its decisions as columns."""
        with self.lock:
            if session.closed:
                raise SessionNotFound(session.id)
            adv = session.advisor
            tables = adv.tables
            out = adv.observe_batch(*moves)
            session.record_batch(out, tables)
            session.last_seen = time.monotonic()
        return out

    def touch(self, session: LiveSession) -> None:
        session.last_seen = time.monotonic()

    def end(self, session_id: str) -> LiveSession:
        with self.lock:
            session = self._sessions.pop(session_id, None)
            if session is None or session.closed:
                raise SessionNotFound(session_id)
            session.closed = True
        return session

    def end_domain(self, name: str) -> int:
        """End every session of domain ``name`` (it was deleted or its map replaced)."""
        with self.lock:
            gone = [s for s in self._sessions.values() if s.domain.name == name]
            for s in gone:
                s.closed = True
                del self._sessions[s.id]
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
            s.closed = True
            del self._sessions[s.id]
        return len(idle)

    def sessions(self) -> list[LiveSession]:
        with self.lock:
            return list(self._sessions.values())

    def count_by_domain(self) -> dict[str, int]:
        with self.lock:
            return dict(Counter(s.domain.name for s in self._sessions.values()))

    def describe(self, session: LiveSession) -> SessionSnapshot:
        with self.lock:
            return _snap(session, time.monotonic())

    def snapshot(
        self, limit: int | None = None, domain: str | None = None
    ) -> list[SessionSnapshot]:
        """Copies of the most recently active sessions (all if ``limit`` is None)."""
        now = time.monotonic()
        with self.lock:
            live = [s for s in self._sessions.values() if domain is None or s.domain.name == domain]
            live.sort(key=lambda s: s.last_seen, reverse=True)
            return [_snap(s, now) for s in live[:limit]]


def _snap(s: LiveSession, now: float) -> SessionSnapshot:
    cells = s.domain.domain.cells
    adv = s.advisor
    beliefs = adv.goal_beliefs()

    def cell(state: int) -> tuple[int, int]:
        return int(cells[state, 0]), int(cells[state, 1])

    return SessionSnapshot(
        s.id, s.domain.name, s.agent_type, s.table_key, adv.kappa, adv.window, adv.strategy,
        adv.params(), adv.steps, cell(s.position), s.p_normal, adv.advice_count,
        adv.total_cost, adv.benefit, adv.advice_per_100, s.created_at, now - s.last_seen,
        [(r, c) for r, c in cells[s.path.tolist() if s.path else [s.position]].tolist()],
        s.p_history.tolist() if s.p_history else [s.p_normal],
        [
            (step, cell(st), _advice(tables, st))
            for step, st, tables in (s.advice_log.items() if s.advice_log else ())
        ],
        None if beliefs is None else [(cell(g), p, out) for g, p, out in beliefs],
    )  # fmt: skip


def _advice(source: AdviceTables | Advice, state: int) -> Advice:
    if not isinstance(source, AdviceTables):
        return source
    n, e, s, w = source.theta[state].tolist()
    return (n, e, s, w)
