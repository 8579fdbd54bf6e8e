"""The reference explorers behave as specified, on hand-made maps and on random mazes."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from app.agents.explorers import (
    FIXED_EXPLORERS,
    BugExplorer,
    LeftExplorer,
    OptimalExplorer,
    RandomAvoidExplorer,
    make_explorer,
    sample_action,
    uniform_choice,
)
from app.agents.qlearning import QLearningExplorer
from app.domain.generate import generate_domain
from app.domain.grid import E, GridDomain, N, S, W

# A T-junction: from S heading north, the left-hand rule turns west at the top.
T_MAP = ["G...G", "##.##", "##S##"]


def walk(domain: GridDomain, explorer: LeftExplorer, goal: int, limit: int) -> list[int]:
    s, path = domain.start, [domain.start]
    for _ in range(limit):
        a = explorer.policy(s, np.random.default_rng(0))
        s2 = domain.step(s, a)
        explorer.observe(s, a, s2)
        s = s2
        path.append(s)
        if s == goal:
            break
    return path


def test_left_turns_left_at_a_t_junction() -> None:
    d = GridDomain.from_strings(T_MAP)
    walker = LeftExplorer(d)
    walker.reset(d.state(0, 0), np.random.default_rng(0))
    walker.heading = N
    path = walk(d, walker, d.state(0, 0), 10)
    assert [d.cell(s) for s in path] == [(2, 2), (1, 2), (0, 2), (0, 1), (0, 0)]


def test_left_prefers_left_then_straight_then_right_then_back() -> None:
    d = GridDomain.from_strings(["#.#", ".S.", "#.#", "#G#"])  # a crossroads
    centre = d.state(1, 1)
    walker = LeftExplorer(d)
    for heading, left in ((N, W), (E, N), (S, E), (W, S)):
        walker.heading = heading
        assert walker.policy(centre, np.random.default_rng(0)) == left
    dead_end = GridDomain.from_strings(["#G#", "#.#", "#S#"])
    walker = LeftExplorer(dead_end)
    walker.heading = S  # walls left, ahead and right: it turns back
    assert walker.policy(dead_end.start, np.random.default_rng(0)) == N


def test_left_heading_follows_moves_but_not_bumps() -> None:
    d = GridDomain.from_strings(T_MAP)
    walker = LeftExplorer(d)
    walker.heading = N
    walker.observe(d.start, W, d.start)  # bumped into a wall: heading kept
    assert walker.heading == N
    walker.observe(d.state(1, 2), N, d.state(0, 2))
    assert walker.heading == N
    walker.observe(d.state(0, 2), E, d.state(0, 3))
    assert walker.heading == E


@given(st.integers(0, 10_000), st.integers(0, 3))
def test_left_reaches_every_goal_of_a_perfect_maze(seed: int, heading: int) -> None:
    """A wall follower visits every cell of a maze without loops (a tree)."""
    d = generate_domain(11, 11, seed, braid=0.0, n_goals=3)
    for goal in d.goals:
        walker = LeftExplorer(d)
        walker.reset(goal, np.random.default_rng(0))
        walker.heading = heading
        path = walk(d, walker, goal, 4 * d.n_states)
        assert path[-1] == goal


@given(st.integers(0, 10_000), st.integers(0, 2**32 - 1))
def test_bug_reduces_the_distance_whenever_it_can(seed: int, rng_seed: int) -> None:
    d = generate_domain(11, 13, seed, braid=0.5, n_goals=4)
    rng = np.random.default_rng(rng_seed)
    bug = BugExplorer(d)
    for _ in range(30):
        goal = d.goals[int(rng.integers(len(d.goals)))]
        bug.reset(goal, rng)
        s = int(rng.integers(d.n_states))
        (r, c), (gr, gc) = d.cell(s), d.cell(goal)
        gap = abs(gr - r) + abs(gc - c)
        a = bug.policy(s, rng)
        nr, nc = d.cell(d.step(s, a))
        reducing = [m for m in range(4) if d.open_moves[s, m] and _gap(d, d.step(s, m), goal) < gap]
        if reducing:
            assert abs(gr - nr) + abs(gc - nc) == gap - 1
            larger_axis = (S if gr > r else N) if abs(gr - r) > abs(gc - c) else None
            if abs(gc - c) > abs(gr - r):
                larger_axis = E if gc > c else W
            if larger_axis is not None and d.open_moves[s, larger_axis]:
                assert a == larger_axis
        else:
            assert d.open_moves[s, a]  # escapes by an open move, never bumps


def _gap(d: GridDomain, s: int, goal: int) -> int:
    (r, c), (gr, gc) = d.cell(s), d.cell(goal)
    return abs(gr - r) + abs(gc - c)


@given(st.integers(0, 10_000), st.integers(0, 2**32 - 1))
def test_optimal_reaches_its_goal_in_exactly_the_bfs_distance(seed: int, rng_seed: int) -> None:
    d = generate_domain(13, 13, seed, braid=0.4, n_goals=5)
    rng = np.random.default_rng(rng_seed)
    walker = OptimalExplorer(d)
    for gi, goal in enumerate(d.goals):
        walker.reset(goal, rng)
        s, moves = d.start, 0
        while s != goal and moves <= d.n_states:
            s = d.step(s, walker.act(s, rng))
            moves += 1
        assert s == goal
        assert moves == d.goal_distances[gi, d.start]


@given(st.integers(0, 10_000), st.integers(0, 2**32 - 1))
def test_random_avoid_never_hits_a_wall(seed: int, rng_seed: int) -> None:
    d = generate_domain(9, 9, seed, braid=0.3, n_goals=2)
    rng = np.random.default_rng(rng_seed)
    walker = RandomAvoidExplorer(d)
    s = d.start
    for _ in range(200):
        s2 = d.step(s, walker.act(s, rng))
        assert s2 != s
        s = s2


def test_sample_action_is_the_inverse_cdf() -> None:
    weights = np.array([0.1, 0.2, 0.3, 0.4])
    n = 10_000
    counts = np.bincount([sample_action(weights, (k + 0.5) / n) for k in range(n)], minlength=4)
    np.testing.assert_array_equal(counts, (weights * n).round().astype(int))
    mask = np.array([False, True, False, True])
    picks = {sample_action(weights, (k + 0.5) / 100, mask) for k in range(100)}
    assert picks == {1, 3}
    assert sample_action(weights, 1.0 - 1e-17) == 3


def test_uniform_choice_covers_the_allowed_actions_evenly() -> None:
    mask = np.array([True, False, True, True])
    picks = [uniform_choice(mask, (k + 0.5) / 300) for k in range(300)]
    assert np.bincount(picks, minlength=4).tolist() == [100, 0, 100, 100]


@pytest.mark.parametrize("name", FIXED_EXPLORERS)
def test_advised_fixed_explorer_samples_the_advice(name: str) -> None:
    d = generate_domain(9, 9, 1, braid=0.3, n_goals=2)
    explorer = make_explorer(name, d)
    rng = np.random.default_rng(5)
    explorer.reset(d.goals[0], rng)
    advice = np.array([0.0, 0.0, 1.0, 0.0])
    assert all(explorer.act(d.start, rng, advice) == S for _ in range(50))
    advice = np.array([0.5, 0.0, 0.0, 0.5])
    picks = np.bincount([explorer.act(d.start, rng, advice) for _ in range(4000)], minlength=4)
    assert picks[1] == picks[2] == 0
    assert abs(picks[0] - 2000) < 200  # 6 standard deviations


def test_make_explorer_rejects_unknown_names() -> None:
    with pytest.raises(ValueError, match="unknown explorer 'drunk'"):
        make_explorer("drunk", GridDomain.from_strings(T_MAP))


def test_q_learning_update_is_the_textbook_rule() -> None:
    d = GridDomain.from_strings(["S..G"])
    q = QLearningExplorer(d, alpha=0.5, gamma=0.9, epsilon=0.0)
    q.reset(d.goals[0], np.random.default_rng(0))
    a, b, c = d.state(0, 1), d.state(0, 2), d.goals[0]
    assert q.learn(b, E, c) == 1000.0
    assert q.q[b, E] == 500.0  # 0 + 0.5 * (1000 - 0), no bootstrap at the goal
    assert q.learn(a, E, b) == 0.0
    assert q.q[a, E] == pytest.approx(0.5 * 0.9 * 500.0)


def test_q_learning_explores_with_the_advice_and_breaks_ties_with_it() -> None:
    d = GridDomain.from_strings(["S..G"])
    rng = np.random.default_rng(0)
    advice = np.array([0.0, 0.0, 0.0, 1.0])
    explorer = QLearningExplorer(d, epsilon=1.0)
    assert all(explorer.act(d.start, rng, advice) == W for _ in range(50))
    tie_breaker = QLearningExplorer(d, epsilon=0.0, ties="advice")
    assert all(tie_breaker.act(d.start, rng, advice) == W for _ in range(50))
    uniform = QLearningExplorer(d, epsilon=0.0, ties="uniform")
    assert len({uniform.act(d.start, rng, advice) for _ in range(200)}) == 4
    uniform.q[d.start, E] = 1.0  # a learned preference beats the advice
    assert all(uniform.act(d.start, rng, advice) == E for _ in range(20))


def test_q_learning_learns_a_corridor() -> None:
    d = GridDomain.from_strings(["S.....G"])
    learner = QLearningExplorer(d, alpha=0.5, gamma=0.9, epsilon=0.1)
    rng = np.random.default_rng(1)
    learner.reset(d.goals[0], rng)
    for _ in range(200):
        s = d.start
        for _ in range(100):
            a = learner.act(s, rng)
            s2 = d.step(s, a)
            learner.learn(s, a, s2)
            s = s2
            if s == d.goals[0]:
                break
    assert all(learner.greedy_action(s, rng) == E for s in range(d.n_states - 1))


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [({"alpha": 0.0}, "alpha"), ({"epsilon": 1.5}, "epsilon"), ({"ties": "coin"}, "ties")],
)
def test_q_learning_rejects_bad_settings(kwargs: dict[str, object], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        QLearningExplorer(GridDomain.from_strings(T_MAP), **kwargs)  # type: ignore[arg-type]
