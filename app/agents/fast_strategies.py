"""Every advising strategy compiled with the explorers: one task in one numba call.

:func:`strategy_episode` is the loop of :func:`app.agents.episodes.run_episode` with the
advisor of :func:`app.advice.strategies.make_advisor` inlined, for each strategy of
:data:`app.advice.strategies.STRATEGIES` (same order as the ``RULE_*`` constants):

* ``paper``: advise iff KL[theta_s || P(A | s, H)] >= kappa (the kernel of ``fast.py``);
* ``goal_aware``: the goal posterior w of :class:`app.advice.goals.GoalAwareAdvisor`, advice
  theta^w_s, advise iff KL[theta^w_s || P(M1 | H) theta^w_s + P(M2 | H) u] >= kappa;
* ``early`` / ``importance`` / ``mistake`` / ``random`` / ``always``: the rules of
  :class:`app.advice.strategies.RuleAdvisor`, advice theta_s. ``random`` draws from its own
  generator (``rule_rng``), one draw per decision, as the reference draws from its own.

The explorer's draws are those of the reference classes, in the same order. The window sums
use the same operations in the same order as the reference advisors; where the reference uses
numpy on four-element rows (goal-aware advice) the last bit can differ, so the tests require
equal decisions and moves and KL equal to 1e-12 (``tests/agents/test_fast_strategies.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from numba import njit

from app.advice.advisor import DEFAULT_KAPPA, DEFAULT_WINDOW, check_kappa_window
from app.advice.goals import GoalPriors
from app.advice.models import AdviceTables
from app.advice.strategies import STRATEGIES, StrategyParams
from app.agents.experts import optimal_actions
from app.agents.explorers import FIXED_EXPLORERS
from app.agents.fast import LEFT, own_action, sample_action
from app.agents.fast_advisor import FlatTables, advisor_push, fsum, resync_period
from app.domain.grid import GridDomain

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

# strategies, in the order of app.advice.strategies.STRATEGIES
RULE_PAPER, RULE_GOAL_AWARE, RULE_EARLY, RULE_IMPORTANCE, RULE_MISTAKE = 0, 1, 2, 3, 4
RULE_RANDOM, RULE_ALWAYS = 5, 6


@njit(cache=True)
def goal_posterior(
    goal_ll: FloatArray, alive: BoolArray, beta: float, w: FloatArray
) -> None:  # pragma: no cover - compiled
    """GoalAwareAdvisor.goal_posterior into ``w``: softmax of beta * log P(H | theta^g) over
    the goals not ruled out (all goals if every one is)."""
    n_goals = goal_ll.shape[0]
    any_alive = False
    for g in range(n_goals):
        any_alive = any_alive or alive[g]
    mx = -math.inf
    for g in range(n_goals):
        if alive[g] or not any_alive:
            z = beta * goal_ll[g]
            if z > mx:
                mx = z
    tot = 0.0
    for g in range(n_goals):
        if alive[g] or not any_alive:
            # beta = 0: exp(+-0 - +-0) is exactly 1, so skip the exp (ruling out only)
            w[g] = 1.0 if beta == 0.0 else math.exp(beta * goal_ll[g] - mx)
        else:
            w[g] = 0.0
        tot += w[g]
    for g in range(n_goals):
        w[g] = w[g] / tot


@njit(cache=True)
def model_posterior(
    loglik: FloatArray, log_weights: FloatArray, z: FloatArray
) -> float:  # pragma: no cover - compiled
    """Advisor.posterior without allocating: ``z`` receives exp(log P(H | M) + log P(M) - max);
    returns their sum (P(M | H) = z[m] / sum)."""
    n_models = loglik.shape[0]
    mx = loglik[0] + log_weights[0]
    for m in range(n_models):
        z[m] = loglik[m] + log_weights[m]
        if z[m] > mx:
            mx = z[m]
    tot = 0.0
    for m in range(n_models):
        z[m] = math.exp(z[m] - mx)
        tot += z[m]
    return tot


@njit(cache=True)
def paper_decide(
    loglik: FloatArray,
    log_weights: FloatArray,
    probs: FloatArray,
    theta: FloatArray,
    neg_entropy: FloatArray,
    s: int,
    z: FloatArray,
) -> tuple[float, float]:  # pragma: no cover - compiled
    """fast_advisor.advisor_decide with a scratch buffer ``z`` (no allocation per step)."""
    tot = model_posterior(loglik, log_weights, z)
    b = s * 4
    p0 = z[0] / tot
    m0 = p0 * probs[0, b]
    m1 = p0 * probs[0, b + 1]
    m2 = p0 * probs[0, b + 2]
    m3 = p0 * probs[0, b + 3]
    for m in range(1, loglik.shape[0]):
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
def goal_aware_decide(
    loglik: FloatArray,
    log_weights: FloatArray,
    probs: FloatArray,
    w: FloatArray,
    alpha0: float,
    unknown_counts: FloatArray,
    goal_counts: FloatArray,
    s: int,
    theta_w: FloatArray,
    z: FloatArray,
) -> tuple[float, float]:  # pragma: no cover - compiled
    """GoalAwareAdvisor.decide: fills ``theta_w`` (4,) with theta^w_s and returns
    (KL[theta^w_s || mixture], P(M1 | H)). ``goal_counts`` is (S*4, G)."""
    n_goals = w.shape[0]
    b = s * 4
    total = 0.0
    for a in range(4):
        dot = 0.0
        for g in range(n_goals):
            dot += w[g] * goal_counts[b + a, g]
        theta_w[a] = alpha0 + unknown_counts[b + a] + n_goals * dot
        total += theta_w[a]
    for a in range(4):
        theta_w[a] = theta_w[a] / total
    tot = model_posterior(loglik, log_weights, z)  # P(M | H), eq. (5)
    n_models = loglik.shape[0]
    p0 = z[0] / tot
    kl = 0.0
    for a in range(4):
        mix = p0 * theta_w[a]
        for m in range(1, n_models):
            mix += z[m] / tot * probs[m, b + a]
        kl += theta_w[a] * (math.log(theta_w[a]) - math.log(mix))
    if kl < 0.0:
        kl = 0.0
    return kl, p0


@njit(cache=True)
def strategy_episode(
    kind: int,
    next_state: IntArray,
    open_moves: BoolArray,
    cells: IntArray,
    optimal: BoolArray,
    start: int,
    goal: int,
    max_steps: int,
    advised: bool,
    rule: int,
    kappa: float,
    window: int,
    n_steps: int,
    threshold: float,
    rate: float,
    beta: float,
    theta: FloatArray,
    probs: FloatArray,
    log_probs: FloatArray,
    log_weights: FloatArray,
    neg_entropy: FloatArray,
    goal_of_state: IntArray,
    alpha0: float,
    unknown_counts: FloatArray,
    goal_counts: FloatArray,
    goal_log_theta: FloatArray,
    rng: np.random.Generator,
    rule_rng: np.random.Generator,
    states_out: IntArray,
    advise_out: BoolArray,
) -> tuple[int, bool, int, float, int]:  # pragma: no cover - compiled
    """One task of a fixed-policy explorer advised by ``rule``.

    Returns (steps, success, advice count, benefit, goals ruled out at the end). ``states_out``
    and ``advise_out`` receive the state and the decision before each move. Goal tables
    (``goal_counts`` and ``goal_log_theta`` (S*4, G), ``unknown_counts`` (S*4,)) are read
    only by ``goal_aware``.
    """
    n_models = log_probs.shape[0]
    ring = np.zeros((n_models, window))
    loglik = np.zeros(n_models)
    pos = 0
    period = resync_period(window)
    n_goals = goal_log_theta.shape[1]
    goal_ring = np.zeros((n_goals, window))
    goal_ll = np.zeros(n_goals)
    alive = np.ones(n_goals, dtype=np.bool_)
    w = np.empty(n_goals)
    theta_w = np.empty(4)
    z = np.empty(n_models)
    log_uniform = math.log(4.0)
    heading = 0
    if kind == LEFT:
        heading = int(rng.random() * 4)
    all_moves = np.ones(4, dtype=np.bool_)
    advice_count = 0
    benefit = 0.0
    s = start
    last_s = -1
    last_a = -1
    kl = 0.0
    for t in range(max_steps + 1):
        # ---- the decision for s (t decisions made so far) -------------------------------
        if rule == RULE_GOAL_AWARE:
            goal_posterior(goal_ll, alive, beta, w)
            kl, _ = goal_aware_decide(
                loglik, log_weights, probs, w, alpha0, unknown_counts, goal_counts, s, theta_w, z
            )
            advise = kl >= kappa
        elif rule == RULE_PAPER:
            kl, _ = paper_decide(loglik, log_weights, probs, theta, neg_entropy, s, z)
            advise = kl >= kappa
        else:
            if rule == RULE_EARLY:
                advise = t < n_steps
            elif rule == RULE_IMPORTANCE:
                advise = log_uniform + neg_entropy[s] >= threshold
            elif rule == RULE_MISTAKE:
                advise = last_s >= 0 and theta[last_s * 4 + last_a] < threshold
            elif rule == RULE_RANDOM:
                advise = rule_rng.random() < rate
            else:
                advise = True
            if advise:  # the paper's KL is only reported (benefit), so only where advised
                kl, _ = paper_decide(loglik, log_weights, probs, theta, neg_entropy, s, z)
        if t == max_steps:
            break
        if advise:
            advice_count += 1
            benefit += kl
        states_out[t] = s
        advise_out[t] = advise
        # ---- the explorer acts ------------------------------------------------------------
        if advised and advise:
            if rule == RULE_GOAL_AWARE:
                a = sample_action(theta_w, rng.random(), all_moves)
            else:
                a = sample_action(theta[s * 4 : s * 4 + 4], rng.random(), all_moves)
        else:
            a = own_action(kind, s, heading, goal, open_moves, cells, optimal, rng)
        s2 = next_state[s, a]
        if kind == LEFT and s2 != s:
            heading = a
        if s2 == goal:
            return t + 1, True, advice_count, benefit, n_goals - int(alive.sum())
        # ---- the advisor appends (s, a) to H ----------------------------------------------
        if rule == RULE_GOAL_AWARE:
            gi = goal_of_state[s]
            if gi >= 0:  # it stood on goal gi's cell and went on: not its goal
                alive[gi] = False
            k = s * 4 + a
            for g in range(n_goals if beta > 0.0 else 0):  # beta = 0 never reads goal_ll
                v = goal_log_theta[k, g]
                goal_ll[g] += v - goal_ring[g, pos]
                goal_ring[g, pos] = v
            if beta > 0.0 and pos + 1 == window and (t + 1) % period == 0:
                for g in range(n_goals):
                    goal_ll[g] = fsum(goal_ring[g])
        pos = advisor_push(ring, loglik, pos, t + 1, period, log_probs, s, a)
        last_s, last_a = s, a
        s = s2
    return max_steps, False, advice_count, benefit, n_goals - int(alive.sum())


@dataclass(frozen=True)
class StrategyRun:
    """One task of a fixed-policy explorer under one strategy; per-step arrays per move."""

    success: bool
    steps: int
    advice_count: int
    benefit: float  # sum of the deciding KL at advised states (paper's KL for the peer rules)
    goals_ruled_out: int  # goal_aware only (0 otherwise)
    states: IntArray  # state before each move
    advise: BoolArray  # the decision there (given to the explorer only if advised)

    @property
    def advice_per_100(self) -> float:
        return 100.0 * self.advice_count / max(1, self.steps)


class StrategySimulator:
    """A domain, its pooled tables and per-goal counts, prepared once for many compiled runs.

    ``tables`` is the paper's (pooled theta; P(M1 | H) for every strategy) and ``goal_priors``
    the per-goal counts goal-aware advice narrows theta with (the same expert data).
    """

    def __init__(self, domain: GridDomain, tables: AdviceTables, goal_priors: GoalPriors):
        if tables.n_states != domain.n_states or goal_priors.n_states != domain.n_states:
            raise ValueError("tables, goal priors and maze must have the same states")
        self.domain = domain
        self.flat = FlatTables(tables)
        self.next_state = np.ascontiguousarray(domain.next_state)
        self.open_moves = np.ascontiguousarray(domain.open_moves)
        self.cells = np.ascontiguousarray(domain.cells)
        g = goal_priors.n_goals
        self.goal_of_state = np.full(domain.n_states, -1, dtype=np.int64)
        self.goal_of_state[list(goal_priors.goals)] = np.arange(g)
        self.alpha0 = goal_priors.alpha0
        self.unknown_counts = np.ascontiguousarray(goal_priors.unknown_counts.reshape(-1))
        self.goal_counts = np.ascontiguousarray(goal_priors.goal_counts.reshape(g, -1).T)
        self.goal_log_theta = np.ascontiguousarray(goal_priors.goal_log_theta().reshape(g, -1).T)
        self._optimal: dict[int, BoolArray] = {}

    def optimal(self, goal: int) -> BoolArray:
        if goal not in self._optimal:
            self._optimal[goal] = np.ascontiguousarray(optimal_actions(self.domain, goal))
        return self._optimal[goal]

    def run(
        self,
        explorer: str,
        strategy: str,
        goal: int,
        rng: np.random.Generator,
        *,
        advised: bool = True,
        kappa: float = DEFAULT_KAPPA,
        window: int = DEFAULT_WINDOW,
        params: StrategyParams | None = None,
        rule_rng: np.random.Generator | None = None,
        max_steps: int = 5000,
    ) -> StrategyRun:
        """One task of ``explorer`` from the start cell, advised by ``strategy``.

        ``rule_rng`` is the ``random`` rule's own generator (default: seeded with
        ``params.seed``, as :class:`~app.advice.strategies.RuleAdvisor` seeds its own).
        """
        if explorer not in FIXED_EXPLORERS:
            raise ValueError(f"unknown explorer {explorer!r}: use {', '.join(FIXED_EXPLORERS)}")
        if strategy not in STRATEGIES:
            raise ValueError(f"unknown strategy {strategy!r}: use one of {', '.join(STRATEGIES)}")
        check_kappa_window(kappa, window)
        p = params or StrategyParams()
        p.check()
        if max_steps < 1:
            raise ValueError(f"max_steps must be at least 1, got {max_steps}")
        states = np.empty(max_steps, dtype=np.int64)
        advise = np.empty(max_steps, dtype=np.bool_)
        f = self.flat
        steps, success, count, benefit, ruled_out = strategy_episode(
            FIXED_EXPLORERS.index(explorer),
            self.next_state,
            self.open_moves,
            self.cells,
            self.optimal(goal),
            self.domain.start,
            goal,
            max_steps,
            advised,
            STRATEGIES.index(strategy),
            float(kappa),
            int(window),
            int(p.n_steps),
            float(p.threshold),
            float(p.rate),
            float(p.beta),
            f.theta,
            f.probs,
            f.log_probs,
            f.log_weights,
            f.neg_entropy,
            self.goal_of_state,
            self.alpha0,
            self.unknown_counts,
            self.goal_counts,
            self.goal_log_theta,
            rng,
            rule_rng if rule_rng is not None else np.random.default_rng(p.seed),
            states,
            advise,
        )
        return StrategyRun(
            bool(success),
            int(steps),
            int(count),
            float(benefit),
            int(ruled_out),
            states[:steps],
            advise[:steps],
        )
