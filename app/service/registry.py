"""Live sessions: one :class:`StreamAdvisor` per explorer, with bounded recent history.

Sessions live in memory only (they are watchers, not data: an explorer that loses its session
opens a new one). The registry bounds them: at most ``max_sessions`` live at once, and a session
idle for ``idle_seconds`` is dropped. Each keeps its recent path, recent P(M1 | H) and recent
advice in bounded deques, so :meth:`SessionRegistry.snapshot` (for ``/overview`` and the viewer)
is cheap and safe to call from another thread: every change and every snapshot holds one lock.
"""

from __future__ import annotations

import secrets
import threading
import time
from array import array
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import numpy as np
import numpy.typing as npt

from app.advice.advisor import Advisor, Decision
from app.advice.goals import GoalAwareAdvisor, GoalPriors
from app.advice.models import AdviceTables
from app.advice.strategies import StrategyParams, make_advisor
from app.service.domains import DomainState
from app.service.stream_advisor import DecisionArrays, DecisionColumns, StreamAdvisor

IntArray = npt.NDArray[np.int64]
Advice = tuple[float, float, float, float]
RECENT_ADVICE = 50


class SessionNotFound(KeyError):
    """No live session with that id (never created, ended, or expired)."""


class TooManySessions(RuntimeError):
    """The registry holds ``max_sessions`` live sessions already."""


def _ring_spans(count: int, k: int, size: int) -> tuple[int, int, int]:
    """Where the last ``m = min(k, size)`` of ``k`` values appended to a ring of ``size``
    after ``count`` items go: ring[start:start + first] gets the first ``first`` of them and
    ring[:m - first] the rest (two slices: no index arrays). Returns (m, start, first)."""
    m = min(k, size)
    start = (count + k - m) % size
    return m, start, min(m, size - start)


class Recent:
    """The last ``size`` numbers pushed, oldest first, in one ring (8 bytes or less a number,
    where a deque of Python numbers costs about 32). The ring is an ``array.array``, whose
    items a single event sets at a third of numpy's cost; batches go through a numpy view."""

    __slots__ = ("_buf", "_count")

    def __init__(self, size: int, dtype: type[np.generic], first: float):
        kind = np.dtype(dtype)
        self._buf: array[Any] = array(kind.char, bytes(kind.itemsize * size))
        self._buf[0] = first
        self._count = 1

    def _view(self) -> npt.NDArray[Any]:
        return np.frombuffer(self._buf, dtype=self._buf.typecode)

    def push(self, value: float) -> None:
        self._buf[self._count % len(self._buf)] = value
        self._count += 1

    def extend(self, values: Sequence[float] | npt.NDArray[Any]) -> None:
        size, k = len(self._buf), len(values)
        if k == 1:  # one event per request: no index arrays
            self.push(values[0])
            return
        m, start, first = _ring_spans(self._count, k, size)
        view, tail = self._view(), values[k - m :]
        view[start : start + first] = tail[:first]
        view[: m - first] = tail[first:]
        self._count += k

    def tolist(self) -> list[Any]:
        size = len(self._buf)
        m = min(self._count, size)
        out: list[Any] = self._view()[np.arange(self._count - m, self._count) % size].tolist()
        return out


class AdviceLog:
    """The last ``size`` pieces of advice as (step, state, tables that advised), oldest first,
    in one numpy ring (the tables as an index into a short list: they change only when the
    prior does). About 1.3 kB for 50 entries where a deque of tuples takes about 7 kB:
    100,000 sessions hold one each (docs/PERFORMANCE.md, memory)."""

    __slots__ = ("_buf", "_count", "_own", "_tables")

    def __init__(self, size: int):
        # rows step, state, index into _tables; an array.array, as in Recent
        self._buf = array("q", bytes(8 * 3 * size))
        self._count = 0
        self._tables: list[AdviceTables] = []
        # the advice itself, for advisors whose advice is not theta_s (made at the first one)
        self._own: npt.NDArray[np.float64] | None = None

    def extend(
        self,
        steps: Sequence[int] | IntArray,
        states: Sequence[int] | IntArray,
        tables: AdviceTables,
        advice: Sequence[Advice | None] | npt.NDArray[np.float64] | None = None,
    ) -> None:
        """Log advice given at ``states``: theta_s of ``tables``, or ``advice`` when given."""
        k, size = len(steps), len(self._buf) // 3
        if not k:
            return
        which, buf = self._index(tables), self._rows()
        m, start, first = _ring_spans(self._count, k, size)
        spans = (
            (slice(start, start + first), slice(0, first)),
            (slice(0, m - first), slice(first, m)),
        )
        tail_steps, tail_states = steps[k - m :], states[k - m :]
        for ring, part in spans:
            buf[0, ring] = tail_steps[part]
            buf[1, ring] = tail_states[part]
            buf[2, ring] = which
        if advice is not None and self._own is None:
            self._own = np.full((size, 4), np.nan)
        if self._own is not None:  # NaN rows: theta_s of the tables
            if advice is None or len(advice) == 0:
                rows: Any = np.full((m, 4), np.nan)
            else:
                nan = (np.nan,) * 4
                rows = np.array([nan if a is None else a for a in advice[k - m :]], dtype=float)
            for ring, part in spans:
                self._own[ring] = rows[part]
        self._count += k

    def add(self, step: int, state: int, tables: AdviceTables, advice: Advice | None) -> None:
        """:meth:`extend` for one piece of advice (``advice`` None: theta_s of ``tables``;
        pass it only for advisors whose advice is not theta_s), without index arrays."""
        which, buf, size = self._index(tables), self._buf, len(self._buf) // 3
        at = self._count % size
        buf[at], buf[size + at], buf[2 * size + at] = step, state, which
        if advice is not None and self._own is None:
            self._own = np.full((size, 4), np.nan)
        if self._own is not None:  # NaN row: theta_s of the tables
            self._own[at] = np.nan if advice is None else advice
        self._count += 1

    def _index(self, tables: AdviceTables) -> int:
        """The index of ``tables`` in the list: the last one, appended (after a compaction)
        when it is not already."""
        if not self._tables or self._tables[-1] is not tables:
            self._compact()
            self._tables.append(tables)
        return len(self._tables) - 1

    def _rows(self) -> npt.NDArray[np.int64]:
        """The ring as a (3, size) numpy view."""
        return np.frombuffer(self._buf, dtype=np.int64).reshape(3, -1)

    def _compact(self) -> None:
        """Forget tables no entry refers to any more (so the list stays short).

        Entries are written oldest first and each table of the list got entries when it was
        appended, so the tables in use are those from the oldest entry's to the last: the
        unused ones are a prefix. (This runs at nearly every piece of advice while the prior
        changes often, e.g. one trajectory per ingest request: O(1), not a set.)"""
        if len(self._tables) < 4:
            return
        size = len(self._buf) // 3
        oldest = (self._count - min(self._count, size)) % size
        first = self._buf[2 * size + oldest]
        if first:
            self._rows()[2] -= first  # slots not yet written are never read
            del self._tables[:first]

    def _order(self) -> npt.NDArray[np.int64]:
        size = len(self._buf) // 3
        m = min(self._count, size)
        return np.arange(self._count - m, self._count) % size

    def items(self) -> list[tuple[int, int, AdviceTables | Advice]]:
        order = self._order()
        steps, states, which = self._rows()[:, order].tolist()
        if self._own is None:
            return [(a, s, self._tables[t]) for a, s, t in zip(steps, states, which, strict=True)]
        own = self._own[order].tolist()
        return [
            (a, s, self._tables[t] if o[0] != o[0] else (o[0], o[1], o[2], o[3]))  # NaN: theta
            for a, s, t, o in zip(steps, states, which, own, strict=True)
        ]


@dataclass(eq=False, slots=True)
class LiveSession:
    """One explorer watched by the advisor."""

    id: str
    token: str
    domain: DomainState
    agent_type: str | None
    table_key: str
    advisor: Advisor  # a StreamAdvisor for the paper's rule (batches in one compiled loop)
    strategy: str
    position: int
    p_normal: float
    created_at: datetime
    last_seen: float  # time.monotonic()
    sizes: tuple[int, int]  # how many recent cells and p_normal values to keep
    # recent cells and P(M1 | H), created at the first batch (until then: the start alone)
    path: Recent | None = None
    p_history: Recent | None = None
    # (step, state, the tables that advised): theta_s is read at snapshot time, so an entry
    # costs three numbers (goal_aware sessions also keep the advice itself, which is not
    # theta_s of the tables); created at the first advice
    advice_log: AdviceLog | None = None
    closed: bool = False

    def record(self, cols: DecisionColumns) -> None:
        """Remember a batch of decisions (recent path, posterior, advice given)."""
        if not cols.step:
            return
        path, p_history = self._rings()
        self.position = cols.state[-1]
        self.p_normal = cols.p_normal[-1]
        path.extend(cols.state)
        p_history.extend(cols.p_normal)
        if cols.advice_count[-1] != cols.advice_count[0] or cols.advise[0]:
            self.log_advice(cols.step, cols.state, cols.advise, cols.advice)

    def _rings(self) -> tuple[Recent, Recent]:
        """The recent path and P(M1 | H) rings, made at the first batch (until then the
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

    def record_arrays(self, out: DecisionArrays) -> None:
        """:meth:`record` for a batch as arrays (the binary answer's path)."""
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
            own = None if out.advice is None else out.advice[-len(advised) :]
            self._log().extend(
                advised + out.first_step, out.state[advised], self.advisor.tables, own
            )

    def record_one(self, d: Decision, own_advice: bool) -> None:
        """:meth:`record` for one decision (``own_advice``: log ``d.advice`` itself, for
        advisors whose advice is not theta_s), without building columns."""
        path, p_history = self._rings()
        self.position = d.state
        self.p_normal = d.p_normal
        path.push(d.state)
        p_history.push(d.p_normal)
        if d.advise:
            own = d.advice if own_advice else None
            self._log().add(d.step, d.state, self.advisor.tables, own)

    def log_advice(
        self,
        steps: list[int],
        states: list[int],
        advise: list[bool],
        advice: list[Advice | None] | None = None,
    ) -> None:
        advised = [i for i, a in enumerate(advise) if a][-RECENT_ADVICE:]
        self._log().extend(
            [steps[i] for i in advised],
            [states[i] for i in advised],
            self.advisor.tables,
            None if advice is None else [advice[i] for i in advised],
        )

    def observe(
        self, states: IntArray, actions: IntArray, next_states: IntArray
    ) -> DecisionColumns:
        """The advisor's decisions for checked (s, a, s') arrays: the paper's rule in one
        compiled loop, the other strategies one core call per event."""
        adv = self.advisor
        if isinstance(adv, StreamAdvisor):
            return adv.observe_many(states, actions, next_states)
        moves = zip(states.tolist(), actions.tolist(), next_states.tolist(), strict=True)
        decisions = [adv.observe(s, a, s2) for s, a, s2 in moves]
        return DecisionColumns.of(decisions, with_advice=isinstance(adv, GoalAwareAdvisor))


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
    # goal_aware: (goal cell, P(goal | H), ruled out) for each goal of the map
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
        session needs ``domain.goal_priors`` built (:meth:`DomainCatalog.goal_priors`)."""
        view = domain.view
        key = view.resolve(agent_type)
        advisor: Advisor
        if strategy == "paper":
            advisor = StreamAdvisor(view.tables[key], kappa=kappa, window=window)
        else:
            advisor = make_advisor(
                strategy, view.tables[key], kappa, window, params, domain.goal_priors
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
                sid, secrets.token_urlsafe(24), domain, agent_type, key, advisor, strategy,
                start, decision.p_normal, datetime.now(UTC), now,
                self.history_sizes,
            )  # fmt: skip
            if decision.advise:
                own = [decision.advice] if isinstance(advisor, GoalAwareAdvisor) else None
                session.log_advice([0], [start], [True], own)
            self._sessions[sid] = session
        return session, decision

    def get(self, session_id: str) -> LiveSession:
        session = self._sessions.get(session_id)
        if session is None or session.closed:
            raise SessionNotFound(session_id)
        return session

    def observe(
        self, session: LiveSession, moves: tuple[IntArray, IntArray, IntArray]
    ) -> DecisionColumns:
        """Advance ``session`` by checked (s, a, s') arrays; its decisions in columns."""
        with self.lock:
            if session.closed:
                raise SessionNotFound(session.id)
            cols = session.observe(*moves)
            session.record(cols)
            session.last_seen = time.monotonic()
        return cols

    def observe_arrays(
        self, session: LiveSession, moves: tuple[IntArray, IntArray, IntArray]
    ) -> DecisionArrays:
        """:meth:`observe` with the decisions as arrays (for the binary answer)."""
        adv = session.advisor
        with self.lock:
            if session.closed:
                raise SessionNotFound(session.id)
            if isinstance(adv, StreamAdvisor):
                out = adv.observe_arrays(*moves)
            else:
                tables, count, benefit = adv.tables, adv.advice_count, adv.benefit
                triples = zip(*(m.tolist() for m in moves), strict=True)
                decisions = [adv.observe(s, a, s2) for s, a, s2 in triples]
                own = isinstance(adv, GoalAwareAdvisor)
                out = DecisionArrays.of(adv, decisions, count, benefit, tables, own)
            session.record_arrays(out)
            session.last_seen = time.monotonic()
        return out

    def observe_one(
        self, session: LiveSession, state: int, action: int, next_state: int
    ) -> tuple[Decision, AdviceTables]:
        """Advance ``session`` by one checked (s, a, s'): :meth:`observe` for one event,
        without arrays or columns. Returns the decision and the tables that made it."""
        adv = session.advisor
        with self.lock:
            if session.closed:
                raise SessionNotFound(session.id)
            tables = adv.tables
            d = adv.observe(state, action, next_state)
            session.record_one(d, isinstance(adv, GoalAwareAdvisor))
            session.last_seen = time.monotonic()
        return d, tables

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
        """Point the sessions of ``domain`` at its current prior view (new tables after new
        trajectories); each advisor's window stays exact (the core keeps what it added)."""
        view = domain.view
        with self.lock:
            for s in self._sessions.values():
                if s.domain.name == domain.name:
                    s.domain = domain
                    s.table_key = view.resolve(s.agent_type)
                    s.advisor.tables = view.tables[s.table_key]
                    if isinstance(s.advisor, GoalAwareAdvisor) and domain.goal_priors is not None:
                        s.advisor.use_priors(domain.goal_priors)

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
    return SessionSnapshot(
        s.id, s.domain.name, s.agent_type, s.table_key, adv.kappa, adv.window, s.strategy,
        adv.steps,
        (int(cells[s.position, 0]), int(cells[s.position, 1])), s.p_normal,
        adv.advice_count, adv.total_cost, adv.benefit, adv.advice_per_100, s.created_at,
        now - s.last_seen,
        [(r, c) for r, c in cells[s.path.tolist() if s.path else [s.position]].tolist()],
        s.p_history.tolist() if s.p_history else [s.p_normal],
        [
            (step, (int(cells[st, 0]), int(cells[st, 1])), _advice(tables, st))
            for step, st, tables in (s.advice_log.items() if s.advice_log else ())
        ],
        _goals(adv, cells) if isinstance(adv, GoalAwareAdvisor) else None,
    )  # fmt: skip


def _advice(source: AdviceTables | Advice, state: int) -> Advice:
    if not isinstance(source, AdviceTables):
        return source
    n, e, s, w = source.theta[state].tolist()
    return (n, e, s, w)


def _goals(adv: GoalAwareAdvisor, cells: IntArray) -> list[tuple[tuple[int, int], float, bool]]:
    goals: GoalPriors = adv.priors
    return [
        ((int(cells[g, 0]), int(cells[g, 1])), p, not alive)
        for g, p, alive in zip(goals.goals, adv.goal_posterior(), adv.alive, strict=True)
    ]
