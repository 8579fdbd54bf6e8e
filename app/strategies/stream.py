"""The strategies' advisors as a service runs them: the core's, with windows of pair keys and
batches compiled.

Every strategy's session keeps its window as pair keys into tables the domain shares
(:class:`KeyedWindow`), so a session's memory is bounded by its window, not by the size of the
map or its number of goals, and its state is plain arrays and numbers.

A websocket message may carry hundreds of one explorer's moves: the paper's rule, goal_aware
and guide run a batch in one compiled call (:func:`app.kernels.observe_stream`,
:func:`app.kernels.goal_stream`, :func:`app.kernels.guide_stream`): the core's window update and
decision, in the core's order, with libm's exp and log as :mod:`math` uses, and the core's exact
re-sums where it makes them. The advisor is left in exactly the state the sequential calls leave
it in (window, sums, position, counters), so single events and batches mix freely, and every
decision equals the core's bit for bit (``tests/service/live/test_stream.py``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from app import kernels
from app.advice.advisor import Advisor, Decision, DecisionBatch, resync_period
from app.advice.goals import GoalAwareAdvisor
from app.advice.guide import (
    MAX_TOUR,
    PURPOSE_WALK,
    GuideAdvisor,
    GuideParams,
    compliance_state,
    kernel_params,
    run_list,
    run_ring,
    tour_work,
)
from app.advice.models import AdviceTables
from app.advice.rules import RuleAdvisor
from app.arrays import BoolArray, FloatArray, IntArray

#: guide's batch (kernels.guide_stream) compiled for the domain's number of actions: four on
#: one floor, six in a building of several floors
STREAMS = {4: kernels.guide_stream_four, 6: kernels.guide_stream_six}
#: the most steps of the next destination's search (``guide.tour_work``) a guide batch's slice
#: may hold: about 2 ms compiled, at the 1.3-1.6 ns a step measured (benchmarks/bench_tour.py)
SLICE_STEPS = 1_500_000
_NO_RING = np.zeros((0, 0))  # no value kept: the window's values are those of the tables


#: what a window of pair keys holds, on each class using :class:`KeyedWindow`
KEYED_SLOTS = ("_kept", "_keys", "_keys_tables", "_n_kept", "_old")

#: a batch's columns as a kernel fills them: KL, P(M1 | H), advise, the advice count and the
#: benefit after each decision (and each decision's advice, for advisors whose advice is their
#: own: ``rows``)
Columns = tuple[FloatArray, FloatArray, BoolArray, IntArray, FloatArray]


def columns(n: int) -> Columns:
    """Empty columns for a batch of ``n`` decisions."""
    return (np.empty(n), np.empty(n), np.empty(n, dtype=np.bool_), np.empty(n, dtype=np.int64),
            np.empty(n))  # fmt: skip


def decided(
    adv: Advisor, next_states: IntArray, out: Columns, advice: FloatArray,
    before: tuple[int, float], advised_from: AdviceTables | None,
) -> DecisionBatch:  # fmt: skip
    """The batch a kernel decided into ``out`` (the advisor's counters moved on by it):
    ``advice`` the advising decisions' rows, ``before`` the advice count and benefit before."""
    n = len(next_states)
    adv.steps += n
    adv.decisions += n
    kl, p_normal, advise, count, benefit = out
    return DecisionBatch(
        adv.steps - n + 1, next_states, advise, kl, p_normal, count, benefit, advice, adv.kappa,
        before[0], before[1], advised_from,
    )  # fmt: skip


class KeyedWindow(Advisor):
    """The core's window as pair keys (a mixin for the service's advisors).

    The core's window keeps, per model, the log-probability each pair added (lists of Python
    floats, about 32 bytes an entry and model). This one keeps each pair's key ``s * A + a``
    (int32, 4 bytes a pair whatever the number of models): the value the core stored is
    ``tables.log_probs[m][key]``. Only when the tables change (a prior update) are the values
    of the pairs then in the window kept as numbers (``_old``, models x W float64, until the
    last of those pairs has left), since the new tables would give other values. So removing
    a pair and the exact re-sums use exactly the core's numbers, and a session costs about
    1.5 kB of window instead of 4.8 (W = 300, two models): 100,000 sessions hold one each
    (docs/PERFORMANCE.md, memory). :meth:`append` is the core's, step for step.

    The state is plain: the keys, a flag per pair, the kept values, the sums and counters.
    A class using it declares :data:`KEYED_SLOTS`.
    """

    if not TYPE_CHECKING:  # slots of its own would clash with the core classes' (each user
        __slots__ = ()  # declares KEYED_SLOTS); mypy reads the annotations below instead
    _keys: npt.NDArray[np.int32]
    _kept: npt.NDArray[np.uint8]
    _old: FloatArray | None
    _n_kept: int
    _keys_tables: AdviceTables

    def _reset_window(self) -> None:
        self._ring = []  # the core's lists are not used: the window lives in ``_keys``
        self._keys = np.full(self.window, -1, dtype=np.int32)  # -1: empty (the core's 0.0)
        self._kept = np.zeros(self.window, dtype=np.uint8)  # 1: value in _old
        self._old = None
        self._n_kept = 0
        self._keys_tables = self.tables  # the tables giving the values of the other pairs

    def footprint(self) -> int:
        """Bytes the window's arrays can take at most (keys, flags, kept values)."""
        return self.window * (4 + 1 + 8 * self.tables.n_models)

    def window_state(self) -> dict[str, bytes]:
        """The window as a saved session keeps it: its keys, and the value each pair added
        (models x W float64, the numbers the core's ring holds), whatever tables gave them."""
        return {
            "keys": self._keys.tobytes(),
            "values": np.ascontiguousarray(self._window).tobytes(),
        }

    def restore_window(self, state: Mapping[str, bytes]) -> None:
        """The window :meth:`window_state` wrote, on this advisor's tables: every pair's value
        kept as a number until it leaves (ValueError for a window of another length)."""
        w, models = self.window, self.tables.n_models
        keys = np.frombuffer(state["keys"], dtype=np.int32).copy()
        if keys.shape != (w,):
            raise ValueError("the window does not have the session's length")
        values = np.frombuffer(state["values"], dtype=np.float64).reshape(models, w).copy()
        filled = keys >= 0
        self._keys = keys
        self._kept = filled.astype(np.uint8)
        self._n_kept = int(np.count_nonzero(filled))
        self._old = values if self._n_kept else None
        self._keys_tables = self.tables

    def batch_slice(self) -> int:
        """Events of a batch to run at once, about 2 ms of work (the rest waits its turn on the
        event loop): the rules run one Python call an event, 3-6 us each (measured)."""
        return 500

    def _sync_tables(self) -> None:
        """After a change of tables, keep the values of the pairs added with the old ones.

        This runs at the first event after each prior update, so with one trajectory per
        ingest request nearly every event of every session pays it: one compiled call."""
        if self._keys_tables is self.tables:
            return
        if self.steps:  # the window holds pairs
            before = self._keys_tables.arrays[0]
            if self._old is None:  # then no value is kept yet: every pair moves
                self._old = np.zeros((before.shape[0], self.window))
            self._n_kept += kernels.keep_values(self._keys, self._kept, self._old, before)
        self._keys_tables = self.tables

    def _left(self, gone: int) -> None:
        self._n_kept -= gone
        if self._n_kept == 0:
            self._old = None  # every pair of the old tables has left the window

    @property
    def _window(self) -> FloatArray:
        """The window as the core holds it: (models, W) log-probabilities, 0.0 where empty."""
        self._sync_tables()
        keys = self._keys
        values = self.tables.arrays[0].take(keys, axis=1)  # an empty slot (-1): the last one
        if keys.min() < 0:  # the window not full yet: 0.0 where empty
            values[:, keys < 0] = 0.0
        if self._old is not None:
            kept = self._kept == 1
            values[:, kept] = self._old[:, kept]
        return values

    def append(self, state: int, action: int) -> None:
        """Add (s, a) to H exactly as :meth:`Advisor.append` does."""
        t = self.tables
        if not (0 <= state < t.n_states and 0 <= action < t.n_actions):
            self._check(state, action)
        if self._keys_tables is not t:
            self._sync_tables()
        k = state * t.n_actions + action
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


class StreamAdvisor(KeyedWindow):
    """The paper's :class:`Advisor` with its window as pair keys (:class:`KeyedWindow`) and
    batches in one compiled call (:func:`app.kernels.observe_stream`)."""

    __slots__ = KEYED_SLOTS

    def batch_slice(self) -> int:
        return 20_000  # compiled, 0.16 us an event: a whole batch at once

    def observe_batch(
        self, states: IntArray, actions: IntArray, next_states: IntArray
    ) -> DecisionBatch:
        """``[self.observe(s, a, s2) for ...]`` as columns, in one compiled call. Inputs must
        be valid (states in range, actions 0..3): the caller checks them first."""
        n = len(states)
        count_before, benefit_before = self.advice_count, self.benefit
        self._sync_tables()
        tables = self.tables
        loglik = np.array(self._loglik, dtype=np.float64)
        out = columns(n)
        old = self._old if self._old is not None else _NO_RING
        pos, self.advice_count, self.benefit, gone = kernels.observe_stream(
            (self._keys, self._kept, old), loglik, self._pos, self.steps,
            resync_period(self.window), tables.arrays, self.kappa, count_before,
            benefit_before, self.cap, (states, actions, next_states), out,
        )  # fmt: skip
        self._loglik, self._pos = loglik.tolist(), pos
        if gone:
            self._left(gone)
        advice = tables.theta[next_states[out[2]]] if n else tables.theta[:0]
        return decided(self, next_states, out, advice, (count_before, benefit_before), tables)


def keyed(rule: type[RuleAdvisor]) -> type[RuleAdvisor]:
    """The rule advisor ``rule`` (early, importance, mistake, random, always) with its window
    as pair keys: the core's decisions, one Python call per event."""
    made: type[RuleAdvisor] = type(
        f"Keyed{rule.__name__}", (KeyedWindow, rule), {"__slots__": KEYED_SLOTS}
    )
    return made


class StreamGoalAware(KeyedWindow, GoalAwareAdvisor):
    """A :class:`GoalAwareAdvisor` whose windows are pair keys into tables the domain shares.

    The core keeps, per session, W rows of G per-goal log-probabilities (and reads the goal
    counts as Python lists): memory grows with goals x window. Here both windows are the pair
    keys of :class:`KeyedWindow`; each goal's log theta^g of a pair is read from the
    domain's :meth:`GoalPriors.arrays`, built once per change of the counts and shared by
    every session. A session holds its keys, its sums (per model, per goal), the goals ruled
    out and, only after the goal counts changed while pairs were in its window, those pairs'
    per-goal values (G x W float64, until they have left). Every event runs compiled
    (:func:`app.kernels.goal_stream`), with the core's arithmetic in the core's order: the
    decisions equal the core's bit for bit (``tests/service/live/test_stream.py``).
    """

    __slots__ = (
        *KEYED_SLOTS, "_goal_arrays", "_goal_kept", "_goal_n_kept", "_goal_old", "_theta_w",
    )  # fmt: skip
    _goal_ll: FloatArray  # type: ignore[assignment]
    alive: npt.NDArray[np.bool_]  # type: ignore[assignment]

    def reset(self) -> None:
        super().reset()
        g = self.priors.n_goals
        self.alive = np.ones(g, dtype=np.bool_)
        self._goal_ll = np.zeros(g)
        self._theta_w = np.empty(self.priors.n_actions)

    def _reset_goal_window(self) -> None:
        self._goal_ring = []  # the core's rows are not used: the pair keys index the tables
        self._goal_kept = np.zeros(self.window if self.beta > 0.0 else 0, dtype=np.uint8)
        self._goal_old: FloatArray | None = None
        self._goal_n_kept = 0
        self._goal_arrays = self.priors.arrays()  # the goal tables of the non-kept pairs

    def footprint(self) -> int:
        """Bytes the session's arrays can take at most: the models' window, per goal a sum
        and a flag, and with beta > 0 a flag per pair and G x W kept values."""
        g = self.priors.n_goals
        per_goal = self.window * (1 + 8 * g) if self.beta > 0.0 else 0
        return super().footprint() + g * 9 + per_goal + 4 * 8

    def batch_slice(self) -> int:
        return max(64, 40_000 // (self.priors.n_goals + 1))  # compiled: 0.05 us a goal

    def window_state(self) -> dict[str, bytes]:
        """Both windows: with beta > 0 also each goal's value of each pair (G x W float64)."""
        out = super().window_state()
        if self.beta > 0.0:
            out["goal_values"] = np.ascontiguousarray(self._goal_window.T).tobytes()
        return out

    def restore_window(self, state: Mapping[str, bytes]) -> None:
        super().restore_window(state)
        if self.beta > 0.0:
            g, w = self.priors.n_goals, self.window
            goal = np.frombuffer(state["goal_values"], dtype=np.float64).reshape(g, w).copy()
            self._goal_kept = self._kept.copy()
            self._goal_n_kept = self._n_kept
            self._goal_old = goal if self._goal_n_kept else None
            self._goal_arrays = self.priors.arrays()

    def _sync_goals(self) -> None:
        """After new goal counts, keep each goal's values of the pairs added with the old."""
        arrays = self.priors.arrays()
        if self._goal_arrays is arrays:
            return
        if self.beta > 0.0 and self.steps:
            before = self._goal_arrays[4].T  # (G, S * 4)
            if self._goal_old is None:
                self._goal_old = np.zeros((before.shape[0], self.window))
            self._goal_n_kept += kernels.keep_values(
                self._keys, self._goal_kept, self._goal_old, before
            )
        self._goal_arrays = arrays

    def _goal_left(self, gone: int) -> None:
        self._goal_n_kept -= gone
        if self._goal_n_kept == 0:
            self._goal_old = None

    def _windows(self) -> tuple[tuple[Any, ...], tuple[Any, ...], FloatArray]:
        """Both windows synced to the current tables, as the kernels take them."""
        self._sync_tables()
        self._sync_goals()
        old = self._old if self._old is not None else _NO_RING
        goal_old = self._goal_old if self._goal_old is not None else _NO_RING
        loglik = np.array(self._loglik, dtype=np.float64)
        return (self._keys, self._kept, old), (self._goal_kept, goal_old), loglik

    @property
    def _goal_window(self) -> FloatArray:
        """The per-goal window as the core holds it: (W, G) values, 0.0 where empty."""
        self._sync_goals()
        log_theta = self._goal_arrays[4]
        values = np.zeros((self.window, self.priors.n_goals))
        filled = self._keys >= 0
        values[filled] = log_theta[self._keys[filled]]
        if self._goal_old is not None:
            kept = self._goal_kept == 1
            values[kept] = self._goal_old[:, kept].T
        return values

    def append(self, state: int, action: int) -> None:
        """Add (s, a) to both windows exactly as :meth:`GoalAwareAdvisor.append` does."""
        self._check(state, action)
        window, goal_window, loglik = self._windows()
        self._pos, gone, goal_gone = kernels.goal_append(
            window, goal_window, loglik, self._goal_ll, self.alive, self._pos, self.steps + 1,
            resync_period(self.window), self.beta, self.tables.arrays[0], self._goal_arrays,
            state, action,
        )  # fmt: skip
        self._loglik = loglik.tolist()
        self.steps += 1
        if gone:
            self._left(gone)
        if goal_gone:
            self._goal_left(goal_gone)

    def goal_posterior(self) -> list[float]:
        w = np.empty(self.priors.n_goals)
        kernels.goal_posterior(self._goal_ll, self.alive, self.beta, w)
        out: list[float] = w.tolist()
        return out

    def goal_beliefs(self) -> list[tuple[int, float, bool]]:
        w = self.goal_posterior()
        out = zip(self.priors.goals, w, self.alive.tolist(), strict=True)
        return [(g, p, not a) for g, p, a in out]

    def decide(self, state: int) -> Decision:
        self._check(state)
        self._sync_goals()
        loglik = np.array(self._loglik, dtype=np.float64)
        tw = self._theta_w
        kl, p0 = kernels.goal_decision(
            loglik, self.tables.arrays, self._goal_arrays, self._goal_ll, self.alive, self.beta,
            state, tw,
        )  # fmt: skip
        return self.record(state, kl >= self.kappa, tuple(tw.tolist()), kl, p0)

    def observe_batch(
        self, states: IntArray, actions: IntArray, next_states: IntArray
    ) -> DecisionBatch:
        n = len(states)
        count_before, benefit_before = self.advice_count, self.benefit
        window, goal_window, loglik = self._windows()
        out, rows = columns(n), np.empty((n, self.priors.n_actions))
        pos, self.advice_count, self.benefit, gone, goal_gone = kernels.goal_stream(
            window, goal_window, (loglik, self._goal_ll, self.alive), self._pos, self.steps,
            resync_period(self.window), self.beta, self.tables.arrays, self._goal_arrays,
            self.kappa, count_before, benefit_before, self.cap, (states, actions, next_states),
            (*out, rows),
        )  # fmt: skip
        self._loglik, self._pos = loglik.tolist(), pos
        if gone:
            self._left(gone)
        if goal_gone:
            self._goal_left(goal_gone)
        return decided(self, next_states, out, rows[out[2]], (count_before, benefit_before), None)

    def observe(self, state: int, action: int, next_state: int) -> Decision:
        self._check(state, action)
        self._check(next_state)
        s, a, s2 = (np.array([v], dtype=np.int64) for v in (state, action, next_state))
        return self.observe_batch(s, a, s2).decisions()[0]


class StreamGuide(GuideAdvisor):
    """A :class:`GuideAdvisor` whose batches run in one call of
    :func:`app.kernels.guide_stream`: the core's arithmetic in the core's order, leaving the
    advisor in the state the sequential calls leave it in, so single events (the core's own
    :meth:`observe`) and batches mix freely (``tests/service/live/test_stream.py``)."""

    __slots__ = ()

    def footprint(self) -> int:
        """Bytes the session's state can take at most: no window, but a sum per model (6 + 3G
        Python floats in a list, 32 bytes each), a flag per destination (a list) and the
        compliance evidence (:func:`compliance_state`'s floats) and a doubt per destination
        (a list of small ints), and the states decided for since the last piece of advice (a
        list of up to PURPOSE_WALK + 1 ints, 32 bytes each)."""
        g = self.guide.n_goals
        run = (PURPOSE_WALK + 1) * 32
        return (6 + 3 * g + len(compliance_state())) * 32 + g * 8 * 2 + 4 * 8 + run

    def batch_slice(self) -> int:
        # compiled: about 0.45 us a decision and 0.06 us more a destination (bench_guide.py),
        # so a slice is well under 2 ms; where the next destination is searched for (more
        # than MAX_TOUR destinations: up to MAX_SEARCHED_TOUR of them alive), any event may
        # set off a search (a client can walk onto each target and off it in turn, up to
        # twice a destination), so a slice holds at most SLICE_STEPS of its steps
        g = self.guide.n_goals
        usual = max(64, 5_000 // (g + 1))
        if g > MAX_TOUR:
            return max(1, min(usual, SLICE_STEPS // tour_work(g)))
        return usual

    def observe_batch(
        self, states: IntArray, actions: IntArray, next_states: IntArray
    ) -> DecisionBatch:
        n = len(states)
        count_before, benefit_before = self.advice_count, self.benefit
        g = self.guide
        ll = np.array(self._loglik, dtype=np.float64)
        alive = np.array(self.alive, dtype=np.bool_)
        doubt = np.array(self.doubt, dtype=np.int64)
        last_advice = np.array(self._last_advice, dtype=np.float64)
        comply = np.array(self._comply, dtype=np.float64)
        run = run_ring(self._run)
        out, rows = columns(n), np.empty((n, g.n_actions))
        params = kernel_params(self.window, GuideParams(self.p_lost, self.slack, self.spread))
        # the loop compiled with the constant 4 on one floor, 6 in a building
        stream = STREAMS[g.n_actions]
        got = stream(
            g.arrays, params, g.goal_states, ll, alive, doubt, self._target, self._last,
            self._heading, self._came, last_advice, comply, run, self.kappa, count_before,
            benefit_before, self.cap, (states, actions, next_states), (*out, rows),
        )  # fmt: skip
        self._comply = comply.tolist()
        self._run = run_list(run)
        self._target, self._last, self._heading, self._came, self.advice_count, self.benefit = got
        self._loglik = ll.tolist()
        self.alive = alive.tolist()
        self.doubt = doubt.tolist()
        self._last_advice = tuple(last_advice.tolist())
        return decided(self, next_states, out, rows[out[2]], (count_before, benefit_before), None)
