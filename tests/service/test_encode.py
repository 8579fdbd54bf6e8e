"""The compiled decision encoder writes exactly the text of the f-string encoder."""

from __future__ import annotations

import json

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from app.advice.models import AdviceTables
from app.service.encode import SMALL, encode_decisions, encode_one, fragments, packed
from app.service.stream_advisor import DecisionColumns, StreamAdvisor


@given(
    seed=st.integers(0, 2**32 - 1),
    n_states=st.integers(1, 60),
    kappa=st.sampled_from([0.0, 0.05, 0.5, 1.0, 1e9]),
    sizes=st.lists(st.integers(0, 600), min_size=1, max_size=4),
)
def test_compiled_encoder_writes_the_same_text(
    seed: int, n_states: int, kappa: float, sizes: list[int]
) -> None:
    rng = np.random.default_rng(seed)
    alpha = rng.choice([0.1, 1.0, 5.0]) + rng.integers(0, 20, (n_states, 4))
    tables = AdviceTables.paper(alpha / alpha.sum(axis=1, keepdims=True))
    cells = [f"[{int(rng.integers(0, 10**6))},{k}]" for k in range(n_states)]
    parts, pack = fragments(tables, cells), packed(tables, cells)
    advisor = StreamAdvisor(tables, kappa=kappa, window=int(rng.integers(1, 400)))
    advisor.start(0)
    for n in sizes:
        s, a, s2 = (rng.integers(0, n_states, n), rng.integers(0, 4, n),
                    rng.integers(0, n_states, n))  # fmt: skip
        cols = advisor.observe_many(s, a, s2)
        plain = encode_decisions(cols, parts, False)
        assert encode_decisions(cols, parts, False, pack) == plain
        assert len(json.loads(plain)) == n
        if n > SMALL:
            assert cols.arrays is not None


@given(
    seed=st.integers(0, 2**32 - 1),
    n_states=st.integers(1, 60),
    kappa=st.sampled_from([0.0, 0.05, 0.5, 1.0, 1e9]),
    own=st.booleans(),
)
def test_one_decision_is_written_as_the_column_encoder_writes_it(
    seed: int, n_states: int, kappa: float, own: bool
) -> None:
    """``encode_one`` (the single-event path) against ``encode_decisions`` of one column,
    with theta_s as the advice or the decision's own advice (goal_aware)."""
    rng = np.random.default_rng(seed)
    alpha = rng.choice([0.1, 1.0, 5.0]) + rng.integers(0, 20, (n_states, 4))
    tables = AdviceTables.paper(alpha / alpha.sum(axis=1, keepdims=True))
    cells = [f"[{int(rng.integers(0, 10**6))},{k}]" for k in range(n_states)]
    parts = fragments(tables, cells)
    advisor = StreamAdvisor(tables, kappa=kappa, window=int(rng.integers(1, 400)))
    advisor.start(0)
    for _ in range(20):
        s, a, s2 = (int(x) for x in rng.integers(0, [n_states, 4, n_states]))
        d = advisor.observe(s, a, s2)
        if own and d.advise:  # advice of its own, as goal_aware's (not theta_s)
            d = d._replace(advice=tuple(float(x) for x in rng.dirichlet(np.ones(4))))
        cols = DecisionColumns.of([d], with_advice=own)
        assert encode_one(d, parts, own) == encode_decisions(cols, parts, True)
