"""The compiled kernels make exactly the decisions and moves of the reference code."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.advice.advisor import Advisor
from app.advice.models import AdviceTables, BehaviourModel
from app.agents.episodes import run_episode, run_learning
from app.agents.experts import train_prior
from app.agents.explorers import FIXED_EXPLORERS, make_explorer
from app.agents.fast_advisor import FlatTables, fsum
from app.agents.qlearning import QLearningExplorer
from app.agents.simulate import QParams, Simulator
from app.domain.generate import generate_domain
from app.domain.grid import GridDomain

finite = st.floats(allow_nan=False, allow_infinity=False, min_value=-1e300, max_value=1e300)


@given(st.lists(finite | st.sampled_from([1e-16, 1.0, 1e16, -1e16, 0.1, -0.0]), max_size=60))
def test_fsum_is_cpython_fsum(values: list[float]) -> None:
    assert fsum(np.array(values, dtype=np.float64)) == math.fsum(values)


def test_fsum_rounds_half_even_across_partials() -> None:
    for values in ([1e-16, 1.0, 1e16], [1.0, 1e100, 1.0, -1e100], [0.1] * 10):
        assert fsum(np.array(values)) == math.fsum(values)


def random_tables(d: GridDomain, seed: int, extra_model: bool) -> AdviceTables:
    rng = np.random.default_rng(seed)
    source = ("start", "anywhere", "policy")[seed % 3]
    alpha0 = float(rng.choice([0.05, 0.5, 1.0, 5.0]))
    theta = train_prior(d, rng, source, int(rng.integers(1, 4)), alpha0).theta()  # type: ignore[arg-type]
    if not extra_model:
        return AdviceTables.paper(theta)
    p = rng.dirichlet(np.ones(4), size=d.n_states)
    return AdviceTables.with_models(theta, [BehaviourModel("other", p, 0.3)])


@settings(max_examples=40)
@given(
    st.integers(0, 10_000),
    st.integers(1, 25),
    st.sampled_from([0.0, 0.1, 0.5, 1.0, 1.386]),
    st.booleans(),
)
def test_compiled_advisor_makes_the_core_advisors_decisions(
    seed: int, window: int, kappa: float, extra_model: bool
) -> None:
    d = generate_domain(9, 11, seed, braid=0.3, n_goals=3)
    tables = random_tables(d, seed, extra_model)
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 2600))  # past the exact re-sum (>= 1024 pairs) in most examples
    states = rng.integers(0, d.n_states, n)
    actions = rng.integers(0, 4, n)
    nexts = d.next_state[states, actions]
    start = int(rng.integers(d.n_states))
    kl, p_normal = FlatTables(tables).stream(window, start, states, actions, nexts)
    core = Advisor(tables, kappa=kappa, window=window)
    decisions = [core.start(start)]
    decisions += [
        core.observe(int(s), int(a), int(t)) for s, a, t in zip(states, actions, nexts, strict=True)
    ]
    assert [dec.advise for dec in decisions] == (kl >= kappa).tolist()
    # the same operations in the same order: equal to the last bit, not only within 1e-9
    assert kl.tolist() == [dec.kl for dec in decisions]
    assert p_normal.tolist() == [dec.p_normal for dec in decisions]


def small_world(seed: int) -> tuple[GridDomain, AdviceTables]:
    d = generate_domain(9, 9, seed, braid=0.3, n_goals=3)
    return d, random_tables(d, seed, extra_model=False)


@settings(max_examples=30)
@given(
    st.integers(0, 10_000),
    st.sampled_from(FIXED_EXPLORERS),
    st.booleans(),
    st.sampled_from([0.0, 0.3, 0.8]),
    st.integers(3, 40),
)
def test_fixed_kernel_follows_the_reference_explorer(
    seed: int, name: str, advised: bool, kappa: float, window: int
) -> None:
    d, tables = small_world(seed)
    goal = d.goals[seed % len(d.goals)]
    fast = Simulator(d, tables).fixed(
        name,
        goal,
        np.random.default_rng(seed),
        advised=advised,
        kappa=kappa,
        window=window,
        max_steps=1200,
    )
    ref = run_episode(
        d,
        make_explorer(name, d),
        Advisor(tables, kappa, window),
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
    assert fast.p_normal.tolist() == [dec.p_normal for dec in ref.decisions]


@settings(max_examples=20)
@given(
    st.integers(0, 10_000),
    st.booleans(),
    st.booleans(),
    st.sampled_from(["advice", "uniform"]),
    st.sampled_from([0.05, 0.3]),
)
def test_learning_kernel_follows_the_reference_q_learner(
    seed: int, advised: bool, keep_history: bool, ties: str, epsilon: float
) -> None:
    d, tables = small_world(seed)
    goal = d.goals[seed % len(d.goals)]
    params = QParams(alpha=0.3, gamma=0.9, epsilon=epsilon, ties=ties)
    fast = Simulator(d, tables).learning(
        goal,
        np.random.default_rng(seed),
        advised=advised,
        params=params,
        episodes=25,
        max_steps=60,
        keep_history=keep_history,
        kappa=0.4,
        window=50,
    )
    learner = QLearningExplorer(d, 0.3, 0.9, epsilon, ties)  # type: ignore[arg-type]
    ref = run_learning(
        d,
        learner,
        Advisor(tables, 0.4, 50),
        goal,
        np.random.default_rng(seed),
        episodes=25,
        advised=advised,
        max_steps=60,
        keep_history=keep_history,
    )
    assert fast.steps.tolist() == [r.steps for r in ref]
    assert fast.success.tolist() == [r.success for r in ref]
    assert fast.advice_count.tolist() == [r.advice_count for r in ref]
    np.testing.assert_array_equal(fast.q, learner.q)
    np.testing.assert_allclose(
        fast.p_normal_mean, [np.mean([x.p_normal for x in r.decisions]) for r in ref], atol=1e-9
    )


def test_step_budget_stops_learning_mid_episode() -> None:
    d, tables = small_world(3)
    run = Simulator(d, tables).learning(
        d.goals[0],
        np.random.default_rng(0),
        advised=True,
        episodes=100,
        max_steps=7,
        step_budget=30,
    )
    assert run.steps.sum() == 30
    assert len(run.steps) <= 5


def test_simulator_rejects_bad_arguments() -> None:
    d, tables = small_world(1)
    sim = Simulator(d, tables)
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="unknown explorer"):
        sim.fixed("teleport", d.goals[0], rng, advised=True)
    with pytest.raises(ValueError, match="kappa"):
        sim.fixed("random", d.goals[0], rng, advised=True, kappa=-1.0)
    with pytest.raises(ValueError, match="ties"):
        QParams(ties="coin")
    other = generate_domain(7, 7, 0)
    with pytest.raises(ValueError, match="states"):
        Simulator(other, tables)
