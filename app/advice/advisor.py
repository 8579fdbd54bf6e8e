"""The advisor's decision for one explorer (Section IV): window, posterior, KL-vs-kappa, cost.

One step (docs/METHOD.md): the explorer at ``s`` takes ``a`` and reaches ``s'``; the advisor appends
``(s, a)`` to its window H, then decides for ``s'``::

    log P(H | M)  = sum over H of log P(a_i | s_i, M)            kept in O(1) per event
    P(M | H)      = P(H | M) P(M) / sum_M' P(H | M') P(M')       eq. (5)
    P(A | s', H)  = sum_M P(A | s', M) P(M | H)                  eq. (4)
    advise        iff KL[theta_s' || P(A | s', H)] >= kappa      eq. (6), nats

The window keeps the log-probabilities it added, so subtracting the pair that leaves it is
exact even if the tables change meanwhile; when the ring wraps (at most once per
:data:`RESYNC_PAIRS` pairs) the sums are recomputed exactly (``math.fsum``), so floating-point
drift never accumulates.
This single-explorer form is plain Python on flat lists (a few microseconds per decision);
the compiled form (:func:`app.kernels.decide`) is the same arithmetic in the same order.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import ClassVar, NamedTuple

import numpy as np
import numpy.typing as npt

from app.advice.models import AdviceTables
from app.advice.priors import GoalPriors
from app.arrays import BoolArray, FloatArray, IntArray
from app.domain.grid import N_ACTIONS

DEFAULT_KAPPA = 0.5
DEFAULT_WINDOW = 300
#: the strategy a session follows unless it asks for another: the paper's rule, this class
DEFAULT_STRATEGY = "paper"
#: an advisor's cap on its advice count when nothing caps it (:attr:`Advisor.cap`)
NO_CAP = 2**62
#: The window sums are recomputed exactly when the ring wraps, at most once per this many pairs
#: (a short window would otherwise pay an O(W) re-sum every W steps for nothing).
RESYNC_PAIRS = 1024


def resync_period(window: int) -> int:
    """Pairs between exact re-sums: the first multiple of ``window`` >= RESYNC_PAIRS."""
    return window * -(-RESYNC_PAIRS // window)


class Decision(NamedTuple):
    """The advisor's answer for the state an explorer is now in, with its running cost."""

    step: int  # moves observed so far (0 for the start decision)
    state: int
    advise: bool
    advice: tuple[float, ...] | None  # theta_s when advising (one probability an action)
    kl: float  # KL[theta_s || P(A | s, H)] in nats (times ``kl_scale``: AdviceTables)
    p_normal: float  # P(M1 | H)
    advice_count: int
    total_cost: float  # kappa x advice_count
    benefit: float  # sum of KL at advised states (eq. (3): Delta U(s) ~ KL)


@dataclass(frozen=True, slots=True)
class DecisionBatch:
    """The decisions for a batch of one explorer's moves, as columns: decision ``i`` is step
    ``first_step + i``. ``advice`` holds the advice of the advising decisions, in order (k, A).
    The running figures follow from the columns: ``total_cost = kappa * advice_count``."""

    first_step: int
    state: IntArray
    advise: BoolArray
    kl: FloatArray
    p_normal: FloatArray
    advice_count: IntArray
    benefit: FloatArray
    advice: FloatArray
    kappa: float
    count_before: int  # the advisor's figures before the batch
    benefit_before: float
    #: the tables whose theta_s the advice is (None: the advice is the advisor's own)
    advised_from: AdviceTables | None = None

    def __len__(self) -> int:
        return len(self.state)

    @property
    def total_cost(self) -> FloatArray:
        return np.multiply(self.kappa, self.advice_count, dtype=np.float64)

    @classmethod
    def of(
        cls, decisions: Sequence[Decision], kappa: float, count_before: int,
        benefit_before: float, advised_from: AdviceTables | None = None,
    ) -> DecisionBatch:  # fmt: skip
        """Columns of decisions made one at a time (``first_step`` 0 when there are none)."""
        rows = [d.advice for d in decisions if d.advise and d.advice is not None]
        width = (
            advised_from.n_actions if advised_from is not None
            else len(rows[0]) if rows else N_ACTIONS
        )  # fmt: skip
        return cls(
            decisions[0].step if decisions else 0,
            np.array([d.state for d in decisions], dtype=np.int64),
            np.array([d.advise for d in decisions], dtype=np.bool_),
            np.array([d.kl for d in decisions], dtype=np.float64),
            np.array([d.p_normal for d in decisions], dtype=np.float64),
            np.array([d.advice_count for d in decisions], dtype=np.int64),
            np.array([d.benefit for d in decisions], dtype=np.float64),
            np.array(rows, dtype=np.float64).reshape(len(rows), width),
            kappa, count_before, benefit_before, advised_from,
        )  # fmt: skip

    def decisions(self) -> list[Decision]:
        """The same decisions one by one, as :meth:`Advisor.observe` returns them."""
        rows = iter(self.advice.tolist())
        columns = zip(
            self.state.tolist(), self.advise.tolist(), self.kl.tolist(), self.p_normal.tolist(),
            self.advice_count.tolist(), self.total_cost.tolist(), self.benefit.tolist(),
            strict=True,
        )  # fmt: skip
        return [
            Decision(self.first_step + i, s, on, tuple(next(rows)) if on else None, kl, p, n, c, b)
            for i, (s, on, kl, p, n, c, b) in enumerate(columns)
        ]


def check_kappa_window(kappa: float, window: int) -> None:
    if not (isinstance(kappa, int | float) and math.isfinite(kappa) and kappa >= 0):
        raise ValueError(f"kappa must be a finite number >= 0, got {kappa!r}")
    if isinstance(window, bool) or not isinstance(window, int | np.integer) or window < 1:
        raise ValueError(f"window must be a whole number >= 1, got {window!r}")


def kl_divergence(p: npt.ArrayLike, q: npt.ArrayLike) -> float:
    """KL[p || q] in nats for two distributions over the same actions (q > 0 where p > 0)."""
    p_arr = np.asarray(p, dtype=np.float64)
    q_arr = np.asarray(q, dtype=np.float64)
    nz = p_arr > 0
    return float(max(0.0, np.sum(p_arr[nz] * (np.log(p_arr[nz]) - np.log(q_arr[nz])))))


class Advisor:
    """Watches one explorer and decides, step by step, whether advice is worth ``kappa``.

    What every advisor of :mod:`app.strategies` declares, so that a caller (the service,
    the experiments) never asks for its type: :attr:`strategy`, whether its advice is its own
    (:attr:`own_advice`; else theta_s of :attr:`tables`), the parameters in force
    (:meth:`params`), what it believes of the explorer's goal (:meth:`goal_beliefs`).
    """

    #: the advising strategy this advisor follows (its entry's name, :mod:`app.strategies`)
    strategy: ClassVar[str] = DEFAULT_STRATEGY
    #: True when the advice is not theta_s of the tables (goal-aware advice narrows it)
    own_advice: ClassVar[bool] = False

    __slots__ = (
        "_loglik",
        "_pos",
        "_ring",
        "advice_count",
        "benefit",
        "cap",
        "decisions",
        "kappa",
        "steps",
        "tables",
        "window",
    )

    def __init__(
        self, tables: AdviceTables, kappa: float = DEFAULT_KAPPA, window: int = DEFAULT_WINDOW
    ):
        check_kappa_window(kappa, window)
        self.tables = tables
        self.kappa = float(kappa)
        self.window = int(window)
        #: the advice count the advisor may reach at most: a decision that would advise once
        #: it is reached does not (what a session's advice budget, or a muted visitor, allows;
        #: the service sets it before each event or batch)
        self.cap = NO_CAP
        self.reset()

    def params(self) -> dict[str, int | float]:
        """The strategy's parameters in force (the paper's rule has none besides kappa)."""
        return {}

    def goal_beliefs(self) -> list[tuple[int, float, bool]] | None:
        """(goal state, P(goal | H), ruled out) per goal, for advisors that keep a goal
        posterior; None for the others."""
        return None

    def footprint(self) -> int:
        """Bytes the advisor's own state can take at most (what a service reserves for it):
        here the window's lists, a Python float (24 bytes) and a list slot (8) a value."""
        return self.tables.n_models * (self.window * 32 + 64) + 256

    def batch_slice(self) -> int:
        """Events of a batch a service runs at once (about 2 ms of work, the event loop free
        between slices): this form makes one Python call an event, 3-6 us each (measured)."""
        return 500

    def use_tables(self, tables: AdviceTables, goals: GoalPriors | None = None) -> None:
        """Advise from new tables (the prior was updated) from the next event on; the window
        keeps the log-probabilities it added, so removing them stays exact. ``goals``: new
        per-goal counts, for the advisors that read them."""
        self.tables = tables

    def reset(self) -> None:
        """Forget the history and the cost (a new explorer)."""
        m = self.tables.n_models
        self._reset_window()
        self._loglik = [0.0] * m
        self._pos = 0
        self.steps = 0
        self.decisions = 0
        self.advice_count = 0
        self.benefit = 0.0

    # ---- the window ---------------------------------------------------------------------
    def _reset_window(self) -> None:
        """An empty window: per model, W log-probabilities of 0.0 (forms that keep the window
        otherwise, the service's pair keys, make theirs here instead)."""
        self._ring = [[0.0] * self.window for _ in range(self.tables.n_models)]

    def _check(self, state: int, action: int | None = None) -> None:
        if not 0 <= state < self.tables.n_states:
            raise ValueError(f"state {state} out of range 0..{self.tables.n_states - 1}")
        if action is not None and not 0 <= action < self.tables.n_actions:
            raise ValueError(f"action {action} out of range 0..{self.tables.n_actions - 1}")

    def append(self, state: int, action: int) -> None:
        """Add (s, a) to H, dropping the oldest pair once the window is full. O(1)."""
        t = self.tables
        n_actions = t.n_actions
        if not (0 <= state < t.n_states and 0 <= action < n_actions):
            self._check(state, action)
        k = state * n_actions + action
        pos = self._pos
        loglik = self._loglik
        rings = self._ring
        for m, table in enumerate(t.log_probs_flat):
            lp = table[k]
            ring = rings[m]
            loglik[m] += lp - ring[pos]  # ring holds 0.0 until the window fills
            ring[pos] = lp
        pos += 1
        self.steps += 1
        if pos == self.window:
            pos = 0
            if self.steps % resync_period(self.window) == 0:
                for m, ring in enumerate(rings):
                    loglik[m] = math.fsum(ring)
        self._pos = pos

    @property
    def history_length(self) -> int:
        return min(self.steps, self.window)

    @property
    def log_likelihoods(self) -> list[float]:
        """log P(H | M) for each model, over the current window."""
        return list(self._loglik)

    def posterior(self) -> list[float]:
        """P(M | H) for each model (eq. (5)); the prior weights when H is empty."""
        z = [ll + lw for ll, lw in zip(self._loglik, self.tables.log_weight_list, strict=True)]
        mx = max(z)
        # exp(0) is exactly 1 (C99 F.9.3.1): the largest term needs no call
        e = [1.0 if v == mx else math.exp(v - mx) for v in z]
        tot = sum(e)
        return [v / tot for v in e]

    @property
    def p_normal(self) -> float:
        return self.posterior()[0]

    def expected_behaviour(self, state: int) -> list[float]:
        """P(A | s, H) (eq. (4))."""
        self._check(state)
        return self._mixture(self.posterior(), state)

    def _mixture(self, post: list[float], state: int) -> list[float]:
        n_actions = self.tables.n_actions
        base = state * n_actions
        probs = self.tables.probs_flat
        out = []
        for a in range(n_actions):
            mix = post[0] * probs[0][base + a]
            for m in range(1, len(post)):
                mix += post[m] * probs[m][base + a]
            out.append(mix)
        return out

    # ---- deciding -----------------------------------------------------------------------
    def divergence(self, state: int) -> tuple[float, float]:
        """(KL[theta_s || P(A | s, H)], P(M1 | H)) without counting a decision."""
        self._check(state)
        return self._divergence(state)

    def _divergence(self, state: int) -> tuple[float, float]:
        """The paper's decision for a valid ``state``: eqs. (4)-(6). The hot path, so the
        posterior and the mixture are inlined; app/kernels.py:decide is the same arithmetic
        in the same order, compiled."""
        t = self.tables
        if t.n_actions != N_ACTIONS:
            return self._divergence_any(state)
        b = state * N_ACTIONS
        probs = t.probs_flat
        loglik, weights = self._loglik, t.log_weight_list
        if len(loglik) == 2:
            # the two models of the paper: the general code below, unrolled (the same
            # operations on the same numbers in the same order, so the same bits)
            z0, z1 = loglik[0] + weights[0], loglik[1] + weights[1]
            if z0 >= z1:
                e0, e1 = 1.0, math.exp(z1 - z0)  # exp(0) is exactly 1: one call
            else:
                e0, e1 = math.exp(z0 - z1), 1.0
            tot = e0 + e1
            p0, p1 = e0 / tot, e1 / tot
            q0, q1 = probs[0], probs[1]
            m0, m1 = p0 * q0[b] + p1 * q1[b], p0 * q0[b + 1] + p1 * q1[b + 1]
            m2, m3 = p0 * q0[b + 2] + p1 * q1[b + 2], p0 * q0[b + 3] + p1 * q1[b + 3]
        else:
            post = self.posterior()  # eq. (5)
            p0 = post[0]  # the mixture P(A | s, H), eq. (4)
            m0, m1, m2, m3 = (p0 * probs[0][b], p0 * probs[0][b + 1],
                              p0 * probs[0][b + 2], p0 * probs[0][b + 3])  # fmt: skip
            for m in range(1, len(post)):
                pm, pr = post[m], probs[m]
                m0 += pm * pr[b]
                m1 += pm * pr[b + 1]
                m2 += pm * pr[b + 2]
                m3 += pm * pr[b + 3]
        # KL[theta_s || mixture], eq. (6)
        th = t.theta_flat
        log = math.log
        cross = th[b] * log(m0) + th[b + 1] * log(m1)
        cross += th[b + 2] * log(m2)
        cross += th[b + 3] * log(m3)
        kl = t.neg_entropy_list[state] - cross
        return (kl if kl > 0.0 else 0.0), p0

    def _divergence_any(self, state: int) -> tuple[float, float]:
        """:meth:`_divergence` for any number of actions A (a building of several floors: six),
        the KL times ``kl_scale`` (log 4 / log A): the same operations in the same order as
        app/kernels.py:decide_any."""
        t = self.tables
        n_actions = t.n_actions
        b = state * n_actions
        loglik = self._loglik
        if len(loglik) == 2:  # the paper's two models, unrolled as in _divergence
            weights, probs = t.log_weight_list, t.probs_flat
            z0, z1 = loglik[0] + weights[0], loglik[1] + weights[1]
            if z0 >= z1:
                e0, e1 = 1.0, math.exp(z1 - z0)
            else:
                e0, e1 = math.exp(z0 - z1), 1.0
            tot = e0 + e1
            p0, p1 = e0 / tot, e1 / tot
            q0, q1, th, log = probs[0], probs[1], t.theta_flat, math.log
            # KL[theta_s || mixture], eq. (6), each action's mixture (eq. (4)) as it goes
            cross = th[b] * log(p0 * q0[b] + p1 * q1[b])
            for i in range(b + 1, b + n_actions):
                cross += th[i] * log(p0 * q0[i] + p1 * q1[i])
        else:
            post = self.posterior()  # eq. (5)
            p0 = post[0]
            mix = self._mixture(post, state)  # eq. (4)
            th, log = t.theta_flat, math.log
            cross = th[b] * log(mix[0])
            for a in range(1, n_actions):
                cross += th[b + a] * log(mix[a])
        kl = t.neg_entropy_list[state] - cross  # eq. (6)
        return (kl * t.kl_scale if kl > 0.0 else 0.0), p0

    def decide(self, state: int) -> Decision:
        """Decide for the explorer now at ``state`` and account for the cost."""
        t = self.tables
        if not 0 <= state < t.n_states:
            raise ValueError(f"state {state} out of range 0..{t.n_states - 1}")
        kl, p0 = self._divergence(state)
        self.decisions += 1
        advice: tuple[float, ...] | None = None
        if kl >= self.kappa and self.advice_count < self.cap:
            self.advice_count += 1
            self.benefit += kl
            b, th = state * t.n_actions, t.theta_flat
            if t.n_actions == N_ACTIONS:
                advice = (th[b], th[b + 1], th[b + 2], th[b + 3])
            else:
                advice = tuple(th[b : b + t.n_actions])
        return Decision(
            self.steps, state, advice is not None, advice, kl, p0,
            self.advice_count, self.kappa * self.advice_count, self.benefit,
        )  # fmt: skip

    def record(
        self, state: int, advise: bool, advice: tuple[float, ...] | None,
        kl: float, p_normal: float,
    ) -> Decision:  # fmt: skip
        """Account for a decision taken by another rule (see :mod:`app.advice.rules`); it
        advises only below :attr:`cap`."""
        advise = advise and self.advice_count < self.cap
        self.decisions += 1
        if advise:
            self.advice_count += 1
            self.benefit += kl
        return Decision(
            self.steps, state, advise, advice if advise else None, kl, p_normal,
            self.advice_count, self.kappa * self.advice_count, self.benefit,
        )  # fmt: skip

    def start(self, state: int) -> Decision:
        """The first decision of a session: forget H and the cost, decide for ``state``."""
        self.reset()
        return self.decide(state)

    def observe(self, state: int, action: int, next_state: int) -> Decision:
        """The explorer at ``state`` took ``action`` and reached ``next_state``."""
        self.append(state, action)
        return self.decide(next_state)

    def observe_batch(
        self, states: IntArray, actions: IntArray, next_states: IntArray
    ) -> DecisionBatch:
        """:meth:`observe` for each (s, a, s') in turn, as columns. Inputs must be valid
        (states in range, actions 0..A-1): the caller checks them first. Advisors with a faster
        way (the service's compiled one) override this with the same results."""
        count, benefit, tables = self.advice_count, self.benefit, self.tables
        moves = zip(states.tolist(), actions.tolist(), next_states.tolist(), strict=True)
        decisions = [self.observe(s, a, s2) for s, a, s2 in moves]
        theta = None if self.own_advice else tables
        return DecisionBatch.of(decisions, self.kappa, count, benefit, theta)

    @property
    def total_cost(self) -> float:
        return self.kappa * self.advice_count

    @property
    def advice_per_100(self) -> float:
        """Advice given per 100 decisions (one decision per step, plus the start)."""
        return 100.0 * self.advice_count / self.decisions if self.decisions else 0.0
