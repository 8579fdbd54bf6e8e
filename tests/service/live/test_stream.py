"""StreamAdvisor's compiled batches make exactly the core Advisor's decisions (bit for bit),
over random tables with two or three behaviour models and arbitrary weights, prior updates
mid-stream, and streams long enough to cross the core's exact window re-sums."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.advice import guide
from app.advice.advisor import NO_CAP, Advisor, Decision, DecisionBatch, resync_period
from app.advice.goals import GoalAwareAdvisor
from app.advice.guide import GuideAdvisor, GuideMap, GuideParams
from app.advice.models import AdviceTables
from app.advice.params import StrategyParams
from app.advice.rules import RULES
from app.agents.experts import train_goal_priors
from app.domain.building import Domain
from app.domain.floorplans import generate_floors
from app.domain.generate import generate_building_domain, generate_domain
from app.strategies.stream import (
    SLICE_STEPS,
    KeyedWindow,
    StreamAdvisor,
    StreamGoalAware,
    StreamGuide,
    keyed,
)
from tests.tables import random_tables, split_weight_tables


def _maybe_cap(rng: np.random.Generator, *advisors: Advisor) -> None:
    """Now and then a cap on the advice count a few pieces ahead (a session's budget, or a
    muted visitor: the cap where the count is), else none, the same for every advisor."""
    u = rng.random()
    extra = int(rng.integers(0, 4))
    for adv in advisors:
        adv.cap = adv.advice_count + extra if u < 0.4 else NO_CAP


def _same_state(fast: KeyedWindow, core: Advisor) -> None:
    assert fast.log_likelihoods == core.log_likelihoods
    np.testing.assert_array_equal(fast._window, np.array(core._ring))
    assert (fast.steps, fast.decisions, fast.advice_count, fast.benefit) == (
        core.steps, core.decisions, core.advice_count, core.benefit,
    )  # fmt: skip


@given(
    seed=st.integers(0, 2**32 - 1),
    n_states=st.integers(1, 40),
    n_models=st.sampled_from([2, 3]),
    window=st.one_of(st.integers(1, 60), st.sampled_from([300, 1000, 1024, 1500])),
    kappa=st.sampled_from([0.0, 0.05, 0.3, 0.5, 1.0, 1.5]),
    batches=st.lists(st.one_of(st.integers(0, 20), st.integers(0, 700)), min_size=1, max_size=8),
)
def test_observe_batch_equals_core_observe(
    seed: int, n_states: int, n_models: int, window: int, kappa: float, batches: list[int]
) -> None:
    rng = np.random.default_rng(seed)
    tables = random_tables(rng, n_states, n_models)
    core, fast = Advisor(tables, kappa, window), StreamAdvisor(tables, kappa, window)
    start = int(rng.integers(n_states))
    assert fast.start(start) == core.start(start)
    for n in batches:
        if rng.random() < 0.2:  # the prior changed: new tables mid-session
            core.tables = fast.tables = random_tables(rng, n_states, n_models)
        _maybe_cap(rng, core, fast)
        s, a, s2 = (rng.integers(0, n_states, n), rng.integers(0, 4, n),
                    rng.integers(0, n_states, n))  # fmt: skip
        count, benefit = core.advice_count, core.benefit
        expected = [core.observe(int(x), int(y), int(z)) for x, y, z in zip(s, a, s2, strict=True)]
        got = fast.observe_batch(s, a, s2)
        assert got.decisions() == expected
        assert got.total_cost.tolist() == [d.total_cost for d in expected]
        assert (got.count_before, got.benefit_before) == (count, benefit)
        _same_state(fast, core)
    # and single events after batches still agree (the ring was left as the core leaves it),
    # over more than one exact re-sum of the window
    for _ in range(min(2 * resync_period(window) + 3, 3000)):
        x, y, z = (int(v) for v in rng.integers(0, [n_states, 4, n_states]))
        assert fast.observe(x, y, z) == core.observe(x, y, z)


def test_observe_batch_of_nothing_changes_nothing() -> None:
    adv = StreamAdvisor(random_tables(np.random.default_rng(0), 3), 0.5, 5)
    adv.start(0)
    empty = np.zeros(0, dtype=np.int64)
    out = adv.observe_batch(empty, empty, empty)
    assert len(out) == 0 and out.decisions() == [] and out.advice.shape == (0, 4)
    assert adv.steps == 0 and adv.decisions == 1


def test_tables_changing_at_every_event_keep_the_core_s_numbers() -> None:
    """A prior update before every event (as while trajectories stream in): the values of the
    pairs added with older tables are kept, and dropped once the last of them has left."""
    rng = np.random.default_rng(5)
    tables = random_tables(rng, 12, 3)
    core, fast = Advisor(tables, 0.3, 40), StreamAdvisor(tables, 0.3, 40)
    assert fast.start(0) == core.start(0)
    for step in range(300):
        if step < 200:
            core.tables = fast.tables = random_tables(rng, 12, 3)
        n = int(rng.choice([1, 3, 9, 60]))
        s, a, s2 = (rng.integers(0, 12, n), rng.integers(0, 4, n),
                    rng.integers(0, 12, n))  # fmt: skip
        expected = [core.observe(int(x), int(y), int(z)) for x, y, z in zip(s, a, s2, strict=True)]
        assert fast.observe_batch(s, a, s2).decisions() == expected
        _same_state(fast, core)
    assert fast._old is None  # the last prior update was more than a window ago


def test_decision_batch_of_decisions_round_trips() -> None:
    core = Advisor(random_tables(np.random.default_rng(2), 6, 3), 0.2, 9)
    core.start(0)
    made = [core.observe(i % 6, i % 4, (i * 5) % 6) for i in range(40)]
    batch = DecisionBatch.of(made, core.kappa, 0, 0.0)
    assert batch.decisions() == made
    assert len(batch.advice) == sum(d.advise for d in made)


def test_every_form_reads_the_same_log_weights() -> None:
    # SPLIT_WEIGHTS: where this CPU's numpy and libm round log P(M) differently (WEIGHTS_SPLIT)
    for seed in range(5):
        rng = np.random.default_rng(seed)
        tables = split_weight_tables(rng, 30)
        core, fast = Advisor(tables, 0.3, 50), StreamAdvisor(tables, 0.3, 50)
        assert fast.start(0) == core.start(0)
        s, a, s2 = rng.integers(0, 30, 200), rng.integers(0, 4, 200), rng.integers(0, 30, 200)
        expected = [core.observe(int(x), int(y), int(z)) for x, y, z in zip(s, a, s2, strict=True)]
        assert fast.observe_batch(s, a, s2).decisions() == expected


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    building=st.booleans(),
    window=st.sampled_from([1, 5, 50, 300]),
    kappa=st.sampled_from([0.0, 0.3, 0.5, 1.5]),
    follow=st.booleans(),
    batches=st.lists(st.integers(0, 300), min_size=1, max_size=6),
    taking=st.sampled_from([0.0, 0.5, 1.0]),
    straight=st.booleans(),
    floors=st.sampled_from([1, 1, 2, 3]),
    many=st.sampled_from([False, False, True]),
)
def test_guide_batches_equal_the_core_guide(
    seed: int, building: bool, window: int, kappa: float, follow: bool, batches: list[int],
    taking: float, straight: bool, floors: int, many: bool,
) -> None:  # fmt: skip
    """StreamGuide's compiled batches against GuideAdvisor.observe, on moves that follow the
    map (and, with ``follow`` off, jump anywhere, as a client's reports may), by explorers
    that take a piece of advice with probability ``taking`` (the compliance they learn), with
    new expert counts mid-session, mixed with single events. With ``straight`` their own
    moves go straight on while they can (often a shortest path: the runs guide leaves
    alone). ``floors`` > 1: a building of that many floors (six actions, rides). ``many``:
    a one-floor building of more destinations than guide plans a tour through exactly
    (its next destination searched for)."""
    rng = np.random.default_rng(seed)
    d: Domain
    if floors > 1:
        d = generate_floors(20, 20, floors, rng, n_goals=1 + seed % 3, room=(3, 5))
    elif building or many:
        n_goals = guide.MAX_TOUR + 1 + seed % 10 if many else 1 + seed % 6
        d = generate_building_domain(20, 24, seed % 1000, n_goals=n_goals)
    else:
        d = generate_domain(9, 9, seed % 1000, braid=0.3, n_goals=1 + seed % 4)
    prior, goals = train_goal_priors(d, rng, "start", 2, 1.0)
    tables = AdviceTables.paper(prior.theta())
    gm = GuideMap.of(d, goals)
    params = GuideParams(float(rng.uniform(0.01, 0.99)), float(rng.uniform(0.01, 1.0)),
                         float(rng.uniform(0.0, 1.0)))  # fmt: skip
    core = GuideAdvisor(tables, gm, kappa, window, params=params)
    fast = StreamGuide(tables, gm, kappa, window, params=params)
    s = int(rng.integers(d.n_states))
    assert fast.start(s) == core.start(s)
    for n in batches:
        if rng.random() < 0.3:  # more expert data: new counts
            _, more = train_goal_priors(d, rng, "anywhere", 1, 1.0)
            core.use_tables(tables, more)
            fast.use_tables(tables, more)
        _maybe_cap(rng, core, fast)
        states, actions, nexts = [], [], []
        decided: list[Decision] = []
        heading = int(rng.integers(4))
        for _ in range(n):
            a = int(rng.integers(d.n_actions))
            if straight and int(d.next_state[s, heading]) != s:
                a = heading
            heading = a
            last = decided[-1] if decided else None
            if last is not None and last.advise and rng.random() < taking:  # takes the advice
                a = max(range(d.n_actions), key=lambda b: (last.advice[b], -b))  # type: ignore[index]
            if follow or rng.random() < 0.8:
                s2 = int(d.next_state[s, a])
            else:
                s, s2 = int(rng.integers(d.n_states)), int(rng.integers(d.n_states))
            states.append(s)
            actions.append(a)
            nexts.append(s2)
            decided.append(core.observe(s, a, s2))
            s = s2
        got = fast.observe_batch(
            np.array(states, dtype=np.int64), np.array(actions, dtype=np.int64),
            np.array(nexts, dtype=np.int64),
        )  # fmt: skip
        assert got.decisions() == decided
        assert fast._loglik == core._loglik and fast.alive == core.alive
        assert fast.doubt == core.doubt and fast._run == core._run
        assert fast._comply == core._comply and fast.compliance == core.compliance
        assert fast._came == core._came
        # the memory it is charged for counts every float it keeps
        kept = len(fast._loglik) + len(fast._comply) + len(fast._run)
        assert fast.footprint() >= 32 * kept + 8 * (len(fast.alive) + len(fast.doubt))
        assert fast.target == core.target and fast.goal_beliefs() == core.goal_beliefs()
        a = int(rng.integers(4))  # a single event between batches
        s2 = int(d.next_state[s, a])
        assert fast.observe(s, a, s2) == core.observe(s, a, s2)
        s = s2


def _moves(
    rng: np.random.Generator, d: Domain, s: int, n: int, follow: bool
) -> tuple[list[int], list[int], list[int], int]:
    """``n`` moves from ``s``: along the map, or (``follow`` off) jumping anywhere at times."""
    states, actions, nexts = [], [], []
    for _ in range(n):
        a = int(rng.integers(d.n_actions))
        if follow or rng.random() < 0.8:
            s2 = int(d.next_state[s, a])
        else:
            s, s2 = int(rng.integers(d.n_states)), int(rng.integers(d.n_states))
        states.append(s)
        actions.append(a)
        nexts.append(s2)
        s = s2
    return states, actions, nexts, s


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    window=st.one_of(st.integers(1, 40), st.sampled_from([300, 1024, 1100])),
    kappa=st.sampled_from([0.0, 0.3, 0.5, 1.5]),
    beta=st.sampled_from([0.0, 0.5, 1.0]),
    follow=st.booleans(),
    batches=st.lists(st.one_of(st.integers(0, 10), st.integers(0, 900)), min_size=1, max_size=6),
    floors=st.sampled_from([1, 1, 2, 3]),
)
def test_goal_aware_batches_equal_the_core_goal_aware_advisor(
    seed: int, window: int, kappa: float, beta: float, follow: bool, batches: list[int],
    floors: int,
) -> None:  # fmt: skip
    """StreamGoalAware (both windows as pair keys into shared tables, every event compiled)
    against GoalAwareAdvisor.observe, with new tables and new goal counts mid-session (the
    values of the pairs added before kept exactly), single events between batches; on one
    floor (four actions) or a building of two or three (six: up and down)."""
    rng = np.random.default_rng(seed)
    d: Domain = generate_domain(7, 7, seed % 1000, braid=0.3, n_goals=1 + seed % 4)
    if floors > 1:
        d = generate_floors(20, 20, floors, rng, n_goals=1 + seed % 2, room=(3, 5))
    prior, goals = train_goal_priors(d, rng, "start", 2, 1.0)
    tables = AdviceTables.paper(prior.theta())
    core = GoalAwareAdvisor(tables, goals, kappa, window, beta)
    fast = StreamGoalAware(tables, goals, kappa, window, beta)
    s = int(rng.integers(d.n_states))
    assert fast.start(s) == core.start(s)
    for n in batches:
        if rng.random() < 0.3:  # more expert data: new counts, and new tables or not
            _, more = train_goal_priors(d, rng, "anywhere", 1, 1.0)
            new = random_tables(rng, d.n_states, n_actions=d.n_actions)
            new = new if rng.random() < 0.5 else tables
            core.use_tables(new, more)
            fast.use_tables(new, more)
        _maybe_cap(rng, core, fast)
        states, actions, nexts, s = _moves(rng, d, s, n, follow)
        decided = [core.observe(*m) for m in zip(states, actions, nexts, strict=True)]
        got = fast.observe_batch(*(np.array(v, dtype=np.int64) for v in (states, actions, nexts)))
        assert got.decisions() == decided
        assert fast._loglik == core._loglik and fast._goal_ll.tolist() == core._goal_ll
        assert fast.alive.tolist() == core.alive and fast.goal_beliefs() == core.goal_beliefs()
        np.testing.assert_array_equal(fast._window, np.array(core._ring))
        if beta > 0.0:
            np.testing.assert_array_equal(fast._goal_window, np.array(core._goal_ring))
        a = int(rng.integers(d.n_actions))  # a single event between batches
        s2 = int(d.next_state[s, a])
        assert fast.observe(s, a, s2) == core.observe(s, a, s2)
        s = s2
    assert fast.goal_posterior() == core.goal_posterior()


@settings(max_examples=30, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    rule=st.sampled_from(sorted(RULES)),
    window=st.one_of(st.integers(1, 30), st.sampled_from([300, 1100])),
    batches=st.lists(st.integers(0, 400), min_size=1, max_size=5),
    n_actions=st.sampled_from([4, 4, 6]),
)
def test_rule_advisors_with_pair_keys_equal_the_core_rules(
    seed: int, rule: str, window: int, batches: list[int], n_actions: int
) -> None:
    rng = np.random.default_rng(seed)
    n_states = 15
    tables = random_tables(rng, n_states, n_actions=n_actions)
    params = StrategyParams(n_steps=30, threshold=0.4, rate=0.3, seed=seed % 100)
    core = RULES[rule](tables, 0.5, window, params)
    fast = keyed(RULES[rule])(tables, 0.5, window, params)
    assert isinstance(fast, KeyedWindow)
    assert fast.start(0) == core.start(0)
    for n in batches:
        if rng.random() < 0.3:
            core.tables = fast.tables = random_tables(rng, n_states, n_actions=n_actions)
        _maybe_cap(rng, core, fast)
        s, a, s2 = (rng.integers(0, n_states, n), rng.integers(0, n_actions, n),
                    rng.integers(0, n_states, n))  # fmt: skip
        expected = [core.observe(int(x), int(y), int(z)) for x, y, z in zip(s, a, s2, strict=True)]
        assert fast.observe_batch(s, a, s2).decisions() == expected
        _same_state(fast, core)


@given(
    seed=st.integers(0, 2**32 - 1),
    n_states=st.integers(1, 30),
    n_actions=st.sampled_from([6, 2, 3, 5, 8]),
    n_models=st.integers(2, 4),
    window=st.one_of(st.integers(1, 40), st.sampled_from([300, 1024])),
    kappa=st.sampled_from([0.0, 0.05, 0.3, 0.5, 1.0, 1.5]),
    batches=st.lists(st.integers(0, 400), min_size=1, max_size=5),
)
def test_observe_batch_equals_core_observe_for_any_number_of_actions(
    seed: int, n_states: int, n_actions: int, n_models: int, window: int, kappa: float,
    batches: list[int],
) -> None:  # fmt: skip
    """A building of several floors has six actions (N E S W U D): the compiled stream and the
    core decide alike over any number of actions, models and weights, the KL scaled to four
    actions' units in both."""
    rng = np.random.default_rng(seed)
    tables = random_tables(rng, n_states, n_models, n_actions=n_actions)
    core, fast = Advisor(tables, kappa, window), StreamAdvisor(tables, kappa, window)
    start = int(rng.integers(n_states))
    assert fast.start(start) == core.start(start)
    for n in batches:
        if rng.random() < 0.2:
            core.tables = fast.tables = random_tables(rng, n_states, n_models, n_actions=n_actions)
        _maybe_cap(rng, core, fast)
        s, a, s2 = (rng.integers(0, n_states, n), rng.integers(0, n_actions, n),
                    rng.integers(0, n_states, n))  # fmt: skip
        expected = [core.observe(int(x), int(y), int(z)) for x, y, z in zip(s, a, s2, strict=True)]
        got = fast.observe_batch(s, a, s2)
        assert got.decisions() == expected
        assert got.advice.shape == (sum(d.advise for d in expected), n_actions)
        _same_state(fast, core)


@pytest.mark.parametrize("n_goals", [8, 11, 24, 48, 49, 70])
def test_a_guide_slice_holds_at_most_its_steps_of_searches_for_the_next_destination(
    n_goals: int,
) -> None:
    """Where any event may set off a search for the next destination (more destinations than
    MAX_TOUR: up to MAX_SEARCHED_TOUR of them alive, on a map of more too), a batch's slice
    holds at most SLICE_STEPS of the search's steps (one event at least); elsewhere it is as
    long as before."""
    d = generate_building_domain(40, 40, 1, n_goals=n_goals)
    prior, goals = train_goal_priors(d, np.random.default_rng(0), "start", 1, 1.0)
    fast = StreamGuide(
        AdviceTables.paper(prior.theta()), GuideMap.of(d, goals), 0.5, 50,
        params=GuideParams.of(StrategyParams()),
    )  # fmt: skip
    usual = max(64, 5_000 // (n_goals + 1))
    assert guide.tour_work(n_goals) >= guide.tour_work(min(n_goals, guide.MAX_SEARCHED_TOUR))
    if n_goals > guide.MAX_TOUR:
        slice_ = fast.batch_slice()
        assert slice_ == 1 or slice_ * guide.tour_work(n_goals) <= SLICE_STEPS
        assert slice_ < usual
    else:
        assert fast.batch_slice() == usual
