"""One explorer's batch of events in one call: the core :class:`Advisor`, compiled over time.

A websocket message may carry hundreds of one explorer's moves. Calling
:meth:`Advisor.observe` per move costs microseconds each in Python;
:meth:`StreamAdvisor.observe_many` runs the same steps in one numba loop over the batch:

* the window update ``loglik[m] += lp - ring[m, pos]`` and the decision (eqs. 4-6) are the
  core's arithmetic in the core's order; exp and log are libm's, as :mod:`math` uses;
* where the core re-sums the window exactly (``math.fsum`` when the ring wraps at a multiple
  of :func:`resync_period`), the exact sums are computed beforehand with ``math.fsum`` itself
  and handed to the loop.

The advisor is left in exactly the state the sequential calls leave it in (ring, sums,
position, counters), so single events (the core's own :meth:`observe`) and batches mix freely,
and every decision equals the core's bit for bit (``tests/service/test_stream_advisor.py``).
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
from numba import njit

from app.advice.advisor import Advisor, Decision, resync_period
from app.advice.models import AdviceTables
from app.domain.grid import N_ACTIONS

IntArray = npt.NDArray[np.int64]
KeyArray = npt.NDArray[np.int32]
FlagArray = npt.NDArray[np.uint8]
FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

#: Below this many events a plain loop over :meth:`Advisor.observe` is cheaper.
SMALL_BATCH = 8


@dataclass(frozen=True, slots=True)
class DecisionColumns:
    """Decisions for a batch, one list per field of :class:`Decision`. The advice is
    ``tables.theta[state]`` where ``advise`` is true, unless ``advice`` holds it (strategies
    whose advice is not theta_s, as goal_aware's). A batch from the compiled loop also keeps
    (state, advise, advice_count) as arrays, for the compiled encoder."""

    step: list[int]
    state: list[int]
    advise: list[bool]
    kl: list[float]
    p_normal: list[float]
    advice_count: list[int]
    total_cost: list[float]
    benefit: list[float]
    arrays: tuple[IntArray, BoolArray, IntArray] | None = field(
        default=None, compare=False, repr=False
    )
    advice: list[tuple[float, float, float, float] | None] | None = None

    @classmethod
    def of(cls, decisions: list[Decision], with_advice: bool = False) -> DecisionColumns:
        if not decisions:
            return cls([], [], [], [], [], [], [], [], advice=[] if with_advice else None)
        c = list(zip(*decisions, strict=True))
        return cls(
            list(c[0]), list(c[1]), list(c[2]), list(c[4]), list(c[5]), list(c[6]),
            list(c[7]), list(c[8]), advice=list(c[3]) if with_advice else None,
        )  # fmt: skip

    def __len__(self) -> int:
        return len(self.step)


@dataclass(frozen=True, slots=True)
class DecisionArrays:
    """Decisions for a batch as arrays, for the binary answer (:mod:`app.protocol`):
    decision i is step ``first_step + i``; ``count_before`` and ``benefit_before`` are the
    advisor's figures before the batch. ``advice`` holds the rows of the advising decisions
    when they are not theta_s of ``tables`` (goal_aware), else None."""

    first_step: int
    state: IntArray
    advise: BoolArray
    kl: FloatArray
    p_normal: FloatArray
    advice_count: IntArray
    benefit: FloatArray
    kappa: float
    count_before: int
    benefit_before: float
    tables: AdviceTables
    advice: FloatArray | None = None

    @classmethod
    def of(
        cls, advisor: Advisor, decisions: list[Decision], count_before: int,
        benefit_before: float, tables: AdviceTables, with_advice: bool = False,
    ) -> DecisionArrays:  # fmt: skip
        """From one core call per event (the strategies other than the paper's rule)."""
        n = len(decisions)
        c = list(zip(*decisions, strict=True)) if n else [()] * 9
        advice = None
        if with_advice:
            rows = [a for a, on in zip(c[3], c[2], strict=True) if on]
            advice = np.array(rows, dtype=np.float64).reshape(len(rows), 4)
        return cls(
            advisor.steps - n + 1, np.array(c[1], dtype=np.int64), np.array(c[2], dtype=bool),
            np.array(c[4], dtype=np.float64), np.array(c[5], dtype=np.float64),
            np.array(c[6], dtype=np.int64), np.array(c[8], dtype=np.float64), advisor.kappa,
            count_before, benefit_before, tables, advice,
        )  # fmt: skip

    def __len__(self) -> int:
        return len(self.state)


@dataclass(frozen=True, slots=True)
class _Flat:
    """The arrays the compiled loop reads, flattened as ``advisor_decide`` expects."""

    log_probs: FloatArray  # (M, S*4)
    log_weights: FloatArray  # (M,)
    probs: FloatArray  # (M, S*4)
    theta: FloatArray  # (S*4,)
    neg_entropy: FloatArray  # (S,)


_FLAT: weakref.WeakKeyDictionary[AdviceTables, _Flat] = weakref.WeakKeyDictionary()


def _flat(tables: AdviceTables) -> _Flat:
    flat = _FLAT.get(tables)
    if flat is None:
        m = tables.n_models
        flat = _Flat(
            np.ascontiguousarray(tables.log_probs.reshape(m, -1)),
            np.ascontiguousarray(tables.log_weights),
            np.ascontiguousarray(tables.probs.reshape(m, -1)),
            np.ascontiguousarray(tables.theta.reshape(-1)),
            np.ascontiguousarray(tables.neg_entropy),
        )
        _FLAT[tables] = flat
    return flat


@njit(cache=True, inline="always")  # as a call it cost the loop twice its time (measured)
def _decide(
    loglik: FloatArray,
    flat: tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray],
    s: int,
    z: FloatArray,
) -> tuple[float, float]:  # pragma: no cover - compiled
    """(KL[theta_s || P(A | s, H)], P(M1 | H)): Advisor.decide's arithmetic, step for step
    (``z`` is scratch space, one entry per model)."""
    _, log_weights, probs, theta, neg_entropy = flat
    n_models = loglik.shape[0]
    mx = loglik[0] + log_weights[0]
    for m in range(n_models):
        z[m] = loglik[m] + log_weights[m]
        if z[m] > mx:
            mx = z[m]
    tot = 0.0
    for m in range(n_models):
        d = z[m] - mx
        z[m] = 1.0 if d == 0.0 else math.exp(d)  # exp(0) is exactly 1 (C99 F.9.3.1): one exp less
        tot += z[m]
    b = s * 4
    p0 = z[0] / tot
    m0, m1 = p0 * probs[0, b], p0 * probs[0, b + 1]
    m2, m3 = p0 * probs[0, b + 2], p0 * probs[0, b + 3]
    for m in range(1, n_models):
        pm = z[m] / tot
        m0 += pm * probs[m, b]
        m1 += pm * probs[m, b + 1]
        m2 += pm * probs[m, b + 2]
        m3 += pm * probs[m, b + 3]
    cross = theta[b] * math.log(m0) + theta[b + 1] * math.log(m1)
    cross += theta[b + 2] * math.log(m2)
    cross += theta[b + 3] * math.log(m3)
    kl = neg_entropy[s] - cross
    if kl < 0.0:
        kl = 0.0
    return kl, p0


@njit(cache=True)
def _observe_stream(
    window: tuple[KeyArray, FlagArray, FloatArray],
    loglik: FloatArray,
    pos: int,
    flat: tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray],
    kappa: float,
    count: int,
    benefit: float,
    moves: tuple[IntArray, IntArray, IntArray],
    resync: tuple[IntArray, FloatArray],
    out: tuple[FloatArray, FloatArray, BoolArray, IntArray, FloatArray],
) -> tuple[int, int, float, int]:  # pragma: no cover - compiled
    """Advisor.observe for each (s, a, s'), accounting as Advisor.decide. The window is (pair
    keys, 1 where a pair's value was kept in ``old`` because the tables changed since it was
    added, those values): a leaving pair is subtracted with the value the core stored. At
    event ``resync[0][r]`` the sums become ``resync[1][r]`` (the core's exact re-sum). Fills
    ``out`` (kl, p_normal, advise, count, benefit); returns (ring position, advice count,
    benefit, kept values that left the window)."""
    keys, kept, old = window
    log_probs = flat[0]
    states, actions, next_states = moves
    resync_at, resync_sums = resync
    kl_out, p_out, advise_out, count_out, benefit_out = out
    size = keys.shape[0]
    n_models = loglik.shape[0]
    z = np.empty(n_models)
    r = 0
    gone = 0
    for i in range(states.shape[0]):
        k = states[i] * 4 + actions[i]
        leaving = keys[pos]
        if leaving < 0:  # the core's ring holds 0.0 until the window fills
            for m in range(n_models):
                loglik[m] += log_probs[m, k] - 0.0
        elif kept[pos]:
            for m in range(n_models):
                loglik[m] += log_probs[m, k] - old[m, pos]
            kept[pos] = 0
            gone += 1
        else:
            for m in range(n_models):
                loglik[m] += log_probs[m, k] - log_probs[m, leaving]
        keys[pos] = k
        pos += 1
        if pos == size:
            pos = 0
            if r < resync_at.shape[0] and resync_at[r] == i:
                loglik[:] = resync_sums[r]
                r += 1
        kl, p0 = _decide(loglik, flat, next_states[i], z)
        advise = kl >= kappa
        if advise:
            count += 1
            benefit += kl
        kl_out[i] = kl
        p_out[i] = p0
        advise_out[i] = advise
        count_out[i] = count
        benefit_out[i] = benefit
    return pos, count, benefit, gone


@njit(cache=True)
def _keep_values(
    keys: KeyArray, kept: FlagArray, old: FloatArray, log_probs: FloatArray
) -> int:  # pragma: no cover - compiled
    """For each pair of the window whose value is not kept yet, keep its value in each
    model's ``log_probs`` (the tables it was added with) in ``old``; returns how many."""
    n = 0
    for p in range(keys.shape[0]):
        k = keys[p]
        if k >= 0 and kept[p] == 0:
            for m in range(log_probs.shape[0]):
                old[m, p] = log_probs[m, k]
            kept[p] = 1
            n += 1
    return n


class StreamAdvisor(Advisor):
    """An :class:`Advisor` with :meth:`observe_many` for a batch of one explorer's moves.

    The core's window keeps, per model, the log-probability each pair added (lists of Python
    floats, about 32 bytes an entry and model). This one keeps each pair's key ``s * 4 + a``
    (int32, 4 bytes a pair whatever the number of models): the value the core stored is
    ``tables.log_probs[m][key]``. Only when the tables change (a prior update) are the values
    of the pairs then in the window kept as numbers (``_old``, models x W float64, until the
    last of those pairs has left), since the new tables would give other values. So removing
    a pair and the exact re-sums use exactly the core's numbers, and a session costs about
    1.5 kB of window instead of 4.8 (W = 300, two models): 100,000 sessions hold one each
    (docs/PERFORMANCE.md, memory). :meth:`append` is the core's, step for step.
    """

    __slots__ = ("_kept", "_keys", "_keys_tables", "_n_kept", "_old")

    def reset(self) -> None:
        super().reset()
        self._ring = []  # the core's lists are not used: the window lives in ``_keys``
        self._keys = np.full(self.window, -1, dtype=np.int32)  # -1: empty (the core's 0.0)
        self._kept = np.zeros(self.window, dtype=np.uint8)  # 1: value in _old
        self._old: FloatArray | None = None
        self._n_kept = 0
        self._keys_tables = self.tables  # the tables giving the values of the other pairs

    def _sync_tables(self) -> None:
        """After a change of tables, keep the values of the pairs added with the old ones.

        This runs at the first event after each prior update, so with one trajectory per
        ingest request nearly every event of every session pays it: one compiled call."""
        if self._keys_tables is self.tables:
            return
        if self.steps:  # the window holds pairs
            before = _flat(self._keys_tables).log_probs
            if self._old is None:  # then no value is kept yet: every pair moves
                self._old = np.zeros((before.shape[0], self.window))
            self._n_kept += _keep_values(self._keys, self._kept, self._old, before)
        self._keys_tables = self.tables

    def _left(self, gone: int) -> None:
        self._n_kept -= gone
        if self._n_kept == 0:
            self._old = None  # every pair of the old tables has left the window

    @property
    def _window(self) -> FloatArray:
        """The window as the core holds it: (models, W) log-probabilities, 0.0 where empty."""
        self._sync_tables()
        log_probs = _flat(self.tables).log_probs
        filled = self._keys >= 0
        values = np.zeros((log_probs.shape[0], self.window))
        values[:, filled] = log_probs[:, self._keys[filled]]
        if self._old is not None:
            kept = self._kept == 1
            values[:, kept] = self._old[:, kept]
        return values

    def append(self, state: int, action: int) -> None:
        """Add (s, a) to H exactly as :meth:`Advisor.append` does."""
        t = self.tables
        if not (0 <= state < t.n_states and 0 <= action < N_ACTIONS):
            self._check(state, action)
        if self._keys_tables is not t:
            self._sync_tables()
        k = state * N_ACTIONS + action
        pos, loglik = self._pos, self._loglik
        leaving = int(self._keys[pos])
        tables = t.log_probs_flat
        if leaving < 0:
            for m, table in enumerate(tables):
                loglik[m] += table[k] - 0.0
        elif self._kept[pos] and self._old is not None:
            old = self._old[:, pos].tolist()
            for m, table in enumerate(tables):
                loglik[m] += table[k] - old[m]
            self._kept[pos] = 0
            self._left(1)
        else:
            for m, table in enumerate(tables):
                loglik[m] += table[k] - table[leaving]
        self._keys[pos] = k
        pos += 1
        self.steps += 1
        if pos == self.window:
            pos = 0
            if self.steps % resync_period(self.window) == 0:
                ring = self._window
                for m in range(len(loglik)):
                    loglik[m] = math.fsum(ring[m].tolist())
        self._pos = pos

    def _resyncs(
        self, ring: FloatArray, log_probs: FloatArray, keys: IntArray
    ) -> tuple[IntArray, FloatArray]:
        """Events of this batch after which the core re-sums the window exactly, and the
        ``math.fsum`` of the window there (for each model); ``ring`` is :attr:`_window`."""
        w, n = self.window, len(keys)
        period = resync_period(w)
        first = (period - self.steps % period) % period or period  # pairs until the next one
        at = np.arange(first - 1, n, period, dtype=np.int64)
        sums = np.empty((len(at), log_probs.shape[0]))
        if len(at):
            pos = self._pos
            for m in range(log_probs.shape[0]):
                # the window before the batch, oldest first, then the batch's pairs
                tape = np.concatenate((ring[m, pos:], ring[m, :pos], log_probs[m].take(keys)))
                for r, i in enumerate(at.tolist()):
                    sums[r, m] = math.fsum(tape[i + 1 : i + 1 + w].tolist())
        return at, sums

    def observe_many(
        self, states: IntArray, actions: IntArray, next_states: IntArray
    ) -> DecisionColumns:
        """Same as ``[self.observe(s, a, s2) for ...]``, in columns. Inputs must be valid
        (states in range, actions 0..3): the caller checks them first."""
        n = len(states)
        if n == 1:  # one event per request
            d = self.observe(int(states[0]), int(actions[0]), int(next_states[0]))
            return DecisionColumns(
                [d.step], [d.state], [d.advise], [d.kl], [d.p_normal], [d.advice_count],
                [d.total_cost], [d.benefit],
            )  # fmt: skip
        if n < SMALL_BATCH:
            moves = zip(states.tolist(), actions.tolist(), next_states.tolist(), strict=True)
            return DecisionColumns.of([self.observe(s, a, s2) for s, a, s2 in moves])
        out = self.observe_arrays(states, actions, next_states)
        return DecisionColumns(
            list(range(self.steps - n + 1, self.steps + 1)),
            next_states.tolist(),
            out.advise.tolist(),
            out.kl.tolist(),
            out.p_normal.tolist(),
            out.advice_count.tolist(),
            (self.kappa * out.advice_count).tolist(),
            out.benefit.tolist(),
            (next_states, out.advise, out.advice_count),
        )

    def observe_arrays(
        self, states: IntArray, actions: IntArray, next_states: IntArray
    ) -> DecisionArrays:
        """:meth:`observe_many` as arrays, any size, in the compiled loop (for the binary
        answer, and for :meth:`observe_many`'s larger batches): no Python lists."""
        n = len(states)
        tables, count_before, benefit_before = self.tables, self.advice_count, self.benefit
        f = _flat(tables)
        self._sync_tables()
        keys = states * 4 + actions
        period = resync_period(self.window)
        needs_resync = (self.steps % period) + n >= period
        resync = self._resyncs(self._window, f.log_probs, keys) if needs_resync else _NO_RESYNC
        loglik = np.array(self._loglik, dtype=np.float64)
        kl, p_normal, benefit = np.empty(n), np.empty(n), np.empty(n)
        advise, count = np.empty(n, dtype=np.bool_), np.empty(n, dtype=np.int64)
        old = self._old if self._old is not None else _NO_RING
        pos, self.advice_count, self.benefit, gone = _observe_stream(
            (self._keys, self._kept, old), loglik, self._pos,
            (f.log_probs, f.log_weights, f.probs, f.theta, f.neg_entropy),
            self.kappa, self.advice_count, self.benefit,
            (states, actions, next_states), resync,
            (kl, p_normal, advise, count, benefit),
        )  # fmt: skip
        self._loglik, self._pos = loglik.tolist(), pos
        if gone:
            self._left(gone)
        self.steps += n
        self.decisions += n
        return DecisionArrays(
            self.steps - n + 1, next_states, advise, kl, p_normal, count, benefit, self.kappa,
            count_before, benefit_before, tables,
        )  # fmt: skip


_NO_RING = np.zeros((0, 0))
_NO_RESYNC = (np.zeros(0, dtype=np.int64), np.zeros((0, 0)))  # no exact re-sum in this batch


def warm_up() -> None:
    """Load (or compile, the first time) the numba loops, so no request waits for them."""
    tables = AdviceTables.paper(np.full((2, 4), 0.25))
    moves = np.zeros(SMALL_BATCH, dtype=np.int64)
    advisor = StreamAdvisor(tables, window=4)
    advisor.observe_many(moves, moves, moves)
    advisor.tables = AdviceTables.paper(np.full((2, 4), 0.25))  # a prior update
    advisor.observe_many(moves, moves, moves)
