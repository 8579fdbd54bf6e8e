"""StreamAdvisor.observe_many makes exactly the core Advisor's decisions (bit for bit), over
streams long enough to cross the core's exact window re-sums (every resync_period pairs)."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from app.advice.advisor import Advisor, resync_period
from app.advice.models import AdviceTables
from app.service.stream_advisor import SMALL_BATCH, DecisionColumns, StreamAdvisor


def _tables(rng: np.random.Generator, n_states: int) -> AdviceTables:
    alpha = rng.choice([0.1, 1.0, 5.0]) + rng.integers(0, 20, (n_states, 4))
    return AdviceTables.paper(alpha / alpha.sum(axis=1, keepdims=True))


@given(
    seed=st.integers(0, 2**32 - 1),
    n_states=st.integers(1, 40),
    window=st.one_of(st.integers(1, 60), st.sampled_from([300, 1000, 1024, 1500])),
    kappa=st.sampled_from([0.0, 0.05, 0.3, 0.5, 1.0, 1.5]),
    batches=st.lists(
        st.one_of(st.integers(0, 3 * SMALL_BATCH), st.integers(0, 700)), min_size=1, max_size=8
    ),
)
def test_observe_many_equals_core_observe(
    seed: int, n_states: int, window: int, kappa: float, batches: list[int]
) -> None:
    rng = np.random.default_rng(seed)
    tables = _tables(rng, n_states)
    core, fast = Advisor(tables, kappa, window), StreamAdvisor(tables, kappa, window)
    start = int(rng.integers(n_states))
    assert fast.start(start) == core.start(start)
    for n in batches:
        if rng.random() < 0.2:  # the prior changed: new tables mid-session
            core.tables = fast.tables = _tables(rng, n_states)
        s, a, s2 = (rng.integers(0, n_states, n), rng.integers(0, 4, n),
                    rng.integers(0, n_states, n))  # fmt: skip
        expected = DecisionColumns.of(
            [core.observe(int(x), int(y), int(z)) for x, y, z in zip(s, a, s2, strict=True)]
        )
        assert fast.observe_many(s, a, s2) == expected
        assert fast.log_likelihoods == core.log_likelihoods
        np.testing.assert_array_equal(fast._window, np.array(core._ring))
        assert (fast.steps, fast.decisions, fast.advice_count, fast.benefit) == (
            core.steps, core.decisions, core.advice_count, core.benefit,
        )  # fmt: skip
    # and single events after batches still agree (the ring was left as the core leaves it),
    # over more than one exact re-sum of the window
    for _ in range(min(2 * resync_period(window) + 3, 3000)):
        x, y, z = (int(v) for v in rng.integers(0, [n_states, 4, n_states]))
        assert fast.observe(x, y, z) == core.observe(x, y, z)


def test_observe_many_of_nothing_changes_nothing() -> None:
    tables = AdviceTables.paper(np.full((3, 4), 0.25))
    adv = StreamAdvisor(tables, 0.5, 5)
    adv.start(0)
    empty = np.zeros(0, dtype=np.int64)
    assert len(adv.observe_many(empty, empty, empty)) == 0
    assert adv.steps == 0 and adv.decisions == 1


def test_tables_changing_at_every_event_keep_the_core_s_numbers() -> None:
    """A prior update before every event (as while trajectories stream in): the values of the
    pairs added with older tables are kept, and dropped once the last of them has left."""
    rng = np.random.default_rng(5)
    tables = _tables(rng, 12)
    core, fast = Advisor(tables, 0.3, 40), StreamAdvisor(tables, 0.3, 40)
    assert fast.start(0) == core.start(0)
    for step in range(300):
        if step < 200:
            core.tables = fast.tables = _tables(rng, 12)
        n = int(rng.choice([1, 3, 9, 60]))
        s, a, s2 = (rng.integers(0, 12, n), rng.integers(0, 4, n),
                    rng.integers(0, 12, n))  # fmt: skip
        expected = DecisionColumns.of(
            [core.observe(int(x), int(y), int(z)) for x, y, z in zip(s, a, s2, strict=True)]
        )
        assert fast.observe_many(s, a, s2) == expected
        assert fast.log_likelihoods == core.log_likelihoods
        np.testing.assert_array_equal(fast._window, np.array(core._ring))
    assert fast._old is None  # the last prior update was more than a window ago
