"""Retries apply once: a step already applied is answered with the decision it got, nothing is
applied twice, and a step out of turn is refused. The ring of kept decisions against a plain
list of every decision, and the registry's step rule against sessions that got each event
once, for every strategy."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from app.advice.advisor import Decision, DecisionBatch
from app.service.data.domains import DomainState
from app.service.live.registry import Limits, SessionRegistry, SessionSettings
from app.service.live.replay import Replay, StepConflict, part
from app.service.state import ServiceState
from app.strategies import names
from tests.service.live.test_codec import columns, figures, params_for, walk

STRATEGIES = names()


def _decision(step: int, rng: np.random.Generator, count: int, benefit: float) -> Decision:
    advise = bool(rng.random() < 0.4)
    kl = float(rng.random())
    n, e, s, w = rng.dirichlet(np.ones(4)).tolist()
    if advise:
        count += 1
        benefit += kl
    state, p = int(rng.integers(1000)), float(rng.random())
    advice = (n, e, s, w) if advise else None
    return Decision(step, state, advise, advice, kl, p, count, 0.5 * count, benefit)


def _batch(every: list[Decision], lo: int, hi: int, start: tuple[int, float]) -> DecisionBatch:
    """Decisions ``lo`` .. ``hi - 1`` of ``every`` as a batch, with the figures before them."""
    count, benefit = (every[lo - 1].advice_count, every[lo - 1].benefit) if lo else start
    return DecisionBatch.of(every[lo:hi], 0.5, count, benefit)


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    limit=st.integers(1, 40),
    sizes=st.lists(st.integers(1, 50), min_size=1, max_size=12),
    reload_limit=st.integers(1, 60),
)
def test_the_ring_answers_what_a_list_of_every_decision_says(
    seed: int, limit: int, sizes: list[int], reload_limit: int
) -> None:
    rng = np.random.default_rng(seed)
    start = (int(rng.integers(0, 2)), float(rng.random()))
    ring = Replay(limit)
    ring.restart(*start)
    every: list[Decision] = []
    count, benefit = start
    for n in sizes:
        made: list[Decision] = []
        for _ in range(n):
            d = _decision(len(every) + len(made) + 1, rng, count, benefit)
            count, benefit = d.advice_count, d.benefit
            made.append(d)
        if n == 1:
            ring.add_one(made[0])
        else:
            ring.add(_batch(every + made, len(every), len(every) + n, start))
        every += made
    last = len(every)
    reloaded = Replay.of(reload_limit, ring.state())
    for r, kept in ((ring, limit), (reloaded, min(limit, reload_limit))):
        for first in range(1, last + 1):
            for n in (1, 2, 7):
                got = r.answer(first, n, last, 0.5)
                if first < last - kept + 1 or first + n - 1 > last:
                    assert got is None
                    continue
                assert got is not None
                want = _batch(every, first - 1, first - 1 + n, start)
                assert columns(got) == columns(want)
                assert got.count_before == want.count_before
                assert got.benefit_before == want.benefit_before


def _add_one_by_fields(ring: Replay, d: Decision) -> None:
    """``Replay.add_one`` as it was written with numpy's row fields (the reference for its
    packed bytes)."""
    rows = ring._room(1)
    row = rows[ring._count % len(rows)]
    row["state"], row["advise"], row["kl"], row["p"] = d.state, d.advise, d.kl, d.p_normal
    row["advice"] = d.advice if d.advise and d.advice is not None else np.nan
    ring._count += 1


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    limit=st.integers(1, 40),
    sizes=st.lists(st.integers(1, 3), min_size=1, max_size=120),
)
def test_one_decision_is_kept_as_the_bytes_numpy_writes(
    seed: int, limit: int, sizes: list[int]
) -> None:
    rng = np.random.default_rng(seed)
    start = (int(rng.integers(0, 2)), float(rng.random()))
    packed, fields = Replay(limit), Replay(limit)
    for r in (packed, fields):
        r.restart(*start)
    every: list[Decision] = []
    count, benefit = start
    for n in sizes:  # mostly single decisions (growing, then wrapping round), some batches
        made: list[Decision] = []
        for _ in range(n):
            d = _decision(len(every) + len(made) + 1, rng, count, benefit)
            count, benefit = d.advice_count, d.benefit
            made.append(d)
        if n == 3:
            b = _batch(every + made, len(every), len(every) + n, start)
            packed.add(b)
            fields.add(b)
        else:
            for d in made:
                packed.add_one(d)
                _add_one_by_fields(fields, d)
        every += made
        assert packed.state() == fields.state()
        assert packed.kept == fields.kept


def test_part_of_a_batch_is_a_batch_of_its_own() -> None:
    rng = np.random.default_rng(3)
    made: list[Decision] = []
    count, benefit = 0, 0.0
    for i in range(20):
        d = _decision(i + 1, rng, count, benefit)
        count, benefit = d.advice_count, d.benefit
        made.append(d)
    whole = _batch(made, 0, 20, (0, 0.0))
    for lo, hi in ((0, 20), (3, 9), (19, 20), (0, 1)):
        assert columns(part(whole, lo, hi)) == columns(_batch(made, lo, hi, (0, 0.0)))


@pytest.fixture
def domain(service: ServiceState) -> DomainState:
    d = service.catalog.get("default")
    service.catalog.guide_map(d)
    return d


@pytest.mark.parametrize("strategy", STRATEGIES)
@settings(
    max_examples=6, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(seed=st.integers(0, 2**32 - 1), sizes=st.lists(st.integers(1, 40), min_size=1, max_size=6))
def test_retried_steps_are_answered_again_and_applied_once(
    domain: DomainState, strategy: str, seed: int, sizes: list[int]
) -> None:
    rng = np.random.default_rng(seed)
    reg = SessionRegistry(Limits(10), 3600.0, replay_steps=64)
    start, params = domain.domain.start, params_for(strategy)
    once, _ = reg.create(domain, SessionSettings.of(strategy, 0.3, 20, params, start=start))
    retried, _ = reg.create(domain, SessionSettings.of(strategy, 0.3, 20, params, start=start))
    here, step, sent = start, 1, []
    for n in sizes:
        moves = walk(domain, here, n, rng)
        here = int(moves[2][-1])
        want = reg.observe_batch(once, moves)
        got = reg.observe_batch(retried, moves, step)
        assert columns(got) == columns(want)
        sent.append((step, moves, want))
        # a retry of this batch, of an earlier one still kept, and of the tail of this one
        for first, old, answer in (sent[-1], sent[int(rng.integers(len(sent)))]):
            if first < retried.advisor.steps - 63:
                continue  # no longer kept
            again = reg.observe_batch(retried, old, first)
            assert columns(again) == columns(answer)
        if n > 1:
            k = int(rng.integers(1, n))
            tail = (moves[0][k:], moves[1][k:], moves[2][k:])
            assert columns(reg.observe_batch(retried, tail, step + k)) == columns(part(want, k, n))
        one = reg.observe_one(retried, int(moves[0][-1]), int(moves[1][-1]), here, step + n - 1)
        assert one == want.decisions()[-1]
        step += n
        assert figures(reg, retried) == figures(reg, once)


def test_a_step_out_of_turn_or_with_another_move_is_refused(domain: DomainState) -> None:
    reg = SessionRegistry(Limits(10), 3600.0, replay_steps=4)
    session, _ = reg.create(domain, SessionSettings.of("paper", 0.5, 20))
    rng = np.random.default_rng(0)
    moves = walk(domain, domain.domain.start, 10, rng)
    reg.observe_batch(session, moves, 1)
    with pytest.raises(StepConflict, match=r"step 12 is not the next step .* \(the next is 11\)"):
        reg.observe_batch(session, moves, 12)
    with pytest.raises(
        StepConflict, match=r"step 2 was applied already .* \(kept: steps 7 to 10\)"
    ):
        reg.observe_batch(session, moves, 2)
    other = walk(domain, int(moves[2][-2]), 2, np.random.default_rng(5))
    if other[2][0] != moves[2][-1]:
        with pytest.raises(StepConflict, match="step 10 was applied already with another move"):
            reg.observe_batch(session, (other[0][:1], other[1][:1], other[2][:1]), 10)
    assert session.advisor.steps == 10  # nothing applied by the refusals
