"""The compiled kernels (app/kernels.py) make exactly the draws, moves and decisions of the
reference loops, advisors and explorers, for every strategy and explorer, over random tables
with two or three behaviour models and arbitrary weights: equal to the last bit."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app import kernels, strategies
from app.advice.advisor import Advisor
from app.advice.models import AdviceTables
from app.advice.params import StrategyParams
from app.advice.priors import GoalPriors
from app.agents.episodes import EpisodeRecord, run_episode, run_learning
from app.agents.experts import train_goal_priors, train_prior
from app.agents.explorers import (
    FIXED_EXPLORERS,
    WALKERS,
    Visitor,
    make_explorer,
    read_position,
)
from app.agents.qlearning import QLearningExplorer
from app.agents.simulate import EXPLORER_CODES, FixedRun, QParams, Simulator
from app.domain.floorplans import generate_floors
from app.domain.generate import generate_domain
from app.domain.grid import GridDomain
from app.strategies import make_advisor, names
from tests.tables import random_tables, split_weight_tables

STRATEGIES = names()

finite = st.floats(allow_nan=False, allow_infinity=False, min_value=-1e300, max_value=1e300)


@given(st.lists(finite | st.sampled_from([1e-16, 1.0, 1e16, -1e16, 0.1, -0.0]), max_size=60))
def test_fsum_is_cpython_fsum(values: list[float]) -> None:
    assert kernels.fsum(np.array(values, dtype=np.float64)) == math.fsum(values)


def test_fsum_rounds_half_even_across_partials() -> None:
    for values in ([1e-16, 1.0, 1e16], [1.0, 1e100, 1.0, -1e100], [0.1] * 10):
        assert kernels.fsum(np.array(values)) == math.fsum(values)


def test_kernel_codes_name_every_explorer_and_strategy() -> None:
    assert set(EXPLORER_CODES) == set(WALKERS)
    assert len(set(EXPLORER_CODES.values())) == len(EXPLORER_CODES)
    codes = [strategies.get(name).kernel for name in STRATEGIES]
    assert None not in codes and len(set(codes)) == len(codes)  # each compiled, its own code


def world(seed: int, n_models: int) -> tuple[GridDomain, AdviceTables, GoalPriors]:
    """A small braided maze, per-goal counts from experts, and tables over their pooled theta
    with 2 or 3 models of random weights."""
    d = generate_domain(9, 11, seed, braid=0.3, n_goals=3)
    alpha0 = (0.1, 1.0, 5.0)[seed % 3]
    prior, goal_priors = train_goal_priors(d, np.random.default_rng(seed), "start", 2, alpha0)
    tables = random_tables(np.random.default_rng(seed + 1), d.n_states, n_models, prior.theta())
    return d, tables, goal_priors


@settings(max_examples=60, deadline=None)
@given(
    st.integers(0, 10_000),
    st.sampled_from(STRATEGIES),
    st.sampled_from(FIXED_EXPLORERS),
    st.sampled_from([0.0, 0.3, 0.7]),
    st.integers(3, 40),
    st.sampled_from([0.0, 0.5, 1.0]),
    st.booleans(),
    st.sampled_from([2, 3]),
)
def test_compiled_episode_follows_the_reference_loop(
    seed: int, strategy: str, explorer: str, kappa: float, window: int, beta: float,
    advised: bool, n_models: int,
) -> None:  # fmt: skip
    d, tables, goal_priors = world(seed, n_models)
    rng = np.random.default_rng(seed)
    params = StrategyParams(
        n_steps=int(rng.integers(0, 60)),
        threshold=float(rng.choice([0.1, 0.3, 0.5, 0.9])),
        rate=float(rng.choice([0.05, 0.3])),
        beta=beta,
        seed=seed,
        p_lost=float(rng.choice([0.05, 0.5, 0.9])),
        slack=float(rng.choice([0.1, 0.5, 1.0])),
        spread=float(rng.choice([0.0, 0.1, 0.6])),
    )
    goal = d.goals[seed % len(d.goals)]
    sim = Simulator(d, tables, goal_priors)  # its guide map (lead values) read by both
    fast = sim.fixed(
        explorer, goal, np.random.default_rng(seed), advised=advised, strategy=strategy,
        kappa=kappa, window=window, params=params,
        max_steps=1200,  # past the exact re-sum (1,024 pairs) when the task is not solved
    )  # fmt: skip
    guide = sim.guide
    advisor = make_advisor(strategy, tables, kappa, window, params, goal_priors, guide)
    ref = run_episode(
        d, make_explorer(explorer, d), advisor, goal, np.random.default_rng(seed),
        advised=advised, max_steps=1200,
    )  # fmt: skip
    assert fast.success == ref.success
    assert fast.steps == ref.steps
    assert fast.states.tolist() == ref.states
    assert fast.advise.tolist() == [dec.advise for dec in ref.decisions]
    assert fast.advice_count == ref.advice_count
    assert fast.benefit == ref.decisions[-1].benefit
    if strategy in ("paper", "goal_aware", "guide"):  # the others: P(M1 | H) where it is read
        assert fast.p_normal.tolist() == [dec.p_normal for dec in ref.decisions]
    beliefs = advisor.goal_beliefs()
    assert fast.goals_ruled_out == (sum(out for *_, out in beliefs) if beliefs else 0)


def assert_same_run(fast: FixedRun, ref: EpisodeRecord, strategy: str) -> None:
    """The compiled run made the reference loop's moves and decisions (P(M1 | H) where the
    strategy reads it)."""
    assert (fast.success, fast.steps) == (ref.success, ref.steps)
    assert fast.states.tolist() == ref.states
    assert fast.advise.tolist() == [dec.advise for dec in ref.decisions]
    assert fast.benefit == ref.decisions[-1].benefit
    if strategy in ("paper", "goal_aware", "guide"):
        assert fast.p_normal.tolist() == [dec.p_normal for dec in ref.decisions]


@settings(max_examples=40, deadline=None)
@given(
    st.integers(0, 10_000),
    st.sampled_from(STRATEGIES),
    st.sampled_from(WALKERS),
    st.sampled_from([0.0, 0.3, 1.0]),
    st.sampled_from([0.0, 0.1, 0.5, 1.0]),
    st.sampled_from([0, 1, 4]),
    st.booleans(),
    st.booleans(),
)
def test_compiled_visitor_follows_the_reference_loop(
    seed: int, strategy: str, walker: str, compliance: float, noise: float, sight: int,
    anywhere: bool, advised: bool,
) -> None:  # fmt: skip
    """Visitors (compliance, readings one cell off, sight, any free cell as the goal, the
    corridor and straight walkers) make the reference loop's draws, moves and decisions."""
    d, tables, goal_priors = world(seed, 2 + seed % 2)
    rng = np.random.default_rng(seed)
    params = StrategyParams(
        n_steps=int(rng.integers(0, 60)), threshold=0.3, rate=0.3, beta=float(seed % 2),
        seed=seed, p_lost=float(rng.choice([0.05, 0.5])), slack=0.5, spread=0.05,
    )  # fmt: skip
    cells = [c for c in range(d.n_states) if c != d.start]
    goal = cells[seed % len(cells)] if anywhere else d.goals[seed % len(d.goals)]
    kappa, window = float(rng.choice([0.0, 0.3, 0.7])), int(rng.integers(3, 40))
    sim = Simulator(d, tables, goal_priors)  # its guide map (lead values) read by both
    fast = sim.fixed(
        walker, goal, np.random.default_rng(seed), advised=advised, strategy=strategy,
        kappa=kappa, window=window, params=params, max_steps=600, compliance=compliance,
        noise=noise, sight=sight, seen_rng=np.random.default_rng(seed + 7),
    )  # fmt: skip
    advisor = make_advisor(strategy, tables, kappa, window, params, goal_priors, sim.guide)
    ref = run_episode(
        d, make_explorer(walker, d), advisor, goal, np.random.default_rng(seed),
        advised=advised, max_steps=600, compliance=compliance, noise=noise, sight=sight,
        seen_rng=np.random.default_rng(seed + 7),
    )  # fmt: skip
    assert_same_run(fast, ref, strategy)


@settings(max_examples=20, deadline=None)
@given(
    st.integers(0, 10_000),
    st.sampled_from(["random-avoid", "optimal", "corridor"]),
    st.sampled_from([0.0, 0.5]),
)
def test_exact_positions_walk_each_move_as_its_event(seed: int, walker: str, kappa: float) -> None:
    """Fed positions read exactly, a walker that never walks into a wall (and ignores the
    advice, which may point into one) is walked one cell a move, so the service's advisor
    decides as on its events: the walked loop makes the compiled loop's moves, draws and
    decisions (guide, and the paper's rule)."""
    d, tables, goal_priors = world(seed, 2 + seed % 2)
    sim = Simulator(d, tables, goal_priors)
    goal = d.goals[seed % len(d.goals)]
    for strategy in ("guide", "paper"):
        walked = sim.fixed(
            walker, goal, np.random.default_rng(seed), advised=True, strategy=strategy,
            kappa=kappa, max_steps=400, feed="positions", seen_rng=np.random.default_rng(1),
            compliance=0.0,
        )  # fmt: skip
        ref = sim.fixed(
            walker, goal, np.random.default_rng(seed), advised=True, strategy=strategy,
            kappa=kappa, max_steps=400, compliance=0.0,
        )  # fmt: skip
        assert (walked.success, walked.steps) == (ref.success, ref.steps)
        assert walked.states.tolist() == ref.states.tolist()
        assert walked.advise.tolist() == ref.advise.tolist()
        assert walked.advice_count == ref.advice_count
        # (guide may leave a walker alone: one that walked a shortest path so far has a purpose)
        assert walked.advice_count > 0 or kappa > 0.0 or strategy == "guide"


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 10_000), st.integers(1, 4))
def test_a_reading_jumps_at_most_j_moves(seed: int, jump: int) -> None:
    d = world(seed, 2)[0]
    rng = np.random.default_rng(seed)
    for x in rng.integers(0, d.n_states, 30).tolist():
        seen = read_position(d, x, 1.0, rng, jump)
        assert 0 <= d.distances_to(x)[seen] <= jump


def test_a_full_compliance_visitor_is_the_paper_s_explorer() -> None:
    """p = 1, q = 0, r = 0 make the draws of today's explorer (no compliance draw, no
    reading drawn): the same run whatever the readings' generator."""
    d, tables, goal_priors = world(5, 2)
    sim = Simulator(d, tables, goal_priors)
    for walker in FIXED_EXPLORERS:
        a = sim.fixed(walker, d.goals[1], np.random.default_rng(3), advised=True,
                      strategy="guide", max_steps=500)  # fmt: skip
        b = sim.fixed(walker, d.goals[1], np.random.default_rng(3), advised=True,
                      strategy="guide", max_steps=500, compliance=1.0, noise=0.0, sight=0,
                      seen_rng=np.random.default_rng(99))  # fmt: skip
        assert a.states.tolist() == b.states.tolist()
        assert a.advise.tolist() == b.advise.tolist()


def test_visitor_walkers_and_sight() -> None:
    """The corridor walker never turns back in a corridor, the straight one keeps its
    heading, and a visitor with its goal in sight walks straight to it."""
    d = GridDomain.from_strings(["S.........G"])
    sim = Simulator(d, AdviceTables.paper(np.full((d.n_states, 4), 0.25)))
    for walker in ("corridor", "straight"):
        for i in range(20):
            run = sim.fixed(walker, d.goals[0], np.random.default_rng(i), advised=False)
            assert run.success and run.steps == 10  # east at once, or back from the wall
    near = sim.fixed("random", d.goals[0], np.random.default_rng(0), advised=False, sight=10)
    assert near.success and near.steps == 10
    far = sim.fixed("random", d.goals[0], np.random.default_rng(0), advised=False, sight=3)
    assert far.steps > 10


def test_visitor_specs() -> None:
    v = Visitor.parse("corridor  q=0.1 p=0.5 r=8 anywhere")
    assert (v.walker, v.compliance, v.noise, v.sight, v.anywhere) == ("corridor", 0.5, 0.1, 8, True)
    assert v.name == "corridor p=0.5 q=0.1 r=8 anywhere"
    assert Visitor.parse("random destinations").name == "random"
    w = Visitor.parse("random positions j=3 q=0.1")
    assert (w.feed, w.jump, w.noise) == ("positions", 3, 0.1)
    assert w.name == "random q=0.1 j=3 positions" and Visitor.parse(w.name) == w
    assert Visitor.parse("random events").name == "random"
    for bad, says in (
        ("random j=0", "j \\(jump\\)"),
        ("random q=0.1 j=3", "add 'positions'"),
        ("random j=1.5", "not a number"),
        ("random metres", "is not one of"),
        ("", "empty"),
        ("teleport", "unknown walker"),
        ("random p=2", "from 0 to 1"),
        ("random x=1", "is not one of"),
        ("random p=a", "not a number"),
        ("random p=0.5 p=0.4", "twice"),
        ("random r=-1", "r \\(sight\\)"),
    ):
        with pytest.raises(ValueError, match=says):
            Visitor.parse(bad)


@settings(max_examples=25, deadline=None)
@given(
    st.integers(0, 10_000),
    st.booleans(),
    st.booleans(),
    st.sampled_from(["advice", "uniform"]),
    st.sampled_from([0.05, 0.3]),
    st.sampled_from([2, 3]),
)
def test_learning_kernel_follows_the_reference_q_learner(
    seed: int, advised: bool, keep_history: bool, ties: str, epsilon: float, n_models: int
) -> None:
    d, tables, _ = world(seed, n_models)
    goal = d.goals[seed % len(d.goals)]
    params = QParams(alpha=0.3, gamma=0.9, epsilon=epsilon, ties=ties)
    fast = Simulator(d, tables).learning(
        goal, np.random.default_rng(seed), advised=advised, params=params, episodes=25,
        max_steps=60, keep_history=keep_history, kappa=0.4, window=50,
    )  # fmt: skip
    learner = QLearningExplorer(d, 0.3, 0.9, epsilon, ties)  # type: ignore[arg-type]
    ref = run_learning(
        d, learner, Advisor(tables, 0.4, 50), goal, np.random.default_rng(seed), episodes=25,
        advised=advised, max_steps=60, keep_history=keep_history,
    )  # fmt: skip
    assert fast.steps.tolist() == [r.steps for r in ref]
    assert fast.success.tolist() == [r.success for r in ref]
    assert fast.advice_count.tolist() == [r.advice_count for r in ref]
    np.testing.assert_array_equal(fast.q, learner.q)
    # a mean over each episode's decisions (summed in another order), not a decision
    means = [math.fsum(x.p_normal for x in r.decisions) / len(r.decisions) for r in ref]
    np.testing.assert_allclose(fast.p_normal_mean, means, rtol=1e-12)


@settings(max_examples=20, deadline=None)
@given(
    st.integers(0, 10_000),
    st.booleans(),
    st.booleans(),
    st.sampled_from(["advice", "uniform"]),
    st.sampled_from([2, 3]),
    st.sampled_from([0.02, 0.1, 0.3]),
    st.sampled_from(["paper", "guide"]),
)
def test_learning_kernel_follows_the_reference_q_learner_in_a_building(
    seed: int, advised: bool, keep_history: bool, ties: str, floors: int, kappa: float,
    strategy: str,
) -> None:  # fmt: skip
    """Six actions: the compiled Q-learner (Q (S, 6)) learns, draws and is advised by the
    paper's rule or guide as the reference learner is."""
    b = generate_floors(16, 16, floors, np.random.default_rng(seed), n_goals=2, room=(3, 5))
    prior, goal_priors = train_goal_priors(b, np.random.default_rng(seed), "start", 2, 1.0)
    tables = random_tables(np.random.default_rng(seed + 1), b.n_states, 2 + seed % 2,
                           prior.theta())  # fmt: skip
    goal = b.goals[seed % len(b.goals)]
    params = QParams(alpha=0.3, gamma=0.9, epsilon=0.3, ties=ties)
    sim = Simulator(b, tables, goal_priors)
    fast = sim.learning(
        goal, np.random.default_rng(seed), advised=advised, params=params, episodes=15,
        max_steps=200, keep_history=keep_history, kappa=kappa, window=40, strategy=strategy,
    )  # fmt: skip
    learner = QLearningExplorer(b, 0.3, 0.9, 0.3, ties)  # type: ignore[arg-type]
    advisor = make_advisor(strategy, tables, kappa, 40, None, goal_priors, sim.guide)
    ref = run_learning(
        b, learner, advisor, goal, np.random.default_rng(seed), episodes=15,
        advised=advised, max_steps=200, keep_history=keep_history,
    )  # fmt: skip
    assert fast.q.shape == (b.n_states, 6)
    assert fast.steps.tolist() == [r.steps for r in ref]
    assert fast.success.tolist() == [r.success for r in ref]
    assert fast.advice_count.tolist() == [r.advice_count for r in ref]
    np.testing.assert_array_equal(fast.q, learner.q)


@pytest.mark.parametrize("explorer", FIXED_EXPLORERS)
def test_compiled_episode_reads_the_core_s_log_weights(explorer: str) -> None:
    """Weights whose log numpy and libm round differently: the kernels read the tables' own."""
    d, _, goal_priors = world(7, 3)
    tables = split_weight_tables(np.random.default_rng(7), d.n_states)
    for i, strategy in enumerate(("paper", "goal_aware")):
        fast = Simulator(d, tables, goal_priors).fixed(
            explorer, d.goals[i], np.random.default_rng(i), advised=True, strategy=strategy,
            kappa=0.3, window=40, max_steps=1500,
        )  # fmt: skip
        advisor = make_advisor(strategy, tables, 0.3, 40, None, goal_priors)
        ref = run_episode(d, make_explorer(explorer, d), advisor, d.goals[i],
                          np.random.default_rng(i), advised=True, max_steps=1500)  # fmt: skip
        assert fast.states.tolist() == ref.states
        assert fast.p_normal.tolist() == [dec.p_normal for dec in ref.decisions]
        assert fast.benefit == ref.decisions[-1].benefit


def test_step_budget_stops_learning_mid_episode() -> None:
    d, tables, _ = world(3, 2)
    run = Simulator(d, tables).learning(
        d.goals[0], np.random.default_rng(0), advised=True, episodes=100, max_steps=7,
        step_budget=30,
    )  # fmt: skip
    assert run.steps.sum() == 30
    assert len(run.steps) <= 5


def test_goal_priors_share_the_pooled_prior_with_train_prior() -> None:
    d = generate_domain(11, 11, 3, braid=0.2, n_goals=4)
    prior, goal_priors = train_goal_priors(d, np.random.default_rng(5), "start", 3, 0.5)
    same = train_prior(d, np.random.default_rng(5), "start", 3, 0.5)
    np.testing.assert_array_equal(prior.theta(), same.theta())
    np.testing.assert_allclose(goal_priors.pooled_theta(), prior.theta(), atol=1e-12)
    assert goal_priors.goal_counts.sum(axis=(1, 2)).min() > 0  # every goal has its own data


def test_goal_aware_lets_an_explorer_out_of_another_goals_dead_end() -> None:
    # a corridor with a goal at each end, the start in the middle; experts walk to both, so
    # each half of the corridor advises towards its end. Always advised (kappa 0), a random
    # walker whose goal is on the right and that reached the left goal is held there by the
    # paper's advice; goal-aware advice rules the left goal out and stops pointing at it.
    d = GridDomain.from_strings(["G...S...G"])
    prior, goal_priors = train_goal_priors(d, np.random.default_rng(0), "start", 5, 0.1)
    sim = Simulator(d, AdviceTables.paper(prior.theta()), goal_priors)
    left, right = d.goals
    escaped = {}
    for strategy in ("paper", "goal_aware"):
        runs = [
            sim.fixed(
                "random",
                right,
                np.random.default_rng(i),
                advised=True,
                strategy=strategy,
                kappa=0.0,
                max_steps=40,
            )
            for i in range(50)
        ]
        trapped = [r for r in runs if left in r.states.tolist()]
        assert len(trapped) > 10 and all(r.advise.all() for r in runs)
        escaped[strategy] = sum(r.success for r in trapped)
        if strategy == "goal_aware":
            assert all(r.goals_ruled_out == 1 for r in trapped)
    assert escaped["paper"] == 0
    assert escaped["goal_aware"] >= 5


def test_simulator_rejects_bad_arguments() -> None:
    d, tables, goal_priors = world(1, 2)
    sim = Simulator(d, tables, goal_priors)
    goal = d.goals[0]
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="unknown explorer 'teleport'"):
        sim.fixed("teleport", goal, rng, advised=True)
    with pytest.raises(ValueError, match="unknown strategy 'loud'"):
        sim.fixed("random", goal, rng, advised=True, strategy="loud")
    with pytest.raises(ValueError, match=r"rate must be a finite number from 0\.0 to 1\.0"):
        sim.fixed(
            "random", goal, rng, advised=True, strategy="random", params=StrategyParams(rate=2.0)
        )
    with pytest.raises(ValueError, match="kappa"):
        sim.fixed("random", goal, rng, advised=True, kappa=-1.0)
    with pytest.raises(ValueError, match="needs the experts' goals"):
        Simulator(d, tables).fixed("random", goal, rng, advised=True, strategy="goal_aware")
    with pytest.raises(ValueError, match="ties"):
        QParams(ties="coin")
    other = generate_domain(7, 7, 0)
    with pytest.raises(ValueError, match="states"):
        Simulator(other, tables)


@settings(max_examples=80, deadline=None)
@given(
    st.integers(0, 10_000),
    st.sampled_from(STRATEGIES),
    st.sampled_from(WALKERS),
    st.sampled_from([2, 3]),
    st.sampled_from([1.0, 0.5]),
    st.sampled_from([0.0, 0.1]),
    st.sampled_from([0, 3]),
    st.booleans(),
)
def test_compiled_episode_follows_the_reference_loop_in_a_building(
    seed: int, strategy: str, explorer: str, floors: int, compliance: float, noise: float,
    sight: int, advised: bool,
) -> None:  # fmt: skip
    """A building of several floors (six actions, rides): the compiled episode makes the
    reference loop's draws, moves and decisions for every walker (the compass walkers' rides
    and headings included), every strategy (guide's parameters drawn too), visitors'
    compliance, noise and sight."""
    b = generate_floors(20, 20, floors, np.random.default_rng(seed), n_goals=2, room=(3, 5))
    prior, goal_priors = train_goal_priors(b, np.random.default_rng(seed), "start", 2, 1.0)
    tables = random_tables(np.random.default_rng(seed + 1), b.n_states, 2 + seed % 2,
                           prior.theta())  # fmt: skip
    rng = np.random.default_rng(seed)
    params = StrategyParams(
        n_steps=int(rng.integers(0, 60)), threshold=float(rng.choice([0.1, 0.3, 0.5])),
        rate=0.3, beta=float(seed % 2), seed=seed, p_lost=float(rng.choice([0.05, 0.5, 0.9])),
        slack=float(rng.choice([0.1, 0.5, 1.0])), spread=float(rng.choice([0.0, 0.1, 0.6])),
    )  # fmt: skip
    goal = b.goals[seed % len(b.goals)]
    kappa, window = float(rng.choice([0.0, 0.3, 0.7])), int(rng.integers(3, 40))
    sim = Simulator(b, tables, goal_priors)
    fast = sim.fixed(
        explorer, goal, np.random.default_rng(seed), advised=advised, strategy=strategy,
        kappa=kappa, window=window, params=params, max_steps=1100, compliance=compliance,
        noise=noise, sight=sight, seen_rng=np.random.default_rng(seed + 7),
    )  # fmt: skip
    advisor = make_advisor(strategy, tables, kappa, window, params, goal_priors, sim.guide)
    ref = run_episode(
        b, make_explorer(explorer, b), advisor, goal, np.random.default_rng(seed),
        advised=advised, max_steps=1100, compliance=compliance, noise=noise, sight=sight,
        seen_rng=np.random.default_rng(seed + 7),
    )  # fmt: skip
    assert_same_run(fast, ref, strategy)
    beliefs = advisor.goal_beliefs()
    assert fast.goals_ruled_out == (sum(out for *_, out in beliefs) if beliefs else 0)
