"""Compiled explorers with the compiled advisor: whole episodes in one numba call.

Each kernel is the loop of :func:`app.agents.episodes.run_episode` / ``run_learning`` with the
explorers of :mod:`app.agents.explorers` and :mod:`app.agents.qlearning` inlined: the same
``rng.random()`` draws in the same order, so from equal generators they produce the same
trajectory and the same decisions (``tests/agents/test_fast.py``). The Python wrappers in
:mod:`app.agents.simulate` prepare the arrays.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from numba import njit

from app.agents.fast_advisor import advisor_decide, advisor_push, resync_period

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

# explorer kinds, in the order of app.agents.explorers.FIXED_EXPLORERS
RANDOM, RANDOM_AVOID, LEFT, BUG, OPTIMAL = 0, 1, 2, 3, 4


@njit(cache=True)
def sample_action(weights: FloatArray, u: float, mask: BoolArray) -> int:  # pragma: no cover
    """explorers.sample_action: inverse CDF over the allowed actions."""
    total = 0.0
    for a in range(4):
        if mask[a]:
            total += weights[a]
    target = u * total
    running = 0.0
    last = -1
    for a in range(4):
        if mask[a]:
            running += weights[a]
            last = a
            if target < running:
                return a
    return last


@njit(cache=True)
def uniform_choice(mask: BoolArray, u: float) -> int:  # pragma: no cover
    """explorers.uniform_choice: the int(u * k)-th allowed action."""
    k = 0
    for a in range(4):
        if mask[a]:
            k += 1
    pick = int(u * k)
    for a in range(4):
        if mask[a]:
            if pick == 0:
                return a
            pick -= 1
    return -1


@njit(cache=True)
def own_action(
    kind: int,
    s: int,
    heading: int,
    goal: int,
    open_moves: BoolArray,
    cells: IntArray,
    optimal: BoolArray,
    rng: np.random.Generator,
) -> int:  # pragma: no cover
    """The rule of a fixed-policy explorer (explorers.*.policy)."""
    if kind == RANDOM:
        return int(rng.random() * 4)
    if kind == RANDOM_AVOID:
        return uniform_choice(open_moves[s], rng.random())
    if kind == LEFT:
        for turn in (3, 0, 1, 2):  # left, straight, right, back
            a = (heading + turn) % 4
            if open_moves[s, a]:
                return a
        return heading
    if kind == BUG:
        dr = cells[goal, 0] - cells[s, 0]
        dc = cells[goal, 1] - cells[s, 1]
        vert = -1 if dr == 0 else (2 if dr > 0 else 0)
        horiz = -1 if dc == 0 else (1 if dc > 0 else 3)
        first, second = vert, horiz
        if abs(dc) > abs(dr) or (abs(dc) == abs(dr) and dr != 0 and rng.random() >= 0.5):
            first, second = horiz, vert
        if first >= 0 and open_moves[s, first]:
            return first
        if second >= 0 and open_moves[s, second]:
            return second
        return uniform_choice(open_moves[s], rng.random())
    # OPTIMAL
    best = optimal[s]
    n_best = 0
    only = 0
    for a in range(4):
        if best[a]:
            n_best += 1
            only = a
    if n_best == 0:
        return int(rng.random() * 4)
    if n_best == 1:
        return only
    return uniform_choice(best, rng.random())


@njit(cache=True)
def fixed_episode(
    kind: int,
    next_state: IntArray,
    open_moves: BoolArray,
    cells: IntArray,
    optimal: BoolArray,
    start: int,
    goal: int,
    max_steps: int,
    advised: bool,
    kappa: float,
    window: int,
    theta: FloatArray,
    probs: FloatArray,
    log_probs: FloatArray,
    log_weights: FloatArray,
    neg_entropy: FloatArray,
    rng: np.random.Generator,
    states_out: IntArray,
    p_out: FloatArray,
    advise_out: BoolArray,
) -> tuple[int, bool, int, float]:  # pragma: no cover
    """One task of a fixed-policy explorer; returns (steps, success, advice count, benefit).

    ``states_out[t]``, ``p_out[t]`` and ``advise_out[t]`` receive the state, P(M1 | H) and
    the advisor's decision before move ``t`` (only the first ``steps`` entries are written).
    """
    n_models = log_probs.shape[0]
    ring = np.zeros((n_models, window))
    loglik = np.zeros(n_models)
    pos = 0
    period = resync_period(window)
    heading = 0
    if kind == LEFT:
        heading = int(rng.random() * 4)
    all_moves = np.ones(4, dtype=np.bool_)
    advice_count = 0
    benefit = 0.0
    s = start
    kl, p = advisor_decide(loglik, log_weights, probs, theta, neg_entropy, s)
    for t in range(max_steps):
        advise = kl >= kappa
        if advise:
            advice_count += 1
            benefit += kl
        states_out[t] = s
        p_out[t] = p
        advise_out[t] = advise
        if advised and advise:
            a = sample_action(theta[s * 4 : s * 4 + 4], rng.random(), all_moves)
        else:
            a = own_action(kind, s, heading, goal, open_moves, cells, optimal, rng)
        s2 = next_state[s, a]
        if kind == LEFT and s2 != s:
            heading = a
        if s2 == goal:
            return t + 1, True, advice_count, benefit
        pos = advisor_push(ring, loglik, pos, t + 1, period, log_probs, s, a)
        kl, p = advisor_decide(loglik, log_weights, probs, theta, neg_entropy, s2)
        s = s2
    return max_steps, False, advice_count, benefit


@njit(cache=True)
def q_learning(
    next_state: IntArray,
    start: int,
    goal: int,
    episodes: int,
    max_steps: int,
    step_budget: int,
    alpha: float,
    gamma: float,
    epsilon: float,
    ties_advice: bool,
    advised: bool,
    keep_history: bool,
    kappa: float,
    window: int,
    theta: FloatArray,
    probs: FloatArray,
    log_probs: FloatArray,
    log_weights: FloatArray,
    neg_entropy: FloatArray,
    rng: np.random.Generator,
    q: FloatArray,
    steps_out: IntArray,
    success_out: BoolArray,
    advice_out: IntArray,
    decisions_out: IntArray,
    p_mean_out: FloatArray,
) -> int:  # pragma: no cover
    """Episodes of one Q-learning task (``q`` (S, 4) is learned in place); returns how many
    episodes ran (fewer than ``episodes`` only when ``step_budget`` > 0 runs out).

    Per episode: moves, success, advice given and decisions made at the states it acted in
    (one per move), mean P(M1 | H) over those decisions.
    """
    n_models = log_probs.shape[0]
    ring = np.zeros((n_models, window))
    loglik = np.zeros(n_models)
    pos = 0
    period = resync_period(window)
    appended = 0  # pairs in this advisor session
    all_moves = np.ones(4, dtype=np.bool_)
    best = np.zeros(4, dtype=np.bool_)
    total_steps = 0
    for e in range(episodes):
        if not keep_history:
            ring[:] = 0.0
            loglik[:] = 0.0
            pos = 0
            appended = 0
        s = start
        kl, p = advisor_decide(loglik, log_weights, probs, theta, neg_entropy, s)
        n_advice = 0
        p_sum = 0.0
        success = False
        t = 0
        while t < max_steps:
            advise = kl >= kappa
            n_advice += advise
            p_sum += p
            give = advised and advise
            row = theta[s * 4 : s * 4 + 4]
            if rng.random() < epsilon:
                u = rng.random()
                a = sample_action(row, u, all_moves) if give else int(u * 4)
            else:
                qmax = q[s].max()
                n_best = 0
                a = 0
                for b in range(4):
                    best[b] = q[s, b] == qmax
                    if best[b]:
                        n_best += 1
                        a = b
                if n_best > 1:
                    if give and ties_advice:
                        a = sample_action(row, rng.random(), best)
                    else:
                        a = uniform_choice(best, rng.random())
            s2 = next_state[s, a]
            t += 1
            if s2 == goal:
                q[s, a] += alpha * (1000.0 - q[s, a])
                success = True
                break
            q[s, a] += alpha * (gamma * q[s2].max() - q[s, a])
            appended += 1
            pos = advisor_push(ring, loglik, pos, appended, period, log_probs, s, a)
            kl, p = advisor_decide(loglik, log_weights, probs, theta, neg_entropy, s2)
            s = s2
            if step_budget > 0 and total_steps + t >= step_budget:
                break
        total_steps += t
        steps_out[e] = t
        success_out[e] = success
        advice_out[e] = n_advice
        decisions_out[e] = t  # the decisions the explorer acted on, one per move
        p_mean_out[e] = p_sum / t
        if step_budget > 0 and total_steps >= step_budget:
            return e + 1
    return episodes
