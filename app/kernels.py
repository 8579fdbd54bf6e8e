"""Every compiled advisor and explorer function, in one module (numba, numpy only).

numba caches compiled code per file and does not notice a change in another file, so the
kernels that call each other live here together, and nothing is read from another module's
globals: constants (the re-sum period, the explorer and strategy codes) are arguments or are
defined here, and the Python side that calls in (:mod:`app.agents.simulate`, the service's
stream advisor) is pinned to these codes by tests. Each kernel is the compiled form of readable
Python it is tested against, decision by decision and bit for bit:

========================  ====================================================================
kernel                    the readable form (and its test)
========================  ====================================================================
``decide``                ``Advisor._divergence`` (app/advice/advisor.py): eqs. (4)-(6)
``push``, ``fsum``        ``Advisor.append``: the window ring, exact re-sum (``math.fsum``)
``goal_posterior``,       ``GoalAwareAdvisor`` (app/advice/goals.py) and
``goal_decide``           ``GoalPriors.theta_row`` (app/advice/priors.py)
``observe_stream``        a batch of ``Advisor.observe`` for the service's ``StreamAdvisor``
``episode``               ``run_episode`` (app/agents/episodes.py) with the explorers of
                          app/agents/explorers.py and every advisor of ``make_advisor``
``q_learning``            ``run_learning`` with ``QLearningExplorer`` (app/agents/qlearning.py)
========================  ====================================================================

Tables are passed as the tuple ``AdviceTables.arrays``: (log_probs (M, S*4), log_weights (M,),
probs (M, S*4), theta (S*4,), neg_entropy (S,)); goal tables as (goal_of_state (S,), alpha0,
unknown counts (S*4,), goal counts (S*4, G), each goal's log theta (S*4, G)).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from numba import njit

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]
KeyArray = npt.NDArray[np.int32]
FlagArray = npt.NDArray[np.uint8]
Tables = tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]
GoalTables = tuple[IntArray, float, FloatArray, FloatArray, FloatArray]

#: explorer kinds, in the order of app.agents.explorers.FIXED_EXPLORERS
RANDOM, RANDOM_AVOID, LEFT, BUG, OPTIMAL = 0, 1, 2, 3, 4
#: strategies, in the order of app.advice.strategies.STRATEGIES
PAPER, GOAL_AWARE, EARLY, IMPORTANCE, MISTAKE, RANDOM_RULE, ALWAYS = 0, 1, 2, 3, 4, 5, 6


# ---- the paper's advisor ----------------------------------------------------------------------
@njit(cache=True)
def fsum(values: FloatArray) -> float:  # pragma: no cover - compiled
    """Correctly rounded sum of finite floats: CPython 3.11 ``math.fsum`` step for step."""
    partials = np.empty(values.shape[0] + 1)
    n = 0
    for k in range(values.shape[0]):
        x = values[k]
        i = 0
        for j in range(n):
            y = partials[j]
            if abs(x) < abs(y):
                x, y = y, x
            hi = x + y
            lo = y - (hi - x)
            if lo != 0.0:
                partials[i] = lo
                i += 1
            x = hi
        n = i
        if x != 0.0:
            partials[n] = x
            n += 1
    hi = 0.0
    lo = 0.0
    if n > 0:
        n -= 1
        hi = partials[n]
        while n > 0:
            x = hi
            n -= 1
            y = partials[n]
            hi = x + y
            lo = y - (hi - x)
            if lo != 0.0:
                break
        # half-even rounding across several partials (as CPython does)
        if n > 0 and ((lo < 0.0 and partials[n - 1] < 0.0) or (lo > 0.0 and partials[n - 1] > 0.0)):
            y = lo * 2.0
            x = hi + y
            if y == x - hi:
                hi = x
    return float(hi)


@njit(cache=True, inline="always")
def posterior(
    loglik: FloatArray, log_weights: FloatArray, z: FloatArray
) -> float:  # pragma: no cover
    """P(M | H), eq. (5): ``z`` receives exp(log P(H | M) + log P(M) - max); returns their sum
    (P(M | H) = z[m] / sum). exp(0) is exactly 1 (C99 F.9.3.1), so the largest term needs no
    call."""
    n_models = loglik.shape[0]
    mx = loglik[0] + log_weights[0]
    for m in range(n_models):
        z[m] = loglik[m] + log_weights[m]
        if z[m] > mx:
            mx = z[m]
    tot = 0.0
    for m in range(n_models):
        d = z[m] - mx
        z[m] = 1.0 if d == 0.0 else math.exp(d)
        tot += z[m]
    return tot


@njit(cache=True, inline="always")  # as a call it cost the stream loop twice its time (measured)
def decide(
    loglik: FloatArray, tables: Tables, s: int, z: FloatArray
) -> tuple[float, float]:  # pragma: no cover
    """(KL[theta_s || P(A | s, H)], P(M1 | H)) for the explorer now at ``s``: eqs. (4)-(6).
    ``z`` is scratch space, one entry per model."""
    _, log_weights, probs, theta, neg_entropy = tables
    tot = posterior(loglik, log_weights, z)
    b = s * 4
    p0 = z[0] / tot
    m0, m1 = p0 * probs[0, b], p0 * probs[0, b + 1]
    m2, m3 = p0 * probs[0, b + 2], p0 * probs[0, b + 3]
    for m in range(1, loglik.shape[0]):  # the mixture P(A | s, H), eq. (4)
        pm = z[m] / tot
        m0 += pm * probs[m, b]
        m1 += pm * probs[m, b + 1]
        m2 += pm * probs[m, b + 2]
        m3 += pm * probs[m, b + 3]
    cross = theta[b] * math.log(m0) + theta[b + 1] * math.log(m1)
    cross += theta[b + 2] * math.log(m2)
    cross += theta[b + 3] * math.log(m3)
    kl = neg_entropy[s] - cross  # eq. (6)
    return (kl if kl > 0.0 else 0.0), p0


@njit(cache=True)
def decide_call(
    loglik: FloatArray, tables: Tables, s: int, z: FloatArray
) -> tuple[float, float]:  # pragma: no cover - compiled
    """:func:`decide` as a call, for long loops: inlined into the episode loop, it made that
    loop about a fifth slower (measured), where the short stream loop gains from inlining."""
    return decide(loglik, tables, s, z)


@njit(cache=True)
def push(
    ring: FloatArray, loglik: FloatArray, pos: int, steps: int, period: int,
    log_probs: FloatArray, s: int, a: int,
) -> int:  # pragma: no cover - compiled  # fmt: skip
    """Add (s, a) to the window ring (M, W); returns the new position. ``steps`` counts the
    pairs appended, this one included; every ``period`` pairs (at a wrap) the sums are
    recomputed exactly."""
    k = s * 4 + a
    for m in range(ring.shape[0]):
        lp = log_probs[m, k]
        loglik[m] += lp - ring[m, pos]  # the ring holds 0.0 until the window fills
        ring[m, pos] = lp
    pos += 1
    if pos == ring.shape[1]:
        pos = 0
        if steps % period == 0:
            for m in range(ring.shape[0]):
                loglik[m] = fsum(ring[m])
    return pos


# ---- goal-aware advice ------------------------------------------------------------------------
@njit(cache=True)
def goal_posterior(
    goal_ll: FloatArray, alive: BoolArray, beta: float, w: FloatArray
) -> None:  # pragma: no cover
    """``GoalAwareAdvisor.goal_posterior`` into ``w``: softmax of beta * log P(H | theta^g)
    over the goals not ruled out (all goals if every one is)."""
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
            w[g] = 1.0 if beta == 0.0 else math.exp(beta * goal_ll[g] - mx)
        else:
            w[g] = 0.0
        tot += w[g]
    for g in range(n_goals):
        w[g] = w[g] / tot


@njit(cache=True)
def goal_decide(
    loglik: FloatArray, tables: Tables, goals: GoalTables, w: FloatArray, s: int,
    theta_w: FloatArray, z: FloatArray,
) -> tuple[float, float]:  # pragma: no cover - compiled  # fmt: skip
    """``GoalAwareAdvisor.decide``: fills ``theta_w`` (4,) with theta^w_s and returns
    (KL[theta^w_s || P(M1 | H) theta^w_s + sum_m>1 P(M | H) P(A | s, M)], P(M1 | H))."""
    _, alpha0, unknown, counts, _ = goals
    n_goals = w.shape[0]
    b = s * 4
    total = 0.0
    for a in range(4):
        dot = 0.0
        for g in range(n_goals):
            dot += w[g] * counts[b + a, g]
        theta_w[a] = alpha0 + unknown[b + a] + n_goals * dot
        total += theta_w[a]
    for a in range(4):
        theta_w[a] = theta_w[a] / total
    _, log_weights, probs, _, _ = tables
    tot = posterior(loglik, log_weights, z)
    p0 = z[0] / tot
    kl = 0.0
    for a in range(4):
        mix = p0 * theta_w[a]
        for m in range(1, loglik.shape[0]):
            mix += z[m] / tot * probs[m, b + a]
        kl += theta_w[a] * (math.log(theta_w[a]) - math.log(mix))
    return (kl if kl > 0.0 else 0.0), p0


# ---- the service's batches: the window as pair keys -------------------------------------------
@njit(cache=True)
def observe_stream(
    window: tuple[KeyArray, FlagArray, FloatArray],
    loglik: FloatArray,
    pos: int,
    steps: int,
    period: int,
    tables: Tables,
    kappa: float,
    count: int,
    benefit: float,
    moves: tuple[IntArray, IntArray, IntArray],
    out: tuple[FloatArray, FloatArray, BoolArray, IntArray, FloatArray],
) -> tuple[int, int, float, int]:  # pragma: no cover - compiled
    """``Advisor.observe`` for each (s, a, s'), accounting as ``Advisor.decide``.

    The window is (pair keys s * 4 + a, -1 where empty; 1 where a pair's value was kept in
    ``old`` because the tables changed since it was added; those values): a leaving pair is
    subtracted with the value the core stored, and the exact re-sum (after ``steps`` +
    i + 1 pairs, a multiple of ``period``, at a wrap) sums the values the core's ring holds,
    in its order. Fills ``out`` (kl, p_normal, advise, count, benefit); returns (position,
    advice count, benefit, kept values that left the window)."""
    keys, kept, old = window
    log_probs = tables[0]
    states, actions, next_states = moves
    kl_out, p_out, advise_out, count_out, benefit_out = out
    size = keys.shape[0]
    n_models = loglik.shape[0]
    z = np.empty(n_models)
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
            if (steps + i + 1) % period == 0:
                ring = np.empty(size)
                for m in range(n_models):
                    for p in range(size):
                        ring[p] = old[m, p] if kept[p] else log_probs[m, keys[p]]
                    loglik[m] = fsum(ring)
        kl, p0 = decide(loglik, tables, next_states[i], z)
        if kl >= kappa:
            count += 1
            benefit += kl
            advise_out[i] = True
        else:
            advise_out[i] = False
        kl_out[i] = kl
        p_out[i] = p0
        count_out[i] = count
        benefit_out[i] = benefit
    return pos, count, benefit, gone


@njit(cache=True)
def keep_values(
    keys: KeyArray, kept: FlagArray, old: FloatArray, log_probs: FloatArray
) -> int:  # pragma: no cover
    """For each pair of the window whose value is not kept yet, keep its value under each
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


# ---- explorers ----------------------------------------------------------------------------------
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
    kind: int, s: int, heading: int, goal: int, open_moves: BoolArray, cells: IntArray,
    optimal: BoolArray, rng: np.random.Generator,
) -> int:  # pragma: no cover  # fmt: skip
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


# ---- whole episodes -----------------------------------------------------------------------------
@njit(cache=True)
def rule_says(
    rule: int, t: int, s: int, last_s: int, last_a: int,
    rule_params: tuple[int, float, float, float], tables: Tables, rule_rng: np.random.Generator,
) -> bool:  # pragma: no cover - compiled  # fmt: skip
    """``RuleAdvisor``'s rules: advise at ``s`` after ``t`` decisions (the last move was
    (``last_s``, ``last_a``), -1 before the first)."""
    n_steps, threshold, rate, _ = rule_params
    if rule == EARLY:
        return t < n_steps
    if rule == IMPORTANCE:  # KL[theta_s || uniform] = log 4 + sum theta log theta
        return bool(math.log(4.0) + tables[4][s] >= threshold)
    if rule == MISTAKE:
        return last_s >= 0 and bool(tables[3][last_s * 4 + last_a] < threshold)
    if rule == RANDOM_RULE:
        return rule_rng.random() < rate
    return True  # ALWAYS


@njit(cache=True)
def episode(
    kind: int,
    world: tuple[IntArray, BoolArray, IntArray, BoolArray],
    start: int,
    goal: int,
    max_steps: int,
    advised: bool,
    rule: int,
    kappa: float,
    window: int,
    period: int,
    rule_params: tuple[int, float, float, float],
    tables: Tables,
    goals: GoalTables,
    rng: np.random.Generator,
    rule_rng: np.random.Generator,
    out: tuple[IntArray, FloatArray, BoolArray],
) -> tuple[int, bool, int, float, int]:  # pragma: no cover - compiled
    """One task of a fixed-policy explorer ``kind`` from ``start``, watched by the advisor of
    strategy ``rule``; returns (steps, success, advice count, benefit, goals ruled out).

    ``world`` is (next_state (S, 4), open moves (S, 4), cells (S, 2), the optimal moves to
    ``goal`` (S, 4)); ``rule_params`` (n_steps, threshold, rate, beta). ``out`` receives, before
    each move, the state, P(M1 | H) (when ``out[1]`` is not empty) and the decision (given to
    the explorer only if ``advised``). The explorer's draws come from ``rng``, the ``random``
    rule's from ``rule_rng``, in the reference's order. ``goals`` is read by ``goal_aware``
    only (G may be 0 for the others)."""
    next_state, open_moves, cells, optimal = world
    beta = rule_params[3]
    log_probs, _, _, theta, _ = tables
    goal_of_state, _, _, _, goal_log_theta = goals
    states_out, p_out, advise_out = out
    record_p = p_out.shape[0] > 0
    n_models = log_probs.shape[0]
    ring = np.zeros((n_models, window))
    loglik = np.zeros(n_models)
    z = np.empty(n_models)
    pos = 0
    n_goals = goal_log_theta.shape[1] if rule == GOAL_AWARE else 0
    goal_ring = np.zeros((n_goals, window if beta > 0.0 else 0))
    goal_ll = np.zeros(n_goals)
    alive = np.ones(n_goals, dtype=np.bool_)
    w = np.empty(n_goals)
    theta_w = np.empty(4)
    heading = 0
    if kind == LEFT:
        heading = int(rng.random() * 4)
    all_moves = np.ones(4, dtype=np.bool_)
    advice_count = 0
    benefit = 0.0
    s = start
    last_s = -1
    last_a = -1
    for t in range(max_steps):
        # ---- the decision for s (t moves so far) --------------------------------------------
        if rule == GOAL_AWARE:
            goal_posterior(goal_ll, alive, beta, w)
            kl, p = goal_decide(loglik, tables, goals, w, s, theta_w, z)
            advise = kl >= kappa
        else:
            says = rule == PAPER or rule_says(
                rule, t, s, last_s, last_a, rule_params, tables, rule_rng
            )
            kl, p = 0.0, 0.0
            if rule == PAPER or says or record_p:  # the paper's KL is reported where advised
                kl, p = decide_call(loglik, tables, s, z)
            advise = kl >= kappa if rule == PAPER else says
        if advise:
            advice_count += 1
            benefit += kl
        states_out[t] = s
        if record_p:
            p_out[t] = p
        advise_out[t] = advise
        # ---- the explorer acts --------------------------------------------------------------
        if advised and advise:  # two calls: one merged row variable cost a quarter (measured)
            if rule == GOAL_AWARE:
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
        # ---- the advisor appends (s, a) to H ------------------------------------------------
        if rule == GOAL_AWARE:
            gi = goal_of_state[s]
            if gi >= 0:  # it stood on goal gi's cell and went on: not its goal
                alive[gi] = False
            if beta > 0.0:  # beta = 0 never reads the per-goal window
                k = s * 4 + a
                for g in range(n_goals):
                    v = goal_log_theta[k, g]
                    goal_ll[g] += v - goal_ring[g, pos]
                    goal_ring[g, pos] = v
                if pos + 1 == window and (t + 1) % period == 0:
                    for g in range(n_goals):
                        goal_ll[g] = fsum(goal_ring[g])
        pos = push(ring, loglik, pos, t + 1, period, log_probs, s, a)
        last_s, last_a = s, a
        s = s2
    return max_steps, False, advice_count, benefit, n_goals - int(alive.sum())


@njit(cache=True)
def q_learning(
    next_state: IntArray,
    start: int,
    goal: int,
    episodes: int,
    max_steps: int,
    step_budget: int,
    learner: tuple[float, float, float, bool],
    advised: bool,
    keep_history: bool,
    kappa: float,
    window: int,
    period: int,
    tables: Tables,
    rng: np.random.Generator,
    q: FloatArray,
    out: tuple[IntArray, BoolArray, IntArray, IntArray, FloatArray],
) -> int:  # pragma: no cover - compiled
    """Episodes of one Q-learning task (``q`` (S, 4) is learned in place); returns how many
    episodes ran (fewer than ``episodes`` only when ``step_budget`` > 0 runs out).

    ``learner`` is (alpha, gamma, epsilon, ties broken by the advice). Per episode ``out``
    receives: moves, success, advice given and decisions made at the states it acted in (one
    per move), mean P(M1 | H) over those decisions."""
    alpha, gamma, epsilon, ties_advice = learner
    steps_out, success_out, advice_out, decisions_out, p_mean_out = out
    log_probs, _, _, theta, _ = tables
    n_models = log_probs.shape[0]
    ring = np.zeros((n_models, window))
    loglik = np.zeros(n_models)
    z = np.empty(n_models)
    pos = 0
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
        n_advice = 0
        p_sum = 0.0
        success = False
        t = 0
        while t < max_steps:
            kl, p = decide(loglik, tables, s, z)
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
            pos = push(ring, loglik, pos, appended, period, log_probs, s, a)
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
