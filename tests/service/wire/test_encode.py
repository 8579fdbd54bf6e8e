"""The batch writer (orjson's numbers laid out by a compiled loop) writes exactly the bytes
orjson writes for each decision alone, with theta_s as the advice or an advisor's own."""

from __future__ import annotations

import json

import numpy as np
from advisor_client.protocol import unpack
from hypothesis import given
from hypothesis import strategies as st

from app.advice.advisor import Advisor, DecisionBatch
from app.advice.goals import GoalAwareAdvisor
from app.advice.priors import GoalPriors
from app.domain.generate import generate_domain
from app.service.schemas import DecisionPublic
from app.service.wire.encode import batch_binary, batch_json, decision_dict, decision_json
from app.strategies.stream import StreamAdvisor
from tests.tables import random_tables

DOMAIN = generate_domain(15, 17, 4, braid=0.3, n_goals=3)


def advisor(seed: int, kappa: float, own: bool) -> Advisor:
    rng = np.random.default_rng(seed)
    tables = random_tables(rng, DOMAIN.n_states, int(rng.integers(2, 4)))
    window = int(rng.integers(1, 400))
    if not own:
        return StreamAdvisor(tables, kappa=kappa, window=window)
    priors = GoalPriors(DOMAIN.n_states, DOMAIN.goals, 0.5)
    paths = [np.column_stack([rng.integers(0, DOMAIN.n_states, 30), rng.integers(0, 4, 30)])]
    priors.add(paths * 3, [0, 1, None])
    return GoalAwareAdvisor(tables, priors, kappa, window, beta=float(rng.choice([0.0, 0.7])))


@given(
    seed=st.integers(0, 2**32 - 1),
    kappa=st.sampled_from([0.0, 0.05, 0.5, 1.0, 1e9]),
    own=st.booleans(),
    sizes=st.lists(st.integers(0, 300), min_size=1, max_size=4),
)
def test_batch_json_is_each_decision_as_orjson_writes_it(
    seed: int, kappa: float, own: bool, sizes: list[int]
) -> None:
    rng = np.random.default_rng(seed)
    adv = advisor(seed, kappa, own)
    adv.start(DOMAIN.start)
    n_states = DOMAIN.n_states
    for n in sizes:
        s, a, s2 = (rng.integers(0, n_states, n), rng.integers(0, 4, n),
                    rng.integers(0, n_states, n))  # fmt: skip
        out = adv.observe_batch(s, a, s2)
        decisions = out.decisions()
        text = batch_json(out, DOMAIN)
        assert text == b"[" + b",".join(decision_json(d, DOMAIN) for d in decisions) + b"]"
        parsed = json.loads(text)
        assert parsed == [json.loads(json.dumps(decision_dict(d, DOMAIN))) for d in decisions]
        for item in parsed[:3]:
            DecisionPublic.model_validate(item)
        frame = unpack(batch_binary(out, DOMAIN))  # and the binary frame says the same
        assert frame.to_dicts() == parsed


def test_an_empty_batch_is_an_empty_list() -> None:
    out = DecisionBatch.of([], 0.5, 0, 0.0)
    assert batch_json(out, DOMAIN) == b"[]"
    assert len(unpack(batch_binary(out, DOMAIN))) == 0
