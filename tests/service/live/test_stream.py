"""StreamAdvisor's compiled batches make exactly the core Advisor's decisions (bit for bit),
over random tables with two or three behaviour models and arbitrary weights, prior updates
mid-stream, and streams long enough to cross the core's exact window re-sums."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from app.advice.advisor import Advisor, DecisionBatch, resync_period
from app.service.live.stream import StreamAdvisor
from tests.tables import SPLIT_WEIGHTS, random_tables, split_weight_tables


def _same_state(fast: StreamAdvisor, core: Advisor) -> None:
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
    weights = np.array(SPLIT_WEIGHTS) / sum(SPLIT_WEIGHTS)
    assert np.log(weights)[1] != math.log(weights[1])  # the case this test is about
    for seed in range(5):
        rng = np.random.default_rng(seed)
        tables = split_weight_tables(rng, 30)
        core, fast = Advisor(tables, 0.3, 50), StreamAdvisor(tables, 0.3, 50)
        assert fast.start(0) == core.start(0)
        s, a, s2 = rng.integers(0, 30, 200), rng.integers(0, 4, 200), rng.integers(0, 30, 200)
        expected = [core.observe(int(x), int(y), int(z)) for x, y, z in zip(s, a, s2, strict=True)]
        assert fast.observe_batch(s, a, s2).decisions() == expected
