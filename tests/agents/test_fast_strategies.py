"""The compiled strategies kernel makes the reference advisors' decisions and moves."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.advice.goals import GoalAwareAdvisor, GoalPriors
from app.advice.models import AdviceTables
from app.advice.strategies import STRATEGIES, StrategyParams, make_advisor
from app.agents.episodes import run_episode
from app.agents.experts import train_goal_priors, train_prior
from app.agents.explorers import FIXED_EXPLORERS, make_explorer
from app.agents.fast_strategies import StrategySimulator
from app.domain.generate import generate_domain
from app.domain.grid import GridDomain


def world(seed: int, alpha0: float = 1.0) -> tuple[StrategySimulator, AdviceTables, GoalPriors]:
    d = generate_domain(9, 11, seed, braid=0.3, n_goals=3)
    prior, goal_priors = train_goal_priors(d, np.random.default_rng(seed), "start", 2, alpha0)
    tables = AdviceTables.paper(prior.theta())
    return StrategySimulator(d, tables, goal_priors), tables, goal_priors


@settings(max_examples=30, deadline=None)
@given(
    st.integers(0, 10_000),
    st.sampled_from(STRATEGIES),
    st.sampled_from(FIXED_EXPLORERS),
    st.sampled_from([0.0, 0.3, 0.7]),
    st.integers(3, 40),
    st.sampled_from([0.0, 0.5, 1.0]),
    st.booleans(),
)
def test_compiled_strategy_follows_the_reference_advisor(
    seed: int,
    strategy: str,
    explorer: str,
    kappa: float,
    window: int,
    beta: float,
    advised: bool,
) -> None:
    sim, tables, goal_priors = world(seed, alpha0=(0.1, 1.0)[seed % 2])
    d = sim.domain
    rng = np.random.default_rng(seed)
    params = StrategyParams(
        n_steps=int(rng.integers(0, 60)),
        threshold=float(rng.choice([0.1, 0.3, 0.5, 0.9])),
        rate=float(rng.choice([0.05, 0.3])),
        beta=beta,
        seed=seed,
    )
    goal = d.goals[seed % len(d.goals)]
    fast = sim.run(
        explorer,
        strategy,
        goal,
        np.random.default_rng(seed),
        advised=advised,
        kappa=kappa,
        window=window,
        params=params,
        max_steps=1200,  # past the exact re-sum (1,024 pairs) when the task is not solved
    )
    advisor = make_advisor(strategy, tables, kappa, window, params, goal_priors)
    ref = run_episode(
        d,
        make_explorer(explorer, d),
        advisor,
        goal,
        np.random.default_rng(seed),
        advised=advised,
        max_steps=1200,
    )
    assert fast.success == ref.success
    assert fast.steps == ref.steps
    assert fast.states.tolist() == ref.states
    assert fast.advise.tolist() == [dec.advise for dec in ref.decisions]
    assert fast.advice_count == ref.advice_count
    # goal-aware advice: numpy on four-element rows in the reference, so equal to 1e-12
    assert fast.benefit == pytest.approx(ref.decisions[-1].benefit, rel=1e-12, abs=1e-12)
    if isinstance(advisor, GoalAwareAdvisor):
        assert fast.goals_ruled_out == sum(not alive for alive in advisor.alive)


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
    sim = StrategySimulator(d, AdviceTables.paper(prior.theta()), goal_priors)
    left, right = d.goals
    escaped = {}
    for strategy in ("paper", "goal_aware"):
        runs = [
            sim.run("random", strategy, right, np.random.default_rng(i), kappa=0.0, max_steps=40)
            for i in range(50)
        ]
        trapped = [r for r in runs if left in r.states.tolist()]
        assert len(trapped) > 10 and all(r.advise.all() for r in runs)
        escaped[strategy] = sum(r.success for r in trapped)
        if strategy == "goal_aware":
            assert all(r.goals_ruled_out == 1 for r in trapped)
    assert escaped["paper"] == 0
    assert escaped["goal_aware"] >= 5


def test_strategy_simulator_rejects_bad_arguments() -> None:
    sim, _, goal_priors = world(1)
    goal = sim.domain.goals[0]
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="unknown strategy 'loud'"):
        sim.run("random", "loud", goal, rng)
    with pytest.raises(ValueError, match="unknown explorer"):
        sim.run("teleport", "paper", goal, rng)
    with pytest.raises(ValueError, match="rate and beta"):
        sim.run("random", "random", goal, rng, params=StrategyParams(rate=2.0))
    with pytest.raises(ValueError, match="kappa"):
        sim.run("random", "paper", goal, rng, kappa=-1.0)
    other_d = generate_domain(7, 7, 0)
    other, _ = train_goal_priors(other_d, np.random.default_rng(0), "start", 1)
    with pytest.raises(ValueError, match="same states"):
        StrategySimulator(other_d, AdviceTables.paper(other.theta()), goal_priors)
