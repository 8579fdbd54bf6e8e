from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from app.advice.advisor import Advisor, kl_divergence
from app.advice.goals import GoalAwareAdvisor
from app.advice.guide import GuideMap
from app.advice.models import AdviceTables
from app.advice.params import StrategyParams
from app.advice.priors import ActionPrior, GoalPriors
from app.advice.rules import RULES, RuleAdvisor
from app.domain.grid import GridDomain
from app.strategies import make_advisor, names

STRATEGIES = names()


@st.composite
def labelled_data(draw: st.DrawFn):  # type: ignore[no-untyped-def]
    """Random trajectories over states 0..n-1, goals at the last two states, random labels."""
    n = draw(st.integers(4, 10))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    k = draw(st.integers(1, 8))
    trajs = [
        np.column_stack([rng.integers(0, n, m), rng.integers(0, 4, m)])
        for m in rng.integers(1, 30, k)
    ]
    labels = [None if rng.random() < 0.3 else int(rng.integers(2)) for _ in range(k)]
    alpha0 = draw(st.sampled_from([0.1, 0.5, 1.0, 3.0]))
    return n, trajs, labels, alpha0, rng


@given(labelled_data())
def test_goal_priors_uniform_posterior_is_the_pooled_prior(data) -> None:  # type: ignore[no-untyped-def]
    n, trajs, labels, alpha0, _ = data
    gp = GoalPriors(n, [n - 1, n - 2], alpha0).add(trajs, labels)
    pooled = ActionPrior(alpha0=alpha0).fit(trajs, n).theta()
    np.testing.assert_allclose(gp.pooled_theta(), pooled, rtol=0, atol=1e-12)
    for s in range(n):
        np.testing.assert_allclose(gp.theta_row(s, [0.5, 0.5]), pooled[s], atol=1e-12)


@given(labelled_data(), st.sampled_from([0.0, 0.3, 1.0]))
def test_goal_aware_with_no_goal_ruled_out_and_beta0_makes_paper_decisions(data, kappa) -> None:  # type: ignore[no-untyped-def]
    n, trajs, labels, alpha0, rng = data
    gp = GoalPriors(n, [n - 1, n - 2], alpha0).add(trajs, labels)
    tables = AdviceTables.paper(gp.pooled_theta())
    paper, aware = Advisor(tables, kappa, 7), GoalAwareAdvisor(tables, gp, kappa, 7, beta=0.0)
    a, b = paper.start(0), aware.start(0)
    for _ in range(40):  # never on a goal cell, so no goal is ruled out
        s, act, s2 = int(rng.integers(n - 2)), int(rng.integers(4)), int(rng.integers(n - 2))
        a, b = paper.observe(s, act, s2), aware.observe(s, act, s2)
        assert b.kl == pytest.approx(a.kl, abs=1e-9)
        assert b.p_normal == a.p_normal
        if abs(a.kl - kappa) > 1e-9:
            assert b.advise == a.advise
    assert aware.goal_posterior() == pytest.approx([0.5, 0.5])


def test_goal_aware_rules_out_a_goal_the_explorer_left() -> None:
    # 4 states in a row; goal 0 at state 3 (experts go E), goal 1 at state 0 (experts go W)
    east = np.array([[0, 1], [1, 1], [2, 1]])
    west = np.array([[3, 3], [2, 3], [1, 3]])
    gp = GoalPriors(4, [3, 0], alpha0=0.1).add([east, west], [0, 1])
    tables = AdviceTables.paper(gp.pooled_theta())
    adv = GoalAwareAdvisor(tables, gp, kappa=0.0, window=10)
    d = adv.start(1)
    assert d.advice is not None and d.advice[1] == pytest.approx(d.advice[3])  # E and W tie
    d = adv.observe(1, 3, 0)
    d = adv.observe(0, 1, 1)  # stood on goal 1's cell and went on: not its goal
    assert adv.goal_posterior() == [1.0, 0.0]
    assert d.advice is not None
    np.testing.assert_allclose(d.advice, gp.theta_row(1, [1.0, 0.0]))
    assert d.advice[1] == pytest.approx(2.1 / 2.4)  # alpha0 + G * 1 count for east only


def test_goal_aware_likelihood_weighting_favours_the_goal_being_followed() -> None:
    east = np.array([[0, 1], [1, 1], [2, 1]])
    west = np.array([[3, 3], [2, 3], [1, 3]])
    gp = GoalPriors(4, [3, 0], alpha0=0.1).add([east, west], [0, 1])
    adv = GoalAwareAdvisor(AdviceTables.paper(gp.pooled_theta()), gp, window=10, beta=1.0)
    adv.start(1)
    adv.observe(1, 1, 2)
    w = adv.goal_posterior()
    assert w[0] > 0.9 and sum(w) == pytest.approx(1.0)


@given(st.integers(0, 2**32 - 1), st.floats(0.0, 1.4), st.integers(0, 30))
def test_rules_match_their_definitions(seed: int, threshold: float, n_steps: int) -> None:
    rng = np.random.default_rng(seed)
    theta = rng.dirichlet(np.full(4, 0.5), size=6)
    tables = AdviceTables.paper(theta)
    params = StrategyParams(n_steps=n_steps, threshold=threshold)
    adv = {r: RULES[r](tables, 0.5, 20, params) for r in ("always", "early", "importance")}
    mistake = RULES["mistake"](tables, 0.5, 20, StrategyParams(threshold=threshold / 2))
    decisions = {r: [a.start(0)] for r, a in adv.items()}
    assert not mistake.start(0).advise
    for _ in range(40):
        s, a, s2 = int(rng.integers(6)), int(rng.integers(4)), int(rng.integers(6))
        for r, advisor in adv.items():
            decisions[r].append(advisor.observe(s, a, s2))
        assert mistake.observe(s, a, s2).advise == (theta[s, a] < threshold / 2)
    assert all(d.advise for d in decisions["always"])
    assert [d.advise for d in decisions["early"]] == [i < n_steps for i in range(41)]
    for d in decisions["importance"]:
        importance = kl_divergence(theta[d.state], np.full(4, 0.25))
        if abs(importance - threshold) > 1e-9:
            assert d.advise == (importance >= threshold)
        assert d.total_cost == pytest.approx(0.5 * d.advice_count)


def test_random_rule_rate_and_seed() -> None:
    tables = AdviceTables.paper(np.full((2, 4), 0.25))

    def run(rate: float, seed: int) -> list[bool]:
        adv = RULES["random"](tables, params=StrategyParams(rate=rate, seed=seed))
        return [adv.start(0).advise] + [adv.observe(0, 1, 1).advise for _ in range(2000)]

    assert not any(run(0.0, 1)) and all(run(1.0, 1))
    assert run(0.2, 7) == run(0.2, 7)
    assert sum(run(0.2, 7)) / 2001 == pytest.approx(0.2, abs=0.03)


@pytest.mark.parametrize("rule", ["early", "importance", "mistake", "random", "always"])
def test_a_restarted_rule_advisor_advises_as_a_fresh_one(rule: str) -> None:
    rng = np.random.default_rng(3)
    theta = rng.dirichlet(np.full(4, 0.5), size=6)
    tables = AdviceTables.paper(theta)
    params = StrategyParams(rate=0.3, threshold=0.2, n_steps=4, seed=11)
    moves = [(int(s), int(a), int(s2)) for s, a, s2 in rng.integers(0, 6, (300, 3)) % [6, 4, 6]]

    def episode(adv: RuleAdvisor) -> list[tuple[bool, float]]:
        out = [adv.start(0)] + [adv.observe(s, a, s2) for s, a, s2 in moves]
        return [(d.advise, d.kl) for d in out]

    reused = RULES[rule](tables, params=params)
    episode(reused)  # a first explorer
    assert episode(reused) == episode(RULES[rule](tables, params=params))


def test_make_advisor_builds_each_strategy_and_rejects_unknown() -> None:
    theta = np.full((3, 4), 0.25)
    tables = AdviceTables.paper(theta)
    gp = GoalPriors(3, [2], 1.0)
    guide = GuideMap.of(GridDomain.from_strings(["S.G"]), gp)
    for name in STRATEGIES:
        adv = make_advisor(name, tables, goal_priors=gp, guide_map=guide)
        assert adv.start(0).step == 0
        assert adv.strategy == name
    assert type(make_advisor("paper", tables)) is Advisor
    with pytest.raises(ValueError, match="unknown strategy 'loud'"):
        make_advisor("loud", tables)
    with pytest.raises(ValueError, match="needs the experts' goals"):
        make_advisor("goal_aware", tables)
    with pytest.raises(ValueError, match="needs the map's destinations"):
        make_advisor("guide", tables)


@pytest.mark.parametrize(
    ("params", "message"),
    [
        (StrategyParams(n_steps=-1), "n_steps must be a whole number from 0 to 2147483647"),
        (StrategyParams(n_steps=2.5), "n_steps must be a whole number, got 2.5"),  # type: ignore[arg-type]
        (StrategyParams(threshold=math.nan), "threshold must be a finite number >= 0"),
        (StrategyParams(rate=1.5), "rate must be a finite number from 0.0 to 1.0, got 1.5"),
        (StrategyParams(seed=2**32), "seed must be a whole number from 0 to 4294967295"),
    ],
)
def test_strategy_params_are_checked(params: StrategyParams, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        RULES["early"](AdviceTables.paper(np.full((1, 4), 0.25)), params=params)
