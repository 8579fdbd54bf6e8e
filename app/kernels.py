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
``goal_stream``           a batch of ``GoalAwareAdvisor.observe`` for ``StreamGoalAware``
``episode``               ``run_episode`` (app/agents/episodes.py) with the explorers of
                          app/agents/explorers.py and every compiled strategy's advisor
``q_learning``            ``run_learning`` with ``QLearningExplorer`` (app/agents/qlearning.py)
``guide_distances``,      ``bfs_distances_each`` and ``compass_detours_each``
``guide_detours``,        (app/domain/grid.py) and ``compass_table`` (app/advice/guide.py): a
``guide_compass_table``   guide map's searches, without the GIL
========================  ====================================================================

Tables are passed as the tuple ``AdviceTables.arrays``: (log_probs (M, S*A), log_weights (M,),
probs (M, S*A), theta (S*A,), neg_entropy (S,)), A the domain's actions (4 on one floor, 6 in
a building of several floors: every kernel takes any A, the searches ``guide_distances`` and
``guide_detours`` a building's too); goal tables as (goal_of_state (S,),
alpha0, unknown counts (S*A,), goal counts (S*A, G), each goal's log theta (S*A, G)).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from app.arrays import BoolArray, ByteArray, Float32Array, FloatArray, IntArray, KeyArray

Tables = tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]
GoalTables = tuple[IntArray, float, FloatArray, FloatArray, FloatArray]
#: (next_state (S, A), open moves per state (S,), cells (S, 2: row, column), distance to each
#: destination (G, S), destination of each state (S,), the experts' goal counts (G, S * A), the
#: fewest moves against the compass on a way to each destination (G, S), the distance to each
#: landmark (L, S); in a building of several floors each state's floor (S,), (0,) on one floor;
#: the compass moves of every state and destination (S, G: ``compass_table``); whether the row
#: plus column difference bounds a walk's moves; the moves more a quickest walk may take a floor
#: it rides, 0 on one floor; the lead values (G, S, 4) float32, (0, 0, 4) without them):
#: ``GuideMap.arrays``
GuideArrays = tuple[
    IntArray,
    IntArray,
    IntArray,
    IntArray,
    IntArray,
    FloatArray,
    IntArray,
    IntArray,
    IntArray,
    ByteArray,
    bool,
    int,
    Float32Array,
]
#: what a guide batch fills (:func:`guide_stream`): kl, p_normal, advise, count, benefit,
#: advice (n, A)
GuideOut = tuple[FloatArray, FloatArray, BoolArray, IntArray, FloatArray, FloatArray]
#: (lam, p_lost, slack, spread, bump, the most destinations a tour is planned through)
GuideParams = tuple[
    float, float, float, float, float, int, float, float, float, float, float, int, float, float,
    float, int, int, int, int, int, int, float, float, float, float, int, float, float, float,
    float, int, int,
]  # fmt: skip

#: explorer kinds, in the order of app.agents.explorers.WALKERS (the paper's five first)
RANDOM, RANDOM_AVOID, LEFT, BUG, OPTIMAL, CORRIDOR, STRAIGHT = 0, 1, 2, 3, 4, 5, 6
#: (compliance p, position noise q, sight r) of a visitor: app.agents.explorers.Visitor
VisitorParams = tuple[float, float, int]
#: the strategies' compiled forms (each entry of app/strategies/table.py names its code)
PAPER, GOAL_AWARE, EARLY, IMPORTANCE, MISTAKE, RANDOM_RULE, ALWAYS, GUIDE = 0, 1, 2, 3, 4, 5, 6, 7


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
    ``z`` is scratch space, one entry per model. Four actions, unrolled: tables of any other
    number are :func:`decide_any`'s."""
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


@njit(cache=True, inline="always")
def decide_any(
    loglik: FloatArray, tables: Tables, s: int, z: FloatArray, n_actions: int
) -> tuple[float, float]:  # pragma: no cover - compiled
    """:func:`decide` for any number of actions (a building of several floors: six), the KL
    times log 4 / log A (``AdviceTables.kl_scale``): ``Advisor._divergence_any``'s
    operations in its order."""
    _, log_weights, probs, theta, neg_entropy = tables
    tot = posterior(loglik, log_weights, z)
    for m in range(loglik.shape[0]):  # P(M | H), once each (z is scratch)
        z[m] = z[m] / tot
    b = s * n_actions
    p0 = z[0]
    cross = 0.0
    for a in range(n_actions):
        mix = p0 * probs[0, b + a]  # the mixture P(a | s, H), eq. (4)
        for m in range(1, loglik.shape[0]):
            mix += z[m] * probs[m, b + a]
        if a == 0:
            cross = theta[b] * math.log(mix)
        else:
            cross += theta[b + a] * math.log(mix)
    kl = neg_entropy[s] - cross  # eq. (6)
    if not kl > 0.0:  # as ``kl if kl > 0.0 else 0.0``
        return 0.0, p0
    return kl * (math.log(4.0) / math.log(float(n_actions))), p0


@njit(cache=True)
def decide_any_call(
    loglik: FloatArray, tables: Tables, s: int, z: FloatArray, n_actions: int
) -> tuple[float, float]:  # pragma: no cover - compiled
    """:func:`decide_any` as a call (as :func:`decide_call`)."""
    return decide_any(loglik, tables, s, z, n_actions)


@njit(cache=True)
def decide_call(
    loglik: FloatArray, tables: Tables, s: int, z: FloatArray
) -> tuple[float, float]:  # pragma: no cover - compiled
    """:func:`decide` as a call, for long loops: inlined into the episode loop, it made that
    loop about a fifth slower (measured), where the short stream loop gains from inlining.
    Four actions (:func:`decide_any` for the others)."""
    return decide(loglik, tables, s, z)


@njit(cache=True)
def push(
    ring: FloatArray, loglik: FloatArray, pos: int, steps: int, period: int,
    log_probs: FloatArray, s: int, a: int, n_actions: int,
) -> int:  # pragma: no cover - compiled  # fmt: skip
    """Add (s, a) to the window ring (M, W); returns the new position. ``steps`` counts the
    pairs appended, this one included; every ``period`` pairs (at a wrap) the sums are
    recomputed exactly. ``n_actions``: the tables' A (pairs are keyed s * A + a)."""
    k = s * n_actions + a
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
    """``GoalAwareAdvisor.decide``: fills ``theta_w`` (A,) with theta^w_s and returns
    (KL[theta^w_s || P(M1 | H) theta^w_s + sum_m>1 P(M | H) P(A | s, M)], P(M1 | H)), the KL
    times log 4 / log A for A other than 4 (``AdviceTables.kl_scale``)."""
    _, alpha0, unknown, counts, _ = goals
    n_goals = w.shape[0]
    n_actions = theta_w.shape[0]
    b = s * n_actions
    total = 0.0
    for a in range(n_actions):
        dot = 0.0
        for g in range(n_goals):
            dot += w[g] * counts[b + a, g]
        theta_w[a] = alpha0 + unknown[b + a] + n_goals * dot
        total += theta_w[a]
    for a in range(n_actions):
        theta_w[a] = theta_w[a] / total
    _, log_weights, probs, _, _ = tables
    tot = posterior(loglik, log_weights, z)
    p0 = z[0] / tot
    kl = 0.0
    for a in range(n_actions):
        mix = p0 * theta_w[a]
        for m in range(1, loglik.shape[0]):
            mix += z[m] / tot * probs[m, b + a]
        kl += theta_w[a] * (math.log(theta_w[a]) - math.log(mix))
    if not kl > 0.0:  # as ``kl if kl > 0.0 else 0.0``
        return 0.0, p0
    if n_actions != 4:
        kl = kl * (math.log(4.0) / math.log(float(n_actions)))
    return kl, p0


# ---- the service's batches: the window as pair keys -------------------------------------------
@njit(cache=True)
def observe_stream(
    window: tuple[KeyArray, ByteArray, FloatArray],
    loglik: FloatArray,
    pos: int,
    steps: int,
    period: int,
    tables: Tables,
    kappa: float,
    count: int,
    benefit: float,
    cap: int,
    moves: tuple[IntArray, IntArray, IntArray],
    out: tuple[FloatArray, FloatArray, BoolArray, IntArray, FloatArray],
) -> tuple[int, int, float, int]:  # pragma: no cover - compiled
    """:func:`stream_loop` with the tables' number of actions A: four, a constant in the loop
    compiled for it, or any other. (A number read from the tables in the loop made one-floor
    streams 6-7% slower, with or without a branch on it there: docs/PERFORMANCE.md.)"""
    n_actions = tables[3].shape[0] // tables[4].shape[0]  # theta (S*A,), neg_entropy (S,)
    if n_actions == 4:
        return stream_loop(
            window, loglik, pos, steps, period, tables, kappa, count, benefit, cap, moves, out, 4
        )
    if n_actions == 6:
        return stream_loop(
            window, loglik, pos, steps, period, tables, kappa, count, benefit, cap, moves, out, 6
        )
    return stream_loop(
        window, loglik, pos, steps, period, tables, kappa, count, benefit, cap, moves, out,
        n_actions,
    )  # fmt: skip


@njit(cache=True, inline="always")
def stream_loop(
    window: tuple[KeyArray, ByteArray, FloatArray],
    loglik: FloatArray,
    pos: int,
    steps: int,
    period: int,
    tables: Tables,
    kappa: float,
    count: int,
    benefit: float,
    cap: int,
    moves: tuple[IntArray, IntArray, IntArray],
    out: tuple[FloatArray, FloatArray, BoolArray, IntArray, FloatArray],
    n_actions: int,
) -> tuple[int, int, float, int]:  # pragma: no cover - compiled
    """``Advisor.observe`` for each (s, a, s'), accounting as ``Advisor.decide``.

    The window is (pair keys s * A + a, -1 where empty; 1 where a pair's value was kept in
    ``old`` because the tables changed since it was added; those values): a leaving pair is
    subtracted with the value the core stored, and the exact re-sum (after ``steps`` +
    i + 1 pairs, a multiple of ``period``, at a wrap) sums the values the core's ring holds,
    in its order. A decision advises only while the advice count is below ``cap``. Fills
    ``out`` (kl, p_normal, advise, count, benefit); returns (position, advice count, benefit,
    kept values that left the window)."""
    keys, kept, old = window
    log_probs = tables[0]
    states, actions, next_states = moves
    kl_out, p_out, advise_out, count_out, benefit_out = out
    size = keys.shape[0]
    n_models = loglik.shape[0]
    z = np.empty(n_models)
    gone = 0
    for i in range(states.shape[0]):
        k = states[i] * n_actions + actions[i]
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
        if n_actions == 4:  # a constant in the loop compiled for four
            kl, p0 = decide(loglik, tables, next_states[i], z)
        else:
            kl, p0 = decide_any(loglik, tables, next_states[i], z, n_actions)
        if kl >= kappa and count < cap:
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
    keys: KeyArray, kept: ByteArray, old: FloatArray, log_probs: FloatArray
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


# ---- the service's goal-aware sessions: both windows as pair keys -------------------------------
@njit(cache=True, inline="always")
def goal_push(
    window: tuple[KeyArray, ByteArray, FloatArray],
    goal_window: tuple[ByteArray, FloatArray],
    loglik: FloatArray, goal_ll: FloatArray, alive: BoolArray, pos: int, steps: int,
    period: int, beta: float, log_probs: FloatArray, goals: GoalTables, s: int, a: int,
) -> tuple[int, int, int]:  # pragma: no cover - compiled  # fmt: skip
    """``GoalAwareAdvisor.append`` on windows of pair keys: the models' window as
    :func:`observe_stream` keeps it, the goal ruled out where the explorer stood on one, and
    (beta > 0) each goal's log theta^g of the pairs, read from the shared ``goals`` tables
    (values kept in ``goal_window``'s (G, W) array for pairs added under older ones). ``steps``
    counts the pairs appended, this one included. Returns (position, model values and goal
    values that left the window)."""
    keys, kept, old = window
    goal_kept, goal_old = goal_window
    goal_of_state, _, unknown, _, goal_log_theta = goals
    k = s * (unknown.shape[0] // goal_of_state.shape[0]) + a  # unknown counts: (S*A,)
    leaving = keys[pos]
    n_models = loglik.shape[0]
    gone = 0
    if leaving < 0:  # the core's ring holds 0.0 until the window fills
        for m in range(n_models):
            loglik[m] += log_probs[m, k] - 0.0
    elif kept[pos]:
        for m in range(n_models):
            loglik[m] += log_probs[m, k] - old[m, pos]
        kept[pos] = 0
        gone = 1
    else:
        for m in range(n_models):
            loglik[m] += log_probs[m, k] - log_probs[m, leaving]
    gi = goal_of_state[s]
    if gi >= 0:  # it stood on this goal and went on: not its goal
        alive[gi] = False
    goal_gone = 0
    n_goals = goal_ll.shape[0]
    if beta > 0.0:  # beta = 0 never reads the per-goal window
        if leaving < 0:
            for g in range(n_goals):
                goal_ll[g] += goal_log_theta[k, g] - 0.0
        elif goal_kept[pos]:
            for g in range(n_goals):
                goal_ll[g] += goal_log_theta[k, g] - goal_old[g, pos]
            goal_kept[pos] = 0
            goal_gone = 1
        else:
            for g in range(n_goals):
                goal_ll[g] += goal_log_theta[k, g] - goal_log_theta[leaving, g]
    keys[pos] = k
    pos += 1
    size = keys.shape[0]
    if pos == size:
        pos = 0
        if steps % period == 0:
            ring = np.empty(size)
            for m in range(n_models):
                for p in range(size):
                    ring[p] = old[m, p] if kept[p] else log_probs[m, keys[p]]
                loglik[m] = fsum(ring)
            if beta > 0.0:
                for g in range(n_goals):
                    for p in range(size):
                        ring[p] = goal_old[g, p] if goal_kept[p] else goal_log_theta[keys[p], g]
                    goal_ll[g] = fsum(ring)
    return pos, gone, goal_gone


@njit(cache=True)
def goal_append(
    window: tuple[KeyArray, ByteArray, FloatArray],
    goal_window: tuple[ByteArray, FloatArray],
    loglik: FloatArray, goal_ll: FloatArray, alive: BoolArray, pos: int, steps: int,
    period: int, beta: float, log_probs: FloatArray, goals: GoalTables, s: int, a: int,
) -> tuple[int, int, int]:  # pragma: no cover - compiled  # fmt: skip
    """:func:`goal_push` as a call (one event)."""
    return goal_push(
        window, goal_window, loglik, goal_ll, alive, pos, steps, period, beta, log_probs, goals,
        s, a,
    )  # fmt: skip


@njit(cache=True)
def goal_decision(
    loglik: FloatArray, tables: Tables, goals: GoalTables, goal_ll: FloatArray,
    alive: BoolArray, beta: float, s: int, theta_w: FloatArray,
) -> tuple[float, float]:  # pragma: no cover - compiled  # fmt: skip
    """``GoalAwareAdvisor.decide``'s numbers for the explorer now at ``s``: the goal
    posterior, theta^w_s into ``theta_w``, (KL, P(M1 | H))."""
    w = np.empty(goal_ll.shape[0])
    goal_posterior(goal_ll, alive, beta, w)
    return goal_decide(loglik, tables, goals, w, s, theta_w, np.empty(loglik.shape[0]))


@njit(cache=True)
def goal_stream(
    window: tuple[KeyArray, ByteArray, FloatArray],
    goal_window: tuple[ByteArray, FloatArray],
    sums: tuple[FloatArray, FloatArray, BoolArray],
    pos: int,
    steps: int,
    period: int,
    beta: float,
    tables: Tables,
    goals: GoalTables,
    kappa: float,
    count: int,
    benefit: float,
    cap: int,
    moves: tuple[IntArray, IntArray, IntArray],
    out: tuple[FloatArray, FloatArray, BoolArray, IntArray, FloatArray, FloatArray],
) -> tuple[int, int, float, int, int]:  # pragma: no cover - compiled
    """``GoalAwareAdvisor.observe`` for each (s, a, s'): :func:`goal_push`, then the goal
    posterior and :func:`goal_decide`. ``sums`` is (log P(H | M) per model, log P(H | theta^g)
    per goal, goals not ruled out). Fills ``out`` (kl, p_normal, advise, count, benefit, the
    advice theta^w of each decision (n, A)); returns (position, advice count, benefit, model
    values and goal values that left the window)."""
    loglik, goal_ll, alive = sums
    states, actions, next_states = moves
    kl_out, p_out, advise_out, count_out, benefit_out, rows = out
    w = np.empty(goal_ll.shape[0])
    z = np.empty(loglik.shape[0])
    n_actions = rows.shape[1]
    theta_w = np.empty(n_actions)
    gone = 0
    goal_gone = 0
    for i in range(states.shape[0]):
        pos, g1, g2 = goal_push(
            window, goal_window, loglik, goal_ll, alive, pos, steps + i + 1, period, beta,
            tables[0], goals, states[i], actions[i],
        )  # fmt: skip
        gone += g1
        goal_gone += g2
        goal_posterior(goal_ll, alive, beta, w)
        kl, p0 = goal_decide(loglik, tables, goals, w, next_states[i], theta_w, z)
        if kl >= kappa and count < cap:
            count += 1
            benefit += kl
            advise_out[i] = True
        else:
            advise_out[i] = False
        for a in range(n_actions):
            rows[i, a] = theta_w[a]
        kl_out[i] = kl
        p_out[i] = p0
        count_out[i] = count
        benefit_out[i] = benefit
    return pos, count, benefit, gone, goal_gone


# ---- guide: leading lost explorers to a destination ---------------------------------------------
# A compiled call that takes arrays pays a reference count on each (twice), which costs more
# than a destination's arithmetic: the loops over destinations read the arrays in one function,
# their helpers take scalars, and the per-decision functions are inlined into their callers
# (numba's inline="always"). benchmarks/bench_guide.py measures it.
@njit(cache=True, inline="always")
def guide_open(
    next_state: IntArray, n_open: IntArray, s: int, out: FloatArray, k: int
) -> None:  # pragma: no cover - compiled
    """``GuideMap.open_policy``: uniform over the open moves of ``s`` into ``out`` (k,)."""
    n, mask = n_open[s], guide_open_moves(next_state, s, k)
    for a in range(k):
        out[a] = guide_open_share(n, mask, a, k)


@njit(cache=True, inline="always")
def guide_open_moves(next_state: IntArray, s: int, k: int) -> int:  # pragma: no cover
    """The open moves of ``s`` among the first ``k`` as bits (bit a: move a leaves ``s``)."""
    mask = 0
    for a in range(k):
        if next_state[s, a] != s:
            mask |= 1 << a
    return mask


@njit(cache=True)
def guide_open_share(n: int, mask: int, a: int, k: int) -> float:  # pragma: no cover
    """``GuideMap.open_policy`` of move ``a`` at a state with ``n`` open moves, ``mask``, of
    ``k`` actions."""
    return 1.0 / k if n == 0 else (1.0 / n if (mask >> a) & 1 == 1 else 0.0)


@njit(cache=True)
def guide_own_moves(dr: int, dc: int, mask: int) -> tuple[int, int]:  # pragma: no cover
    """``GuideMap.compass_moves``: up to two moves (-1: none) of someone heading ``dr`` rows
    and ``dc`` columns away as the crow flies, from a state whose open moves are ``mask``
    (:func:`guide_open_moves`). Scalars only, so the loops over destinations that call it
    stay one compiled loop."""
    vert = 0 if dr < 0 else 2
    horiz = 1 if dc > 0 else 3
    v_ok = dr != 0 and (mask >> vert) & 1 == 1
    h_ok = dc != 0 and (mask >> horiz) & 1 == 1
    if abs(dr) == abs(dc):
        if v_ok:
            return vert, (horiz if h_ok else -1)
        return (horiz if h_ok else -1), -1
    if abs(dr) > abs(dc):
        return (vert if v_ok else (horiz if h_ok else -1)), -1
    return (horiz if h_ok else (vert if v_ok else -1)), -1


@njit(cache=True, inline="always")
def guide_compass(table: ByteArray, s: int, g: int) -> tuple[int, int]:  # pragma: no cover
    """``GuideMap.compass_moves`` of someone at ``s`` heading for destination ``g``, as
    ``compass_table`` keeps them: up to two moves (-1: none)."""
    c = int(table[s, g])
    return (c & 15) - 1, (c >> 4) - 1


@njit(cache=True, inline="always")
def guide_fill_rows(
    gmap: GuideArrays, goals: IntArray, s: int, rows: FloatArray, k: int
) -> None:  # pragma: no cover - compiled  # fmt: skip
    """Fill ``rows`` (2 G, A) with every destination's pi_g(. | s) (``GuideMap.policy``),
    then its c_g(. | s) (``GuideMap.compass``). One loop, the arrays read in it (a compiled
    call per destination that takes arrays costs more than the arithmetic)."""
    next_state, n_open, _, dist, _, counts, _, _, _, table, _, _, _ = gmap
    n_goals = goals.shape[0]
    n = n_open[s]
    mask = guide_open_moves(next_state, s, k)
    for g in range(n_goals):
        d = dist[g, s]  # pi_g: the shortest moves, weighted 1 + the experts' count
        if d > 0:
            tot = 0.0
            for a in range(k):
                if dist[g, next_state[s, a]] == d - 1:
                    rows[g, a] = 1.0 + counts[g, s * k + a]
                    tot += rows[g, a]
                else:
                    rows[g, a] = 0.0
            for a in range(k):
                rows[g, a] = rows[g, a] / tot
        else:
            for a in range(k):
                rows[g, a] = guide_open_share(n, mask, a, k)
        # c_g: uniform over its own moves, the open moves where it has none
        m0, m1 = guide_compass(table, s, g)
        r = n_goals + g
        for a in range(k):
            if m0 < 0:
                rows[r, a] = guide_open_share(n, mask, a, k)
            else:
                rows[r, a] = (1.0 / (1 if m1 < 0 else 2)) if a in (m0, m1) else 0.0


@njit(cache=True, inline="always")
def guide_route_rows(
    gmap: GuideArrays, goals: IntArray, alive: BoolArray, any_alive: bool, s: int,
    pcs: FloatArray, k: int,
) -> None:  # pragma: no cover - compiled  # fmt: skip
    """``GuideMap.compass_route``: pc_g(. | s) into ``pcs[g]`` for every destination g not
    ruled out (every one when none is left): the open moves after which the fewest moves it
    would not make by itself remain, its own moves first (at g, or where g cannot be
    reached, the open moves)."""
    next_state, n_open, _, _, _, _, detour, _, _, table, _, _, _ = gmap
    n = n_open[s]
    mask = guide_open_moves(next_state, s, k)
    for g in range(goals.shape[0]):
        if not (alive[g] or not any_alive):
            continue
        goal = goals[g]
        if s == goal or detour[g, s] < 0:
            for a in range(k):
                pcs[g, a] = guide_open_share(n, mask, a, k)
            continue
        m0, m1 = guide_compass(table, s, g)
        best = -1
        for a in range(k):  # pcs[g, a]: moves it would not make, counting this one (-1: shut)
            pcs[g, a] = -1.0
            t = next_state[s, a]
            if t != s:
                own = a in (m0, m1)
                cost = detour[g, t] + (0 if own else 1)
                pcs[g, a] = cost + (0.0 if own else 0.5)  # .5 marks a move it would not make
                if best < 0 or cost < best:
                    best = cost
        n_own = 0
        n_any = 0
        for a in range(k):
            if pcs[g, a] >= 0.0 and math.floor(pcs[g, a]) == best:
                n_any += 1
                if pcs[g, a] == best:
                    n_own += 1
        for a in range(k):
            c = pcs[g, a]
            if c >= 0.0 and math.floor(c) == best and (n_own == 0 or c == best):
                pcs[g, a] = 1.0 / (n_own if n_own > 0 else n_any)
            else:
                pcs[g, a] = 0.0


@njit(cache=True, inline="always")
def guide_append(
    gmap: GuideArrays, params: GuideParams, goals: IntArray, ll: FloatArray, alive: BoolArray,
    doubt: IntArray, s: int, a: int, advised: bool, advice: FloatArray, heading: int,
    pi: FloatArray, rows: FloatArray, known: bool, comply: FloatArray, came: int,
    n_actions: int,
) -> tuple[int, int]:  # pragma: no cover - compiled  # fmt: skip
    """``GuideAdvisor.append``: fade the evidence, add log P(a | s, k), rule out a destination
    the explorer stood on. ``goals`` holds each destination's state; ``advised``: the last
    decision, for ``s``, gave ``advice`` (A,); ``pi`` is scratch (A,). ``rows`` (2 G, A):
    every destination's pi_g(. | s), then its c_g(. | s), as :func:`guide_decide` leaves them
    in its scratch (:func:`guide_rows`); ``known``: they are already there for ``s`` (a
    decision for ``s`` came just before), else they are made here. ``comply``
    (:func:`guide_observe_compliance`) learns whether the explorer took the advice. ``came``:
    where the last move led on the map (-1: none); a destination is ruled out only where it
    can have led, or set aside (``doubt``, :func:`guide_rule_out`). ``n_actions``: the
    domain's (:func:`guide_stream`). Returns (the heading, where this move leads)."""
    lam, slack, bump = params[0], params[2], params[4]
    next_state = gmap[0]
    n_goals = alive.shape[0]
    guide_observe_compliance(params, comply, advised, advice, a, s, next_state[s, a])
    if not known:
        guide_fill_rows(gmap, goals, s, rows, n_actions)
    guide_open(next_state, gmap[1], s, pi, n_actions)
    lo = (1.0 - bump) * pi[a] + bump / n_actions
    # LO, LA and LS: their rule (bump 0), with a bump now and then
    o_lo = pi[a]
    o_la = guide_ahead(next_state, gmap[1], s, heading, a, 0.0, n_actions)
    o_ls = guide_straight(next_state, gmap[1], s, heading, a, 0.0, n_actions)
    if advised:  # lost or not, it takes the advice or its own rule, half each (L4 too)
        o_lo, o_la, o_ls = (
            0.5 * (o_lo + advice[a]),
            0.5 * (o_la + advice[a]),
            0.5 * (o_ls + advice[a]),
        )
    o_l4 = 0.5 * (1.0 / n_actions + advice[a]) if advised else 1.0 / n_actions
    ll[0] = lam * ll[0] + math.log(o_l4)  # L4: any action, or the advice half the time
    ll[1] = lam * ll[1] + math.log((1.0 - bump) * o_lo + bump / n_actions)
    last = ll.shape[0] - 1  # LA, then LS
    ll[last - 1] = lam * ll[last - 1] + math.log((1.0 - bump) * o_la + bump / n_actions)
    ll[last] = lam * ll[last] + math.log((1.0 - bump) * o_ls + bump / n_actions)
    for w in range(2):  # the left-hand (w = 0) and right-hand wall followers
        rule = guide_wall(next_state, s, heading, w)
        ind = 1.0 if a == rule else 0.0
        if advised:
            ind = 0.5 * (ind + advice[a])
        ll[2 + w] = lam * ll[2 + w] + math.log((1.0 - slack) * ind + slack * lo)
    for g in range(n_goals):
        pa = rows[g, a]
        ca = rows[n_goals + g, a]
        if advised:  # they take the advice or their own way, half each
            pa = 0.5 * (pa + advice[a])
            ca = 0.5 * (ca + advice[a])
        k = 4 + 3 * g
        ll[k] = lam * ll[k] + math.log((1.0 - slack) * pa + slack / n_actions)
        ll[k + 1] = lam * ll[k + 1] + math.log((1.0 - slack) * pa + slack * lo)
        ll[k + 2] = lam * ll[k + 2] + math.log((1.0 - slack) * ca + slack * lo)
    gi = gmap[4][s]
    if gi >= 0 and (came < 0 or came == s):  # a reading one cell off rules nothing out
        guide_rule_out(alive, doubt, gi)
    to = next_state[s, a]
    return (a if to != s and a < 4 else heading), to  # a heading: a compass move


@njit(cache=True, inline="always")
def guide_ahead(
    next_state: IntArray, n_open: IntArray, s: int, heading: int, a: int, bump: float, k: int
) -> float:  # pragma: no cover - compiled
    """LA's move (``GuideAdvisor._ahead(s)[a]``, with ``bump`` spread over all four as
    ``GuideAdvisor._bumped`` spreads LOST_BUMP): uniform over the open moves but back (against
    ``heading``) where another is open and it has moved, over the open moves otherwise."""
    n = n_open[s]
    back = (heading + 2) % 4
    if heading >= 0 and n > 1 and next_state[s, back] != s:
        o = 1.0 / (n - 1) if a != back and next_state[s, a] != s else 0.0
    elif n == 0:
        o = 1.0 / k
    else:
        o = 1.0 / n if next_state[s, a] != s else 0.0
    return (1.0 - bump) * o + bump / k


@njit(cache=True, inline="always")
def guide_straight(
    next_state: IntArray, n_open: IntArray, s: int, heading: int, a: int, bump: float, k: int
) -> float:  # pragma: no cover - compiled
    """LS's move (``GuideAdvisor._straight(s)[a]``, ``bump`` as in :func:`guide_ahead`): on
    along ``heading`` where it is open, else LA's."""
    if heading >= 0 and next_state[s, heading] != s:
        return (1.0 - bump) * (1.0 if a == heading else 0.0) + bump / k
    return guide_ahead(next_state, n_open, s, heading, a, bump, k)


@njit(cache=True)
def guide_rule_out(alive: BoolArray, doubt: IntArray, gi: int) -> None:
    """``GuideAdvisor._rule_out``: destination ``gi`` stood on and left; doubt 1 set aside,
    2 brought back."""
    if alive[gi]:
        alive[gi] = False
        if doubt[gi] == 0:
            doubt[gi] = 1
    elif doubt[gi] == 1:
        doubt[gi] = 0  # seen on it a second time: ruled out
    any_alive = False
    for g in range(alive.shape[0]):
        any_alive = any_alive or alive[g]
    if not any_alive:  # once it passed every one, it is bound elsewhere
        for g in range(alive.shape[0]):
            if doubt[g] == 1:
                alive[g] = True
                doubt[g] = 2


@njit(cache=True, inline="always")
def guide_observe_compliance(
    params: GuideParams, comply: FloatArray, advised: bool, advice: FloatArray, a: int,
    s: int, to: int,
) -> None:  # pragma: no cover - compiled  # fmt: skip
    """``GuideAdvisor._observe_compliance`` of move ``a`` at ``s``, leading to ``to``.
    ``comply`` (L + 13,): the log-likelihood of each compliance level (j + 1/2) / L, the
    chance that the explorer's own move is the last decision's advice, the decisions since
    the last piece of advice, whether advice is held back (1.0: from P(compliance < IGNORED)
    >= SURE until it is below RELEASE); the last chain of pieces taken in a row (where it
    began, -1: none open; its length k; the explorer's own moves since: undone if they lead
    back there within k moves, or if a piece is taken where the first of them took back the
    chain's last piece, else kept); how many chains in a row were undone, where the last
    began (-1: none) and whether the explorer has left it since by its own moves, no piece
    taken since (back there by its own moves, none undoing a chain, the run is forgotten);
    the last decision's advice (theta's favourite move, -1: none) and whether every move
    since the last piece was that of the decision before it; the advice budget; where the
    last piece taken was given (-1: none)."""
    fade, ignored, sure, release = params[6], params[7], params[8], params[9]
    n = params[11]
    took = False  # the advised move, if advice was given
    if advised:
        best = 0
        for b in range(advice.shape[0]):
            if advice[b] > advice[best]:
                best = b
        took = a == best
    # on the way it is led: it took the piece, or made the move the advice would have been
    on = took if advised else comply[n + 10] != 0.0 and a == int(comply[n + 9])
    comply[n + 10] = 1.0 if on else 0.0
    undid = False
    if took and to != s:  # a piece taken
        if comply[n + 3] >= 0.0 and comply[n + 5] == 1.0 and s == comply[n + 12]:
            # given where its first own move after the chain took back the chain's last
            # piece: it was undoing the chain, which the piece interrupts
            comply[n + 6] += 1.0
            comply[n + 7] = float(s)
            comply[n + 3] = -1.0
        comply[n + 12] = float(s)
        if comply[n + 3] < 0.0 or comply[n + 5] > 0.0:  # the first of a chain
            comply[n + 3] = float(s)
            comply[n + 4] = 1.0
            comply[n + 5] = 0.0
        else:
            comply[n + 4] += 1.0
    elif comply[n + 3] >= 0.0:  # its own move after a chain: kept, or undone?
        comply[n + 5] += 1.0
        if to == int(comply[n + 3]):  # back where the chain began: undone
            comply[n + 6] += 1.0
            comply[n + 7] = comply[n + 3]
            comply[n + 8] = 0.0
            comply[n + 3] = -1.0
            undid = True
        elif comply[n + 5] >= comply[n + 4]:  # as many moves as it took: kept
            comply[n + 6] = 0.0
            comply[n + 7] = -1.0
            comply[n + 3] = -1.0
    if comply[n + 7] >= 0.0:  # where it undid the last: does it circle there?
        if took:
            comply[n + 8] = 0.0  # led: no way of its own since
        elif not undid and to != int(comply[n + 7]):
            comply[n + 8] = 1.0  # its own move away from there
        elif not undid and comply[n + 8] != 0.0:  # and its own moves back there: it
            comply[n + 6] = 0.0  # circles rather than goes its own way
            comply[n + 7] = -1.0
            comply[n + 8] = 0.0
    if not advised:
        comply[n + 1] += 1.0
        return
    comply[n + 1] = 1.0
    chance = min(max(comply[n], params[12]), params[13])
    for j in range(n):
        c = (j + 0.5) / n
        lik = c + (1.0 - c) * chance if took else (1.0 - c) * (1.0 - chance)
        comply[j] = fade * comply[j] + math.log(lik)
    low = guide_compliance_below(comply[:n], ignored)
    if low >= sure:  # it ignores advice: hold it back
        comply[n + 2] = 1.0
    elif low < release:  # it takes advice (again)
        comply[n + 2] = 0.0
    # a piece not taken by one that takes only some (PARTLY, params[24]) is given back
    if not took and guide_compliance_below(comply[:n], params[24]) >= 0.5:
        comply[n + 11] = min(params[22], comply[n + 11] + 1.0)


@njit(cache=True)
def guide_compliance_state(params: GuideParams) -> FloatArray:  # pragma: no cover - compiled
    """``compliance_state``: no advice yet (``COMPLY_LEVELS`` levels, chance 1/2, ``BACKOFF``
    decisions since the last piece, not held back, no chain of taken pieces open, no run of
    undone chains, no decision yet, not led, one piece of the advice budget saved, no piece
    taken yet)."""
    n = params[11]
    comply = np.zeros(n + 13)
    comply[n] = 0.5
    comply[n + 1] = params[10]
    comply[n + 3] = -1.0
    comply[n + 7] = -1.0
    comply[n + 9] = -1.0
    comply[n + 11] = 1.0  # one piece of the advice budget saved
    comply[n + 12] = -1.0  # no piece taken yet
    return comply


@njit(cache=True)
def guide_compliance_below(levels: FloatArray, bound: float) -> float:  # pragma: no cover
    """``compliance_below``: the posterior probability that the explorer's compliance is
    below ``bound``, from the log-likelihood of each level."""
    n = levels.shape[0]
    mx = levels[0]
    for j in range(1, n):
        if levels[j] > mx:
            mx = levels[j]
    low = 0.0
    tot = 0.0
    for j in range(n):
        w = math.exp(levels[j] - mx)
        if (j + 0.5) / n < bound:
            low += w
        tot += w
    return low / tot


@njit(cache=True)
def guide_wall(next_state: IntArray, s: int, heading: int, w: int) -> int:  # pragma: no cover
    """The move of a wall follower at ``s`` heading ``heading`` (-1: none yet, then it goes
    its first open way, N E S W): the left hand's (w = 0: left, straight, right, back) or the
    right hand's (w = 1: right, straight, left, back); -1 where every way is shut."""
    h = 0 if heading < 0 else heading
    for i in range(4):
        if heading < 0:
            turn = i
        elif w == 0:
            turn = (3, 0, 1, 2)[i]
        else:
            turn = (1, 0, 3, 2)[i]
        a = (h + turn) % 4
        if next_state[s, a] != s:
            return a
    return -1


@njit(cache=True, inline="always")
def guide_drift(gmap: GuideArrays, t: int, s: int, k: int) -> float:  # pragma: no cover
    """``GuideMap.drift``: the mean change of the BFS distance to destination ``t`` over the
    open moves of ``s`` (0 at ``t``, where it cannot be reached, or with no open move)."""
    next_state, dist = gmap[0], gmap[3]
    here = dist[t, s]
    if here <= 0:
        return 0.0
    n = 0
    change = 0
    for a in range(k):
        u = next_state[s, a]
        if u != s:
            n += 1
            change += dist[t, u] - here
    return change / n if n > 0 else 0.0


@njit(cache=True, inline="always")
def guide_heading_drift(
    gmap: GuideArrays, t: int, s: int, heading: int, w_la: float, w_ls: float, k: int
) -> float:  # pragma: no cover - compiled
    """``GuideAdvisor._heading_drift``: the mean change of the BFS distance to destination
    ``t`` of the explorer's own move at ``s`` as LA and LS (weights ``w_la``, ``w_ls``) make
    it from ``heading`` (0 at ``t`` or where it cannot be reached)."""
    next_state, n_open, dist = gmap[0], gmap[1], gmap[3]
    here = dist[t, s]
    if here <= 0:
        return 0.0
    ea, es = 0.0, 0.0
    for a in range(k):
        c = dist[t, next_state[s, a]] - here
        ea += guide_ahead(next_state, n_open, s, heading, a, 0.0, k) * c
        es += guide_straight(next_state, n_open, s, heading, a, 0.0, k) * c
    return (w_la * ea + w_ls * es) / (w_la + w_ls)


@njit(cache=True, inline="always")
def guide_lead_after(
    gmap: GuideArrays, t: int, s: int, heading: int, a: int
) -> float:  # pragma: no cover - compiled
    """``GuideAdvisor._lead_after``: the lead value of destination ``t`` where action ``a``
    at ``s`` leaves the explorer (heading ``a`` if it moved by a compass move, else
    ``heading``)."""
    u = gmap[0][s, a]
    return float(gmap[12][t, u, a if u != s and a < 4 else heading])


@njit(cache=True, inline="always")
def guide_lead_gain(
    gmap: GuideArrays, t: int, s: int, heading: int, advice: int, w_la: float, w_ls: float,
    k: int,
) -> float:  # pragma: no cover - compiled  # fmt: skip
    """``GuideAdvisor._lead_gain``: the moves a piece leading by ``advice`` saves at ``s``
    (the lead values of destination ``t``): the mean over LA's and LS's own move from
    ``heading`` (weights ``w_la``, ``w_ls``) of the value where it leads, less the advice's."""
    next_state, n_open = gmap[0], gmap[1]
    if gmap[3][t, s] <= 0:
        return 0.0
    ea, es = 0.0, 0.0
    for a in range(k):
        after = guide_lead_after(gmap, t, s, heading, a)
        pa = guide_ahead(next_state, n_open, s, heading, a, 0.0, k)
        if pa > 0.0:
            ea += pa * after
        ps = guide_straight(next_state, n_open, s, heading, a, 0.0, k)
        if ps > 0.0:
            es += ps * after
    led = guide_lead_after(gmap, t, s, heading, advice)
    return (w_la * ea + w_ls * es) / (w_la + w_ls) - led


@njit(cache=True, inline="always")
def guide_lead_pick(
    gmap: GuideArrays, t: int, s: int, heading: int, pick: int, k: int
) -> int:  # pragma: no cover - compiled
    """``GuideAdvisor._lead_pick``: the shortest move towards ``t`` at ``s`` after which the
    lead value is least, from ``heading``; ``pick`` where it is as low as any."""
    next_state, dist = gmap[0], gmap[3]
    here = dist[t, s]
    if here <= 0:
        return pick
    low = guide_lead_after(gmap, t, s, heading, pick)
    for a in range(k):
        u = next_state[s, a]
        if u != s and dist[t, u] == here - 1:
            after = guide_lead_after(gmap, t, s, heading, a)
            if after < low:
                low, pick = after, a
    return pick


@njit(cache=True, nogil=True)
def guide_lead_values(
    next_state: IntArray, n_open: IntArray, dist: IntArray, price: float, tol: float,
    most: int,
) -> Float32Array:  # pragma: no cover - compiled  # fmt: skip
    """``app.advice.guide.lead_values``, the same sweeps: (G, S, 4) float32, for each
    destination, state and heading the mean moves to it of a walker that never turns back but
    in a dead end (LA's rule), led at a cost of ``price`` moves a piece wherever a piece is
    worth that."""
    n_goals, n_states = dist.shape
    k = next_state.shape[1]
    out = np.zeros((n_goals, n_states, 4), dtype=np.float32)
    v = np.zeros((n_states, 4))
    # a state's moves that move, in the order of the actions, read once a state, not once a
    # heading: where each leads, whether it is a shortest move, and (a compass move keeps its
    # own heading; a ride, the walker's) its value; each heading's move not taken (back)
    nb = np.zeros(k, dtype=np.int64)
    act = np.zeros(k, dtype=np.int64)
    near = np.zeros(k, dtype=np.bool_)
    w = np.zeros(k)
    skip = np.zeros(4, dtype=np.int64)
    own = np.zeros(4)
    n = np.zeros(4, dtype=np.int64)
    for g in range(n_goals):
        dt = dist[g]
        order = np.argsort(dt, kind="mergesort")
        first = 0  # the destination and the states it cannot be reached from come first
        while first < n_states and dt[order[first]] <= 0:
            first += 1
        for c in range(n_states):  # from above: led at every move
            for h in range(4):
                v[c, h] = (1.0 + price) * dt[c] if dt[c] > 0 else 0.0
        for _ in range(most):
            change = 0.0
            for i in range(first, n_states):
                c = order[i]
                here = dt[c]
                if n_open[c] == 0:
                    continue
                m, rides = 0, False
                for a in range(k):
                    u = next_state[c, a]
                    if u != c:
                        nb[m], act[m], near[m] = u, a, dt[u] == here - 1
                        if a < 4:
                            w[m] = v[u, a]
                        rides = rides or a >= 4
                        m += 1
                for h in range(4):  # never back, but in a dead end
                    back = (h + 2) % 4
                    skip[h] = back if n_open[c] > 1 and next_state[c, back] != c else -1
                    own[h], n[h] = 0.0, 0
                led = np.inf
                if not rides:  # each heading's sum in the order of the actions, in one pass
                    for j in range(m):
                        if near[j] and w[j] < led:
                            led = w[j]
                        for h in range(4):
                            if act[j] != skip[h]:
                                own[h] += w[j]
                                n[h] += 1
                for h in range(4):
                    if rides:  # a ride's value is the walker's heading's
                        led = np.inf
                        for j in range(m):
                            x = w[j] if act[j] < 4 else v[nb[j], h]
                            if near[j] and x < led:
                                led = x
                            if act[j] != skip[h]:
                                own[h] += x
                                n[h] += 1
                    best = 1.0 + own[h] / n[h]
                    if 1.0 + price + led < best:
                        best = 1.0 + price + led
                    if abs(best - v[c, h]) > change:
                        change = abs(best - v[c, h])
                    v[c, h] = best
            if change < tol:
                break
        out[g] = v.astype(np.float32)
    return out


@njit(cache=True, inline="always")
def guide_walk_arrivals(
    dist: IntArray, goals: IntArray, order: IntArray, s: int
) -> int:  # pragma: no cover - compiled
    """The sum of the arrivals of a walk from ``s`` along ``order`` (destinations by index)
    at them: ``sum(app.domain.tours.arrivals_along(...))``."""
    t, total, at = 0, 0, s
    for j in range(order.shape[0]):
        t += dist[order[j], at]
        total += t
        at = goals[order[j]]
    return total


@njit(cache=True)
def guide_searched_order(
    dist: IntArray, goals: IntArray, todo: IntArray, s: int, rounds: int
) -> IntArray:  # pragma: no cover - compiled
    """``app.domain.tours.searched_order`` for a walk from ``s`` through ``todo``
    (destinations by index, ascending): the nearest-first order (ties to the lower index),
    improved while a segment reversed or one of 1-3 destinations moved elsewhere lowers
    :func:`guide_walk_arrivals`, each change taken as soon as found, at most ``rounds``
    rounds."""
    n = todo.shape[0]
    order = np.empty(n, dtype=np.int64)
    used = np.zeros(n, dtype=np.bool_)
    at = s
    for i in range(n):
        pick = -1
        for j in range(n):
            if not used[j] and (pick < 0 or dist[todo[j], at] < dist[todo[pick], at]):
                pick = j
        used[pick] = True
        order[i] = todo[pick]
        at = goals[todo[pick]]
    best = guide_walk_arrivals(dist, goals, order, s)
    cand = np.empty(n, dtype=np.int64)
    rest = np.empty(n, dtype=np.int64)
    for _ in range(rounds):
        before = best
        for i in range(n):  # a segment reversed
            for j in range(i + 1, n):
                for m in range(n):
                    cand[m] = order[i + j - m] if i <= m <= j else order[m]
                c = guide_walk_arrivals(dist, goals, cand, s)
                if c < best:
                    order[:] = cand
                    best = c
        for size in range(1, 4):  # 1-3 destinations moved elsewhere
            for i in range(n - size + 1):
                r = 0
                for m in range(n):
                    if m < i or m >= i + size:
                        rest[r] = order[m]
                        r += 1
                for k in range(r + 1):
                    for m in range(n):
                        if m < k:
                            cand[m] = rest[m]
                        elif m < k + size:
                            cand[m] = order[i + m - k]
                        else:
                            cand[m] = rest[m - size]
                    c = guide_walk_arrivals(dist, goals, cand, s)
                    if c < best:
                        order[:] = cand
                        best = c
                        break
        if best == before:
            break
    return order


@njit(cache=True)
def guide_first_of_tour(
    dist: IntArray,
    goals: IntArray,
    alive: BoolArray,
    any_alive: bool,
    s: int,
    max_tour: int,
    latency: bool,
    max_searched: int,
    rounds: int,
) -> int:  # pragma: no cover - compiled
    """``GuideMap.first_of_tour``: the first destination of the shortest walk from ``s``
    (with ``latency``, of the walk with the least sum of arrivals) through every destination
    not ruled out (all of them when ``any_alive`` is false) that ``s`` reaches; exact for up to
    ``max_tour`` of them; beyond, up to ``max_searched``, :func:`guide_searched_order`'s first (at
    most ``rounds`` rounds, whatever ``latency``); the nearest beyond that; -1 if none."""
    todo = np.empty(goals.shape[0], dtype=np.int64)
    n = 0
    for g in range(goals.shape[0]):
        if (alive[g] or not any_alive) and dist[g, s] >= 0:
            todo[n] = g
            n += 1
    if n == 0:
        return -1
    if n > max_searched:
        first = int(todo[0])
        for j in range(1, n):
            if dist[todo[j], s] < dist[first, s]:
                first = int(todo[j])
        return first
    if n > max_tour:
        return int(guide_searched_order(dist, goals, todo[:n], s, rounds)[0])
    full = (1 << n) - 1
    inf = 1 << 60
    rest = np.full((full + 1, n), inf, dtype=np.int64)
    count = np.zeros(full + 1, dtype=np.int64)  # destinations in each mask
    for mask in range(1, full + 1):
        count[mask] = count[mask >> 1] + (mask & 1)
        for j in range(n):
            if not mask & (1 << j):
                continue
            others = mask & ~(1 << j)
            if others == 0:
                rest[mask, j] = 0
                continue
            here = goals[todo[j]]
            best = inf
            for k in range(n):
                if others & (1 << k):
                    c = (count[others] if latency else 1) * dist[todo[k], here]
                    c += rest[others, k]
                    if c < best:
                        best = c
            rest[mask, j] = best
    first = -1
    first_cost = inf
    for j in range(n):
        c = (n if latency else 1) * dist[todo[j], s] + rest[full, j]
        if c < first_cost:
            first = int(todo[j])
            first_cost = c
    return first


@njit(cache=True, inline="always")
def guide_decide(
    gmap: GuideArrays, params: GuideParams, goals: IntArray, ll: FloatArray, alive: BoolArray,
    target: int, heading: int, s: int, theta: FloatArray, scratch: FloatArray,
    comply: FloatArray, run: IntArray, fresh: bool, n_actions: int,
) -> tuple[float, float, int, bool]:  # pragma: no cover - compiled  # fmt: skip
    """``GuideAdvisor.decide``: fills ``theta`` (A,) with the advice; returns (the value
    compared with kappa, 1 - P(lost | H), the target, whether advice may be given at all: not
    to an explorer that ignores it, advice held back, within ``BACKOFF`` decisions of the
    last piece).
    ``heading``: the last move that moved (-1: none). ``scratch`` is (6 + 3 G + 3 G A + A,);
    ``comply`` as :func:`guide_observe_compliance` keeps it; ``run`` (:func:`guide_run_push`)
    the states decided for since the last piece of advice, ``s`` added here; ``fresh``: no
    advice yet this session. A caller that advises restarts ``run`` and spends a piece
    (:func:`guide_advised`). The value returned is divided by the advice budget's price (for a
    walker without drift or one that keeps a heading, below a full budget, held to where its
    own move loses ground instead: ``GuideAdvisor.decide``)."""
    p_lost, slack, spread, bump, max_tour = params[1], params[2], params[3], params[4], params[5]
    backoff = params[10]
    dist = gmap[3]
    n_goals = alive.shape[0]
    n_models = 4 + 3 * n_goals + 2  # LA and LS last
    la_k, ls_k = n_models - 2, n_models - 1
    any_alive = False
    for g in range(n_goals):
        any_alive = any_alive or alive[g]
    n_alive = 0
    for g in range(n_goals):
        if alive[g] or not any_alive:
            n_alive += 1
    # P(k | H)
    lw_lost = math.log(p_lost / 6.0)
    lw_dir = math.log((1.0 - p_lost) / (3.0 * n_alive))
    post = scratch[:n_models]
    mx = -math.inf
    for k in range(4):
        post[k] = ll[k] + lw_lost
        if post[k] > mx:
            mx = post[k]
    for k in range(la_k, n_models):
        post[k] = ll[k] + lw_lost
        if post[k] > mx:
            mx = post[k]
    for k in range(4, la_k):
        g = (k - 4) // 3
        if alive[g] or not any_alive:
            post[k] = ll[k] + lw_dir
            if post[k] > mx:
                mx = post[k]
    tot = 0.0
    for k in range(n_models):
        if 4 <= k < la_k and not (alive[(k - 4) // 3] or not any_alive):
            post[k] = 0.0
        else:
            post[k] = 1.0 if post[k] == mx else math.exp(post[k] - mx)
        tot += post[k]
    for k in range(n_models):
        post[k] = post[k] / tot
    lost = post[0] + post[1] + post[2] + post[3] + post[la_k] + post[ls_k]
    # each destination's policies here, and the target
    rows = guide_rows(scratch, n_goals, n_actions)  # pi_g and c_g (guide_append reads them)
    guide_fill_rows(gmap, goals, s, rows, n_actions)
    pis, cs = rows[:n_goals], rows[n_goals:]
    at = n_models + 2 * n_goals * n_actions
    pcs = scratch[at : at + n_goals * n_actions].reshape((n_goals, n_actions))
    guide_route_rows(gmap, goals, alive, any_alive, s, pcs, n_actions)
    driftless = post[0] + post[1] >= params[26]  # no drift of its own (DRIFTLESS)
    headed = not driftless and post[la_k] + post[ls_k] >= params[28]  # keeps a heading (HEADED)
    # the lead values decide for it: they are the walk of one that never turns back (LA), so
    # for one taken rather for it than for one that goes straight on (LS)
    by_lead = headed and post[la_k] >= post[ls_k] and gmap[12].shape[0] > 0 and heading >= 0
    if target < 0 or not (alive[target] or not any_alive):
        target = guide_first_of_tour(
            dist, goals, alive, any_alive, s, max_tour, driftless, params[30], params[31]
        )
    pi_t = scratch[at + n_goals * n_actions :]
    pick = -1
    if target >= 0:  # r_T: one shortest move (the heaviest; the heading on a tie)
        for a in range(n_actions):
            if (
                pick < 0
                or pis[target, a] > pis[target, pick]
                or (pis[target, a] == pis[target, pick] and a == heading)
            ):
                pick = a
        if by_lead:
            pick = guide_lead_pick(gmap, target, s, heading, pick, n_actions)  # along its way
        for a in range(n_actions):
            pi_t[a] = 1.0 if a == pick else 0.0
    else:
        guide_open(gmap[0], gmap[1], s, pi_t, n_actions)
    op = theta  # the open moves' policy, read before theta is written in its place
    guide_open(gmap[0], gmap[1], s, op, n_actions)
    wl = guide_wall(gmap[0], s, heading, 0)
    wr = guide_wall(gmap[0], s, heading, 1)
    kl = 0.0
    chance = pi_t  # P(A | s, H), written over r_T once r_T is read
    for a in range(n_actions):
        lo = (1.0 - bump) * op[a] + bump / n_actions
        v = lost * pi_t[a]
        m = post[0] * (1.0 / n_actions) + post[1] * lo
        m += post[2] * ((1.0 - slack) * (1.0 if a == wl else 0.0) + slack * lo)
        m += post[3] * ((1.0 - slack) * (1.0 if a == wr else 0.0) + slack * lo)
        m += post[la_k] * guide_ahead(gmap[0], gmap[1], s, heading, a, bump, n_actions)
        m += post[ls_k] * guide_straight(gmap[0], gmap[1], s, heading, a, bump, n_actions)
        for g in range(n_goals):
            if alive[g] or not any_alive:
                k = 4 + 3 * g
                v += (post[k] + post[k + 1]) * pis[g, a] + post[k + 2] * pcs[g, a]
                m += post[k] * ((1.0 - slack) * pis[g, a] + slack / n_actions)
                m += post[k + 1] * ((1.0 - slack) * pis[g, a] + slack * lo)
                m += post[k + 2] * ((1.0 - slack) * cs[g, a] + slack * lo)
        th = (1.0 - spread) * v + spread / n_actions
        theta[a] = th
        chance[a] = m
        if th > 0.0:
            kl += th * (math.log(th) - math.log(m))
    loses_ground = False
    if target >= 0:  # the value: weighted by what a lost explorer's move costs here
        d = guide_drift(gmap, target, s, n_actions)  # over the open moves; L4's over every action
        kl = kl * (1.0 + (lost - post[0]) * d + post[0] * (d * gmap[1][s] / n_actions))
        loses_ground = d > 0.0  # its own move, on average
        # over its way where it takes what it is given (the values' leads are taken)
        whole = guide_compliance_below(comply[: params[11]], params[24]) < 0.5
        if by_lead and whole and pick >= 0:
            w_la, w_ls = post[la_k], post[ls_k]
            gain = guide_lead_gain(gmap, target, s, heading, pick, w_la, w_ls, n_actions)
            loses_ground = gain > params[29]  # LEAD_PRICE
        elif headed:  # its own move from its heading, as LA and LS would make it
            own = guide_heading_drift(gmap, target, s, heading, post[la_k], post[ls_k], n_actions)
            loses_ground = own > 0.0
    kl = kl if kl > 0.0 else 0.0
    if n_actions != 4:  # in four actions' units, as the paper's rule (``kl_scale``)
        kl = kl * (math.log(4.0) / math.log(float(n_actions)))
    best = 0  # the advice: theta's favourite move
    for a in range(n_actions):
        if theta[a] > theta[best]:
            best = a
    n_levels = params[11]
    comply[n_levels] = chance[best]  # its own move would be the advice this often
    comply[n_levels + 9] = float(best)
    for a in range(n_actions):
        theta[a] = (1.0 - spread) * (1.0 if a == best else 0.0) + spread / n_actions
    # an explorer that ignores advice is left in peace, but for a piece now and then
    held = comply[n_levels + 2] != 0.0 or comply[n_levels + 6] >= params[14]
    allowed = not held or comply[n_levels + 1] >= backoff
    allowed = allowed and any_alive  # none left: it is bound elsewhere
    guide_run_push(run, s)
    on_lead = comply[n_levels + 10] != 0.0
    purpose = guide_purposeful(gmap, run, fresh, on_lead, params, target)
    allowed = allowed and not purpose  # it walks a way of its own
    # the advice budget: a piece more saved each 1 / ADVICE_RATE decisions (params[21], up to
    # ADVICE_BURST, params[22]), the value divided by the price of the pieces saved
    saved = min(params[22], comply[n_levels + 11] + params[21])
    comply[n_levels + 11] = saved
    ruled = post[2] + post[3]  # one with a rule of its own: a hand on the wall, the compass
    for g in range(n_goals):
        ruled += post[4 + 3 * g + 2]
    free = ruled >= 0.5  # its detours are not held to the budget (paid for afterwards)
    if saved >= 1.0 and not free:
        if (driftless or headed) and saved < params[22]:  # where its move loses ground, no price
            if not (loses_ground and saved >= 1.0 + params[27]):
                kl = 0.0
        else:
            kl = kl / (params[22] / saved) ** params[23]
    allowed = allowed and (saved >= 1.0 or free)
    return kl, 1.0 - lost, target, allowed


@njit(cache=True, inline="always")
def guide_learner_decides(
    gmap: GuideArrays, params: GuideParams, goals: IntArray, ll: FloatArray, alive: BoolArray,
    target: int, heading: int, s: int, theta: FloatArray, scratch: FloatArray,
    comply: FloatArray, run: IntArray, given: int, kappa: float, n_actions: int,
) -> tuple[float, float, int, bool, int]:  # pragma: no cover - compiled  # fmt: skip
    """:func:`guide_decide` for a Q-learner's session, and the piece given if it advises
    (:func:`guide_advised`): (value, 1 - P(lost | H), target, allowed, pieces given)."""
    kl, p, target, allowed = guide_decide(
        gmap, params, goals, ll, alive, target, heading, s, theta, scratch, comply, run,
        given == 0, n_actions,
    )  # fmt: skip
    if kl >= kappa and allowed:
        guide_advised(params, comply, run, s)
        given += 1
    return kl, p, target, allowed, given


@njit(cache=True, inline="always")
def guide_run_push(run: IntArray, s: int) -> None:  # pragma: no cover - compiled
    """Add ``s`` to ``run``: ``GuideAdvisor._run`` as a ring (how many, the newest's slot,
    then PURPOSE_WALK + 1 slots), the oldest dropped once it is full."""
    size = run.shape[0] - 2
    newest = (run[1] + 1) % size
    run[2 + newest] = s
    run[1] = newest
    if run[0] < size:
        run[0] += 1


@njit(cache=True)
def guide_run_new(params: GuideParams) -> IntArray:  # pragma: no cover - compiled
    """An empty ``run`` of :func:`guide_run_push` (PURPOSE_WALK, ``params[19]``)."""
    run = np.zeros(params[19] + 3, dtype=np.int64)
    run[1] = params[19]  # the first goes to slot 0
    return run


@njit(cache=True)
def guide_advised(
    params: GuideParams, comply: FloatArray, run: IntArray, s: int
) -> None:  # pragma: no cover - compiled
    """Advice was given at ``s``: ``run`` starts again there, and it spends a piece of the
    advice budget."""
    run[0] = 1
    run[1] = 0
    run[2] = s
    comply[params[11] + 11] -= 1.0


@njit(cache=True)
def guide_apart(
    cells: IntArray, dist: IntArray, marks: IntArray, bound: bool, u: int, v: int
) -> int:  # pragma: no cover - compiled
    """``GuideMap.apart``: a lower bound on the moves from ``u`` to ``v`` (the row plus column
    difference where it ``bound``s them, the destinations' distances ``dist``, then the
    landmarks' ``marks``)."""
    far = 0
    if bound:
        far = int(abs(cells[u, 0] - cells[v, 0]) + abs(cells[u, 1] - cells[v, 1]))
    for rows in (dist, marks):
        for g in range(rows.shape[0]):
            du, dv = rows[g, u], rows[g, v]
            if du >= 0 and dv >= 0 and abs(du - dv) > far:
                far = int(abs(du - dv))
    return far


@njit(cache=True, inline="always")
def guide_purposeful(
    gmap: GuideArrays,
    run: IntArray,
    fresh: bool,
    on_lead: bool,
    params: GuideParams,
    target: int,
) -> bool:  # pragma: no cover - compiled
    """``GuideAdvisor.purposeful``: ``run`` holds at least PURPOSE_RUN moves (``params[15]``)
    unless ``fresh``; with no move into a wall (two states in a row the same) among its last
    PURPOSE_LONG (``params[17]``), its last PURPOSE_RUN moves were a shortest path give or
    take PURPOSE_SLACK (``params[16]``), its last PURPOSE_LONG give or take
    PURPOSE_LONG_SLACK (``params[18]``), and all of them give or take a PURPOSE_WALK_PART-th
    (``params[20]``) of their number, as far as :func:`guide_apart` can tell; and, unless
    ``fresh``, neither all the way along the way to destination ``target`` (-1: none) nor
    ``on_lead`` (each move since the last piece that of the advice of the decision before)."""
    k_run, k_slack, k_long, long_slack, part = (
        params[15], params[16], params[17], params[18], params[20],
    )  # fmt: skip
    cells, dist, marks, floor = gmap[2], gmap[3], gmap[7], gmap[8]
    bound, spread = gmap[10], gmap[11]
    m = run[0]
    if m == 0 or (m <= k_run and not fresh):
        return False
    size = run.shape[0] - 2
    newest = run[1]
    n = m - 1
    for i in range(min(n, k_long)):  # a bump: no shortest path has one
        j = (newest - i + size) % size
        if run[2 + j] == run[2 + (j - 1 + size) % size]:
            return False
    now = run[2 + newest]
    began = run[2 + (newest - n + size) % size]
    led = not fresh and n > 0 and target >= 0
    if led and (on_lead or dist[target, began] - dist[target, now] == n):
        return False  # after advice, it went the way it is led
    before = 0
    for test in range(3):  # the last PURPOSE_RUN, PURPOSE_LONG and all of its moves
        if test == 0:
            k, slack = min(k_run, n), k_slack
        elif test == 1:
            k, slack = min(k_long, n), long_slack
        else:
            k, slack = n, max(long_slack, n // part)
        if k <= before:  # the walk of the test before, given more slack
            continue
        before = k
        u = run[2 + (newest - k + size) % size]
        apart = guide_apart(cells, dist, marks, bound, u, now)
        # in a building, a quickest walk may take ``spread`` moves more a floor it rides
        rides = abs(floor[u] - floor[now]) if floor.shape[0] > 0 else 0
        low = k - slack - rides * spread
        if apart > k:
            return False
        if apart < low:  # the bound falls short: the last k moves measured (all: the bound)
            if test == 2 or guide_came_back(run, k, k - low):
                return False
            if guide_within(gmap[0], cells, dist, marks, bound, u, now, low - 1, params[25]) != 0:
                return False
    return True


@njit(cache=True)
def guide_came_back(run: IntArray, k: int, moves: int) -> bool:  # pragma: no cover - compiled
    """``GuideAdvisor._walked_apart``'s first look: whether the last ``k`` moves of ``run``
    (:func:`guide_run_push`'s ring) came back to a cell after more than ``moves`` moves."""
    size = run.shape[0] - 2
    oldest = run[1] - k + size
    for j in range(moves + 1, k + 1):
        c = run[2 + (oldest + j) % size]
        for i in range(j - moves):
            if run[2 + (oldest + i) % size] == c:
                return True
    return False


@njit(cache=True, inline="always")
def guide_slot(table: IntArray, key: int) -> int:  # pragma: no cover - compiled
    """Where ``key`` is in ``table``, an open-addressing hash set of non-negative keys (-1:
    empty; its size a power of two, never full), or the empty slot it would go to."""
    mask = table.shape[0] - 1
    h = (key * 2654435761) & mask
    while table[h] != -1 and table[h] != key:
        h = (h + 1) & mask
    return int(h)


@njit(cache=True)
def guide_within(
    next_state: IntArray, cells: IntArray, dist: IntArray, marks: IntArray, bound: bool,
    u: int, v: int, most: int, budget: int,
) -> int:  # pragma: no cover - compiled  # fmt: skip
    """``GuideMap.within``: 1 if a walk of at most ``most`` moves leads from ``u`` to ``v``,
    0 if none does, -1 if the search would queue more than ``budget`` cells; the same search
    in the same order (buckets as linked lists, the cells taken in a hash set, open
    addressing, at most half full)."""
    if u == v:
        return 1 if most >= 0 else 0
    first = guide_apart(cells, dist, marks, bound, u, v)
    if first > most:
        return 0
    cap = 16
    while cap < 2 * budget:
        cap *= 2
    buf = np.empty(cap + 3 * budget + 2 * (most + 1), dtype=np.int64)  # one allocation
    done = buf[:cap]
    cell = buf[cap : cap + budget]
    moves = buf[cap + budget : cap + 2 * budget]
    after = buf[cap + 2 * budget : cap + 3 * budget]  # the next in its bucket, -1: none
    head = buf[cap + 3 * budget : cap + 3 * budget + most + 1]
    tail = buf[cap + 3 * budget + most + 1 :]
    done[:] = -1
    head[:] = -1
    tail[:] = -1
    cell[0], moves[0], after[0] = u, 0, -1
    head[first] = tail[first] = 0
    queued = 1
    f = first
    while f <= most:
        i = head[f]
        if i < 0:
            f += 1
            continue
        head[f] = after[i]
        if head[f] < 0:
            tail[f] = -1
        w, d = cell[i], moves[i]
        h = guide_slot(done, w)
        if done[h] == w:
            continue
        done[h] = w
        for a in range(next_state.shape[1]):
            t = next_state[w, a]
            if t == w or done[guide_slot(done, t)] == t:
                continue
            ft = d + 1 + guide_apart(cells, dist, marks, bound, t, v)
            if ft > most:
                continue
            if t == v:
                return 1
            if queued >= budget:
                return -1
            b = ft if ft > f else f
            cell[queued], moves[queued], after[queued] = t, d + 1, -1
            if tail[b] < 0:
                head[b] = queued
            else:
                after[tail[b]] = queued
            tail[b] = queued
            queued += 1
    return 0


@njit(cache=True)
def guide_buffers(
    n_goals: int, n_actions: int
) -> tuple[FloatArray, FloatArray, FloatArray]:  # pragma: no cover - compiled
    """What :func:`guide_decide` and :func:`guide_append` need besides the session's state:
    its scratch (6 + 3 G + 3 G A + A,), ``pi`` (A,) and ``theta`` (A,)."""
    size = 6 + 3 * n_goals + 3 * n_goals * n_actions + n_actions
    return np.empty(size), np.empty(n_actions), np.empty(n_actions)


@njit(cache=True)
def guide_rows(
    scratch: FloatArray, n_goals: int, n_actions: int
) -> FloatArray:  # pragma: no cover - compiled
    """The rows of :func:`guide_decide`'s scratch holding every destination's pi_g, then its
    c_g, at the state of the last decision: (2 G, A), what :func:`guide_append` reads."""
    start = 6 + 3 * n_goals
    return scratch[start : start + 2 * n_goals * n_actions].reshape((2 * n_goals, n_actions))


@njit(cache=True, inline="always")
def guide_stream(
    gmap: GuideArrays,
    params: GuideParams,
    goals: IntArray,
    ll: FloatArray,
    alive: BoolArray,
    doubt: IntArray,
    target: int,
    last: int,
    heading: int,
    came: int,
    advice: FloatArray,
    comply: FloatArray,
    run: IntArray,
    kappa: float,
    count: int,
    benefit: float,
    cap: int,
    moves: tuple[IntArray, IntArray, IntArray],
    out: GuideOut,
    n_actions: int,
) -> tuple[int, int, int, int, int, float]:  # pragma: no cover - compiled
    """A batch of ``GuideAdvisor.observe``; ``last`` is the state the last decision advised
    (-1 if it did not), ``advice`` (A,) that advice, updated in place, ``heading`` the last
    move that moved, ``came`` where the last move led on the map (-1: none), ``comply`` the
    compliance evidence (:func:`guide_observe_compliance`) and ``run`` the states decided for
    since the last piece of advice (:func:`guide_run_push`), updated in place. Fills ``out``
    (kl, p_normal, advise, count, benefit, advice (n, A)); returns (target, last, heading,
    came, advice count, benefit). ``n_actions``: the domain's; compiled through
    :func:`guide_stream_four` or :func:`guide_stream_six`, where it is a constant."""
    states, actions, next_states = moves
    kl_out, p_out, advise_out, count_out, benefit_out, advice_out = out
    n_goals = alive.shape[0]
    scratch, pi, theta = guide_buffers(n_goals, n_actions)
    rows = guide_rows(scratch, n_goals, n_actions)
    for i in range(states.shape[0]):
        known = i > 0 and states[i] == next_states[i - 1]  # decided there just before
        heading, came = guide_append(
            gmap, params, goals, ll, alive, doubt, states[i], actions[i], last == states[i],
            advice, heading, pi, rows, known, comply, came, n_actions,
        )  # fmt: skip
        kl, p0, target, allowed = guide_decide(
            gmap, params, goals, ll, alive, target, heading, next_states[i], theta, scratch,
            comply, run, count == 0, n_actions,
        )  # fmt: skip
        if kl >= kappa and count < cap and allowed:
            count += 1
            benefit += kl
            advise_out[i] = True
            last = next_states[i]
            guide_advised(params, comply, run, last)
            for a in range(n_actions):
                advice[a] = theta[a]
        else:
            advise_out[i] = False
            last = -1
        for a in range(n_actions):
            advice_out[i, a] = theta[a]
        kl_out[i] = kl
        p_out[i] = p0
        count_out[i] = count
        benefit_out[i] = benefit
    return target, last, heading, came, count, benefit


@njit(cache=True)
def guide_stream_four(
    gmap: GuideArrays, params: GuideParams, goals: IntArray, ll: FloatArray, alive: BoolArray,
    doubt: IntArray, target: int, last: int, heading: int, came: int, advice: FloatArray,
    comply: FloatArray, run: IntArray, kappa: float, count: int, benefit: float, cap: int,
    moves: tuple[IntArray, IntArray, IntArray], out: GuideOut,
) -> tuple[int, int, int, int, int, float]:  # pragma: no cover - compiled  # fmt: skip
    """:func:`guide_stream` compiled with the constant 4, for a domain of one floor: its
    loops over actions unrolled (with the number read from the map, a one-floor decision cost
    1.3-1.7 times as much: docs/PERFORMANCE.md). A domain has four actions or, in a building
    of several floors, six (:func:`guide_stream_six`)."""
    return guide_stream(
        gmap, params, goals, ll, alive, doubt, target, last, heading, came, advice, comply, run,
        kappa, count, benefit, cap, moves, out, 4,
    )  # fmt: skip


@njit(cache=True)
def guide_stream_six(
    gmap: GuideArrays, params: GuideParams, goals: IntArray, ll: FloatArray, alive: BoolArray,
    doubt: IntArray, target: int, last: int, heading: int, came: int, advice: FloatArray,
    comply: FloatArray, run: IntArray, kappa: float, count: int, benefit: float, cap: int,
    moves: tuple[IntArray, IntArray, IntArray], out: GuideOut,
) -> tuple[int, int, int, int, int, float]:  # pragma: no cover - compiled  # fmt: skip
    """:func:`guide_stream` compiled with the constant 6, for a building of several
    floors (its loops over actions unrolled as on one floor: 15-20% less a decision than with
    the number read from the map)."""
    return guide_stream(
        gmap, params, goals, ll, alive, doubt, target, last, heading, came, advice, comply, run,
        kappa, count, benefit, cap, moves, out, 6,
    )  # fmt: skip


# ---- a domain's guide map, built without the GIL -------------------------------------------------
# A service builds these in a worker thread while its event loop serves others: compiled with
# ``nogil``, the searches never hold the GIL, so the loop runs while they do.
@njit(cache=True, nogil=True)
def guide_distances(next_state: IntArray, targets: IntArray) -> IntArray:  # pragma: no cover
    """``grid.bfs_distances_each``: ``out[i, s]``, the fewest moves from ``s`` to
    ``targets[i]`` (-1: none), one breadth-first search outward from each target over every
    action, the rides of a building's too (moves are reversible: a ride up is undone by the
    ride down)."""
    n, k = next_state.shape
    out = np.full((targets.shape[0], n), -1, dtype=np.int64)
    queue = np.empty(n, dtype=np.int64)
    for i in range(targets.shape[0]):
        dist = out[i]
        dist[targets[i]] = 0
        queue[0] = targets[i]
        head, tail = 0, 1
        while head < tail:
            v = queue[head]
            head += 1
            for a in range(k):
                u = next_state[v, a]
                if dist[u] < 0:
                    dist[u] = dist[v] + 1
                    queue[tail] = u
                    tail += 1
    return out


@njit(cache=True, inline="always")
def guide_compass_at(
    mask: int, cells: IntArray, stops: IntArray, at: int, u: int, t: int
) -> tuple[int, int]:  # pragma: no cover - compiled
    """The compass moves of someone at ``u`` heading for ``t`` (``GuideMap.compass_moves``):
    up to two moves (-1: none); ``mask``: u's open moves (:func:`guide_open_moves` of the
    four on a floor). ``at``: 0 on one floor (``cells`` (S, 2)), 1 in a building (``cells``
    (S, 3), ``stops`` ``Building.nearest_stops``): on another floor than t's, towards the
    nearest stop with a way towards t's floor, and there the ride (``U`` up, ``D`` down);
    none where u's floor has no such stop."""
    aim = t
    if at == 1 and cells[u, 0] != cells[t, 0]:
        up = 0 if cells[t, 0] > cells[u, 0] else 1
        aim = stops[u, up]
        if aim == u:
            return 4 + up, -1  # at the stop: the ride
    if aim < 0 or aim == u:
        return -1, -1
    dr, dc = cells[aim, at] - cells[u, at], cells[aim, at + 1] - cells[u, at + 1]
    return guide_own_moves(dr, dc, mask)


@njit(cache=True, nogil=True)
def guide_compass_table(
    next_state: IntArray, cells: IntArray, targets: IntArray, stops: IntArray
) -> ByteArray:  # pragma: no cover - compiled
    """``guide.compass_table``: the compass moves of every state (rows) and target (columns)
    as one byte each (the first move + 1 in the low four bits, the second + 1 in the high
    four; 0: none), what :func:`guide_compass` reads; ``cells`` and ``stops`` as
    :func:`guide_detours` takes them."""
    n = next_state.shape[0]
    at = 0 if stops.shape[0] == 0 else 1
    out = np.zeros((n, targets.shape[0]), dtype=np.uint8)
    for u in range(n):
        mask = guide_open_moves(next_state, u, 4)
        for i in range(targets.shape[0]):
            m0, m1 = guide_compass_at(mask, cells, stops, at, u, targets[i])
            out[u, i] = (m0 + 1) | ((m1 + 1) << 4)
    return out


@njit(cache=True, nogil=True)
def guide_detours(
    next_state: IntArray, cells: IntArray, targets: IntArray, stops: IntArray
) -> IntArray:  # pragma: no cover
    """``grid.compass_detours_each``: ``out[i, s]``, the fewest moves on any way from ``s`` to
    ``targets[i]`` that someone heading there as the crow flies would not make by itself (-1:
    no way): a 0-1 breadth-first search outward from each target over a double-ended queue,
    the move of ``u`` into ``v`` costing 0 when it is one of ``u``'s own moves.

    On one floor (``stops`` empty, (0, 2); ``cells`` (S, 2)) its own moves are
    :func:`guide_own_moves`' towards the target. In a building (``next_state`` (S, 6),
    ``cells`` (S, 3) ``[floor, row, col]``, ``stops`` ``Building.nearest_stops``), as
    ``Building.compass_takes``: on the target's floor the compass's towards it; on another,
    towards the nearest stop with a way towards the target's floor, and there the ride (``U``
    up, ``D`` down); none where its floor has no such stop."""
    n, k = next_state.shape
    at = 0 if stops.shape[0] == 0 else 1  # the row's column in cells
    out = np.full((targets.shape[0], n), -1, dtype=np.int64)
    size = k * n + 2  # every move relaxed once at most, and the target
    ring = np.empty(size, dtype=np.int64)
    best = np.empty(n, dtype=np.int64)
    done = np.empty(n, dtype=np.bool_)
    for i in range(targets.shape[0]):
        t = targets[i]
        best[:] = n * k + 1  # more than any way's detours
        done[:] = False
        best[t] = 0
        ring[0] = t
        head, count = 0, 1
        while count > 0:
            v = ring[head]
            head = (head + 1) % size
            count -= 1
            if done[v]:
                continue
            done[v] = True
            for a in range(k):
                u = next_state[v, a]
                if u == v or done[u]:
                    continue
                back = (a + 2) % 4 if a < 4 else 9 - a  # u's move into v (U and D: 4, 5)
                mask = guide_open_moves(next_state, u, 4)
                m0, m1 = guide_compass_at(mask, cells, stops, at, u, t)
                cost = 0 if (m0 == back or m1 == back) else 1
                if best[v] + cost < best[u]:
                    best[u] = best[v] + cost
                    if cost == 0:  # to the front: the same number of detours as v
                        head = (head - 1 + size) % size
                        ring[head] = u
                    else:
                        ring[(head + count) % size] = u
                    count += 1
        for s in range(n):
            if done[s]:
                out[i, s] = best[s]
    return out


# ---- explorers ----------------------------------------------------------------------------------
@njit(cache=True, inline="always")
def sample_action(
    weights: FloatArray, u: float, mask: BoolArray, n: int
) -> int:  # pragma: no cover - compiled
    """explorers.sample_action: inverse CDF over the ``n`` actions' allowed ones. Inlined, so
    that a caller's constant 4 makes loops of four (a count read from the arrays made the
    Q-learning kernel 7% slower, measured: docs/PERFORMANCE.md)."""
    total = 0.0
    for a in range(n):
        if mask[a]:
            total += weights[a]
    target = u * total
    running = 0.0
    last = -1
    for a in range(n):
        if mask[a]:
            running += weights[a]
            last = a
            if target < running:
                return a
    return last


@njit(cache=True, inline="always")
def uniform_choice(mask: BoolArray, u: float, n: int) -> int:  # pragma: no cover - compiled
    """explorers.uniform_choice: the int(u * k)-th allowed action of the ``n`` (inlined, as
    :func:`sample_action`)."""
    k = 0
    for a in range(n):
        if mask[a]:
            k += 1
    pick = int(u * k)
    for a in range(n):
        if mask[a]:
            if pick == 0:
                return a
            pick -= 1
    return -1


@njit(cache=True)
def own_action(
    kind: int, s: int, heading: int, goal: int, open_moves: BoolArray, cells: IntArray,
    optimal: BoolArray, stops: IntArray, rng: np.random.Generator,
) -> int:  # pragma: no cover  # fmt: skip
    """The rule of a fixed-policy explorer (explorers.*.policy) over the domain's actions
    (``open_moves``' columns), the heading a compass move. ``cells``: (row, col), or in a
    building (floor, row, col), with ``stops`` (``Building.nearest_stops``) read there."""
    if kind == RANDOM:
        return int(rng.random() * open_moves.shape[1])
    if kind == RANDOM_AVOID:
        return uniform_choice(open_moves[s], rng.random(), open_moves.shape[1])
    if kind == LEFT:
        for turn in (3, 0, 1, 2):  # left, straight, right, back
            a = (heading + turn) % 4
            if open_moves[s, a]:
                return a
        return heading
    if kind in (CORRIDOR, STRAIGHT):
        if kind == STRAIGHT and open_moves[s, heading]:
            return heading
        back = (heading + 2) % 4
        ahead = open_moves[s].copy()
        ahead[back] = False
        if ahead.any():
            return uniform_choice(ahead, rng.random(), open_moves.shape[1])
        return back if open_moves[s, back] else heading  # a dead end: back
    if kind == BUG:
        aim = goal
        rc = cells.shape[1] - 2  # the row's column: 0, or 1 after a building's floor
        if rc == 1 and cells[s, 0] != cells[goal, 0]:  # another floor: the nearest stop
            k = 0 if cells[goal, 0] > cells[s, 0] else 1
            aim = stops[s, k]
            if aim == s:
                return 4 + k  # U or D
            if aim < 0:
                return uniform_choice(open_moves[s], rng.random(), open_moves.shape[1])
        dr = cells[aim, rc] - cells[s, rc]
        dc = cells[aim, rc + 1] - cells[s, rc + 1]
        vert = -1 if dr == 0 else (2 if dr > 0 else 0)
        horiz = -1 if dc == 0 else (1 if dc > 0 else 3)
        first, second = vert, horiz
        if abs(dc) > abs(dr) or (abs(dc) == abs(dr) and dr != 0 and rng.random() >= 0.5):
            first, second = horiz, vert
        if first >= 0 and open_moves[s, first]:
            return first
        if second >= 0 and open_moves[s, second]:
            return second
        return uniform_choice(open_moves[s], rng.random(), open_moves.shape[1])
    # OPTIMAL
    best = optimal[s]
    n_best = 0
    only = 0
    for a in range(best.shape[0]):
        if best[a]:
            n_best += 1
            only = a
    if n_best == 0:
        return int(rng.random() * open_moves.shape[1])
    if n_best == 1:
        return only
    return uniform_choice(best, rng.random(), best.shape[0])


@njit(cache=True)
def in_sight(next_state: IntArray, s: int, goal: int, reach: int) -> int:  # pragma: no cover
    """explorers.in_sight: the move along a straight line of free cells from ``s`` that
    reaches ``goal`` within ``reach`` moves (N, E, S, W tried in turn), or -1."""
    for a in range(4):
        x = s
        for _ in range(reach):
            y = next_state[x, a]
            if y == x:
                break
            if y == goal:
                return a
            x = y
    return -1


@njit(cache=True)
def read_position(
    next_state: IntArray, open_moves: BoolArray, s: int, noise: float, seen_rng: np.random.Generator
) -> int:  # pragma: no cover - compiled
    """explorers.read_position: the cell the advisor reads for an explorer at ``s``."""
    if noise <= 0.0:
        return s
    if seen_rng.random() >= noise or not open_moves[s].any():
        return s
    return int(next_state[s, uniform_choice(open_moves[s], seen_rng.random(), open_moves.shape[1])])


# ---- whole episodes -----------------------------------------------------------------------------
@njit(cache=True)
def rule_says(
    rule: int, t: int, s: int, last_s: int, last_a: int,
    rule_params: tuple[int, float, float, float], tables: Tables, rule_rng: np.random.Generator,
) -> bool:  # pragma: no cover - compiled  # fmt: skip
    """``RuleAdvisor``'s rules: advise at ``s`` after ``t`` decisions (the last move was
    (``last_s``, ``last_a``), -1 before the first)."""
    n_steps, threshold, rate, _ = rule_params
    n_actions = tables[3].shape[0] // tables[4].shape[0]  # theta (S*A,), neg_entropy (S,)
    if rule == EARLY:
        return t < n_steps
    if rule == IMPORTANCE:  # KL[theta_s || uniform] = log A + sum theta log theta
        if n_actions == 4:
            return bool(math.log(4.0) + tables[4][s] >= threshold)
        kl = (math.log(float(n_actions)) + tables[4][s]) * (
            math.log(4.0) / math.log(float(n_actions))
        )  # in four actions' units, as ImportanceAdvisor.says
        return bool(kl >= threshold)
    if rule == MISTAKE:
        return last_s >= 0 and bool(tables[3][last_s * n_actions + last_a] < threshold)
    if rule == RANDOM_RULE:
        return rule_rng.random() < rate
    return True  # ALWAYS


@njit(cache=True)
def episode(
    kind: int,
    visitor: VisitorParams,
    world: tuple[IntArray, BoolArray, IntArray, BoolArray, IntArray],
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
    guide: tuple[GuideArrays, GuideParams, IntArray],
    rng: np.random.Generator,
    rule_rng: np.random.Generator,
    seen_rng: np.random.Generator,
    out: tuple[IntArray, FloatArray, BoolArray],
) -> tuple[int, bool, int, float, int]:  # pragma: no cover - compiled
    """One task of a fixed-policy explorer ``kind`` from ``start``, watched by the advisor of
    strategy ``rule``; returns (steps, success, advice count, benefit, goals ruled out).

    ``visitor`` is (compliance p, position noise q, sight r): an advised explorer takes the
    advice when one draw u < p (no draw at p = 1); the advisor reads each cell the explorer
    stands on through :func:`read_position` (draws from ``seen_rng``, none at q = 0), appends
    (read cell, action) and decides for the next read cell, while the explorer moves from its
    true cell; with r > 0 an explorer whose goal is in sight (:func:`in_sight`) walks to it,
    whatever the advice. ``s`` is the cell the advisor reads, ``x`` the explorer's own.

    ``world`` is (next_state (S, A), open moves (S, A), cells (S, 2; a building's (S, 3)),
    the optimal moves to ``goal`` (S, A), a building's ``nearest_stops`` (S, 2; not read on
    one floor)), A 4 or, in a building of several floors, 6 (every explorer; the paper's
    rule, goal-aware advice and the rules); ``rule_params`` (n_steps, threshold, rate,
    beta). ``out`` receives, before each move, the state, P(M1 | H) (when ``out[1]`` is not
    empty) and the decision (given to the explorer only if ``advised``). The explorer's draws
    come from ``rng``, the ``random`` rule's from ``rule_rng``, in the reference's order.
    ``goals`` is read by ``goal_aware`` only (G may be 0 for the others), ``guide`` (its map,
    parameters and destination states) by ``guide`` only. ``out[0]`` receives the explorer's
    own cell."""
    next_state, open_moves, cells, optimal, stops = world
    n_actions = next_state.shape[1]  # 4, or 6 in a building
    compliance, noise, sight = visitor
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
    theta_w = np.empty(n_actions)
    gmap, gparams, g_goals = guide
    n_dest = g_goals.shape[0] if rule == GUIDE else 0
    g_ll = np.zeros(4 + 3 * n_dest + 2)
    g_alive = np.ones(n_dest, dtype=np.bool_)
    g_doubt = np.zeros(n_dest, dtype=np.int64)
    g_target = -1
    g_heading = -1
    g_comply = guide_compliance_state(gparams)
    g_came = -1
    g_scratch, g_pi, _ = guide_buffers(n_dest, n_actions)
    g_rows = guide_rows(g_scratch, n_dest, n_actions)
    g_run = guide_run_new(gparams)
    heading = 0
    has_heading = kind in (LEFT, CORRIDOR, STRAIGHT)
    if has_heading:
        heading = int(rng.random() * 4)
    all_moves = np.ones(n_actions, dtype=np.bool_)
    advice_count = 0
    benefit = 0.0
    x = start
    s = read_position(next_state, open_moves, x, noise, seen_rng)
    last_s = -1
    last_a = -1
    for t in range(max_steps):
        # ---- the decision for s (t moves so far) --------------------------------------------
        if rule == GOAL_AWARE:
            goal_posterior(goal_ll, alive, beta, w)
            kl, p = goal_decide(loglik, tables, goals, w, s, theta_w, z)
            advise = kl >= kappa
        elif rule == GUIDE:
            kl, p, g_target, allowed = guide_decide(
                gmap, gparams, g_goals, g_ll, g_alive, g_target, g_heading, s, theta_w,
                g_scratch, g_comply, g_run, advice_count == 0, n_actions,
            )  # fmt: skip
            advise = kl >= kappa and allowed
            if advise:
                guide_advised(gparams, g_comply, g_run, s)
        else:
            says = rule == PAPER or rule_says(
                rule, t, s, last_s, last_a, rule_params, tables, rule_rng
            )
            kl, p = 0.0, 0.0
            if rule == PAPER or says or record_p:  # the paper's KL is reported where advised
                if n_actions == 4:
                    kl, p = decide_call(loglik, tables, s, z)
                else:
                    kl, p = decide_any_call(loglik, tables, s, z, n_actions)
            advise = kl >= kappa if rule == PAPER else says
        if advise:
            advice_count += 1
            benefit += kl
        states_out[t] = x
        if record_p:
            p_out[t] = p
        advise_out[t] = advise
        # ---- the explorer acts from its own cell x ------------------------------------------
        a = in_sight(next_state, x, goal, sight) if sight > 0 else -1
        if a >= 0:
            pass  # its goal in sight: it walks there, whatever the advice
        elif advised and advise and (compliance >= 1.0 or rng.random() < compliance):
            # two calls: one merged row variable cost a quarter (measured)
            if rule in (GOAL_AWARE, GUIDE):
                a = sample_action(theta_w, rng.random(), all_moves, n_actions)
            else:
                b = s * n_actions
                a = sample_action(theta[b : b + n_actions], rng.random(), all_moves, n_actions)
        else:
            a = own_action(kind, x, heading, goal, open_moves, cells, optimal, stops, rng)
        x2 = next_state[x, a]
        if has_heading and x2 != x and a < 4:  # a ride keeps the heading
            heading = a
        if x2 == goal:
            ruled = n_goals - int(alive.sum()) + n_dest - int(g_alive.sum())
            return t + 1, True, advice_count, benefit, ruled
        s2 = read_position(next_state, open_moves, x2, noise, seen_rng)
        # ---- the advisor appends (s, a) to H ------------------------------------------------
        if rule == GOAL_AWARE:
            gi = goal_of_state[s]
            if gi >= 0:  # it stood on goal gi's cell and went on: not its goal
                alive[gi] = False
            if beta > 0.0:  # beta = 0 never reads the per-goal window
                k = s * n_actions + a
                for g in range(n_goals):
                    v = goal_log_theta[k, g]
                    goal_ll[g] += v - goal_ring[g, pos]
                    goal_ring[g, pos] = v
                if pos + 1 == window and (t + 1) % period == 0:
                    for g in range(n_goals):
                        goal_ll[g] = fsum(goal_ring[g])
        if rule == GUIDE:  # guide keeps its own evidence, not the paper's window
            g_heading, g_came = guide_append(  # the decision for s came just before
                gmap, gparams, g_goals, g_ll, g_alive, g_doubt, s, a, advise, theta_w,
                g_heading, g_pi, g_rows, True, g_comply, g_came, n_actions,
            )  # fmt: skip
        else:
            pos = push(ring, loglik, pos, t + 1, period, log_probs, s, a, n_actions)
        last_s, last_a = s, a
        s = s2
        x = x2
    ruled = n_goals - int(alive.sum()) + n_dest - int(g_alive.sum())
    return max_steps, False, advice_count, benefit, ruled


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
    rule: int,
    guide: tuple[GuideArrays, GuideParams, IntArray],
    rng: np.random.Generator,
    q: FloatArray,
    out: tuple[IntArray, BoolArray, IntArray, IntArray, FloatArray],
) -> int:  # pragma: no cover - compiled
    """Episodes of one Q-learning task (``q`` (S, A) is learned in place); returns how many
    episodes ran (fewer than ``episodes`` only when ``step_budget`` > 0 runs out).

    ``learner`` is (alpha, gamma, epsilon, ties broken by the advice). Per episode ``out``
    receives: moves, success, advice given and decisions made at the states it acted in (one
    per move), mean P(M1 | H) over those decisions. ``rule`` is PAPER or GUIDE (then
    ``guide`` is read, as :func:`episode` reads it). The domain's A actions:
    ``next_state``'s columns."""
    n_actions = next_state.shape[1]
    alpha, gamma, epsilon, ties_advice = learner
    steps_out, success_out, advice_out, decisions_out, p_mean_out = out
    log_probs, _, _, theta, _ = tables
    n_models = log_probs.shape[0]
    ring = np.zeros((n_models, window))
    loglik = np.zeros(n_models)
    z = np.empty(n_models)
    pos = 0
    appended = 0  # pairs in this advisor session
    all_moves = np.ones(n_actions, dtype=np.bool_)
    best = np.zeros(n_actions, dtype=np.bool_)
    gmap, gparams, g_goals = guide
    n_dest = g_goals.shape[0] if rule == GUIDE else 0
    g_ll = np.zeros(4 + 3 * n_dest + 2)
    g_alive = np.ones(n_dest, dtype=np.bool_)
    g_doubt = np.zeros(n_dest, dtype=np.int64)
    g_target = -1
    g_heading = -1
    g_comply = guide_compliance_state(gparams)
    g_came = -1
    g_scratch, g_pi, theta_w = guide_buffers(n_dest, n_actions)
    g_rows = guide_rows(g_scratch, n_dest, n_actions)
    g_run = guide_run_new(gparams)
    g_given = 0  # advice in this advisor session
    total_steps = 0
    for e in range(episodes):
        if not keep_history:
            ring[:] = 0.0
            loglik[:] = 0.0
            pos = 0
            appended = 0
            g_ll[:] = 0.0
            g_alive[:] = True
            g_doubt[:] = 0
            g_target = -1
            g_heading = -1
            g_comply[:] = guide_compliance_state(gparams)
            g_came = -1
            g_run[:] = guide_run_new(gparams)
            g_given = 0
        s = start
        n_advice = 0
        p_sum = 0.0
        success = False
        t = 0
        while t < max_steps:
            if rule == GUIDE:
                kl, p, g_target, allowed, g_given = guide_learner_decides(
                    gmap, gparams, g_goals, g_ll, g_alive, g_target, g_heading, s, theta_w,
                    g_scratch, g_comply, g_run, g_given, kappa, n_actions,
                )  # fmt: skip
                row = theta_w
            else:
                if n_actions == 4:  # a constant in the loop compiled for four
                    kl, p = decide(loglik, tables, s, z)
                else:
                    kl, p = decide_any_call(loglik, tables, s, z, n_actions)
                row = theta[s * n_actions : s * n_actions + n_actions]
                allowed = True
            advise = kl >= kappa and allowed
            n_advice += advise
            p_sum += p
            give = advised and advise
            if rng.random() < epsilon:
                u = rng.random()
                a = sample_action(row, u, all_moves, n_actions) if give else int(u * n_actions)
            else:
                qmax = q[s].max()
                n_best = 0
                a = 0
                for b in range(n_actions):
                    best[b] = q[s, b] == qmax
                    if best[b]:
                        n_best += 1
                        a = b
                if n_best > 1:
                    if give and ties_advice:
                        a = sample_action(row, rng.random(), best, n_actions)
                    else:
                        a = uniform_choice(best, rng.random(), n_actions)
            s2 = next_state[s, a]
            t += 1
            if s2 == goal:
                q[s, a] += alpha * (1000.0 - q[s, a])
                success = True
                break
            q[s, a] += alpha * (gamma * q[s2].max() - q[s, a])
            appended += 1
            if rule == GUIDE:
                g_heading, g_came = guide_append(  # the decision for s came just before
                    gmap, gparams, g_goals, g_ll, g_alive, g_doubt, s, a, advise, theta_w,
                    g_heading, g_pi, g_rows, True, g_comply, g_came, n_actions,
                )  # fmt: skip
            else:
                pos = push(ring, loglik, pos, appended, period, log_probs, s, a, n_actions)
            s = s2
            if step_budget > 0 and total_steps + t >= step_budget:
                break
        if rule == GUIDE and not success and t >= max_steps:
            # the session saw the last move and decided for where it led (Advisor.observe),
            # as a session kept for the next episode remembers
            _, _, g_target, _, g_given = guide_learner_decides(
                gmap, gparams, g_goals, g_ll, g_alive, g_target, g_heading, s, theta_w,
                g_scratch, g_comply, g_run, g_given, kappa, n_actions,
            )  # fmt: skip
        total_steps += t
        steps_out[e] = t
        success_out[e] = success
        advice_out[e] = n_advice
        decisions_out[e] = t  # the decisions the explorer acted on, one per move
        p_mean_out[e] = p_sum / t
        if step_budget > 0 and total_steps >= step_budget:
            return e + 1
    return episodes
