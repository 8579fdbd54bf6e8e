"""A session written out and loaded back (another worker, a restart) goes on exactly as the one
that stayed in memory: the same decisions, bit for bit, for every strategy, whether the prior
changed before the write, between the write and the load, or after."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from app.advice.advisor import DecisionBatch
from app.advice.guide import COMPLY_LEVELS, compliance_state
from app.advice.params import StrategyParams
from app.arrays import Moves
from app.service.data.domains import DomainState
from app.service.data.store import Trajectory
from app.service.live.codec import (
    CodecError,
    advisor_state,
    decision_record,
    dump,
    load,
    packed,
    packed_record,
    peek,
    read_packed_records,
    read_replay_record,
    read_replay_records,
    replay_record,
    restore_advisor,
    unpacked,
)
from app.service.live.registry import Limits, LiveSession, SessionRegistry, SessionSettings
from app.service.security import token_digest
from app.service.state import ServiceState
from app.strategies import names

STRATEGIES = names()


def walk(domain: DomainState, start: int, n: int, rng: np.random.Generator) -> Moves:
    grid = domain.domain
    s, states, actions, nexts = start, [], [], []
    for a in rng.integers(0, 4, n).tolist():
        s2 = int(grid.next_state[s, a])
        states.append(s)
        actions.append(a)
        nexts.append(s2)
        s = s2
    return (np.array(states), np.array(actions), np.array(nexts))


def columns(b: DecisionBatch) -> list[Any]:
    """Everything a batch answers, as exact numbers (floats by their bits)."""
    return [
        b.first_step, b.state.tolist(), b.advise.tolist(), b.kl.view(np.int64).tolist(),
        b.p_normal.view(np.int64).tolist(), b.advice_count.tolist(),
        b.benefit.view(np.int64).tolist(), np.ascontiguousarray(b.advice).view(np.int64).tolist(),
    ]  # fmt: skip


def figures(reg: SessionRegistry, s: LiveSession) -> list[Any]:
    snap = reg.describe(s)
    return [
        snap.steps, snap.position, snap.p_normal, snap.advice_count, snap.total_cost,
        snap.benefit, snap.path, snap.p_history, [(a, c, v) for a, c, v in snap.advice],
        snap.goals, snap.params, snap.kappa, snap.window, snap.strategy, snap.table_key,
    ]  # fmt: skip


def params_for(strategy: str) -> StrategyParams:
    if strategy == "goal_aware":
        return StrategyParams(beta=0.5)
    if strategy == "random":
        return StrategyParams(rate=0.3, seed=11)
    return StrategyParams()


@pytest.fixture
def domain(service: ServiceState) -> DomainState:
    d = service.catalog.get("default")
    service.catalog.guide_map(d)  # goal priors and the guide map, for goal_aware and guide
    return d


@pytest.mark.parametrize("strategy", STRATEGIES)
@settings(
    max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    seed=st.integers(0, 2**32 - 1),
    window=st.sampled_from([1, 7, 40]),
    kappa=st.sampled_from([0.0, 0.3, 0.8]),
    chunks=st.lists(st.integers(1, 60), min_size=2, max_size=6),
    update_at=st.integers(0, 5),
    when=st.sampled_from(["before", "between", "after"]),
)
def test_a_loaded_session_decides_as_the_one_that_stayed(
    service: ServiceState, domain: DomainState, strategy: str, seed: int, window: int,
    kappa: float, chunks: list[int], update_at: int, when: str,
) -> None:  # fmt: skip
    rng = np.random.default_rng(seed)
    reg = SessionRegistry(Limits(100), 3600.0, replay_steps=32)
    start = domain.domain.start
    params = params_for(strategy)
    stayed, d0 = reg.create(
        domain, SessionSettings.of(strategy, kappa, window, params, start=start)
    )
    moved, d1 = reg.create(domain, SessionSettings.of(strategy, kappa, window, params))
    assert d0 == d1
    here = start
    for i, n in enumerate(chunks):
        moves = walk(domain, here, n, rng)
        here = int(moves[2][-1])
        update = i == update_at
        if update and when == "before":
            domain = _update(service, reg, domain, rng)
        raw = dump(moved)
        if update and when == "between":
            domain = _update(service, reg, domain, rng)
        moved = load(raw, service.catalog.get(domain.name), 32)
        if update and when == "after":
            domain = _update(service, reg, domain, rng)
            moved.advisor.use_tables(domain.view.tables["*"], domain.goal_priors)
        if n == 1:
            one = [int(m[0]) for m in moves]
            a, b = reg.observe_one(stayed, *one), reg.observe_one(moved, *one)
            assert a == b
        else:
            a_batch, b_batch = reg.observe_batch(stayed, moves), reg.observe_batch(moved, moves)
            assert columns(a_batch) == columns(b_batch)
        assert figures(reg, stayed) == figures(reg, moved)


def _update(
    service: ServiceState, reg: SessionRegistry, domain: DomainState, rng: np.random.Generator
) -> DomainState:
    """A new expert trajectory: a prior update, which the registry's sessions follow."""
    grid = domain.domain
    goal = grid.goals[int(rng.integers(len(grid.goals)))]
    pairs = np.array([[grid.start, int(rng.integers(4))], [goal, 0]])
    updated = service.catalog.add_trajectories(domain, [Trajectory(None, pairs, goal)])
    reg.retable(updated)
    return updated


def test_a_dump_holds_the_token_as_a_digest_only(
    service: ServiceState, domain: DomainState
) -> None:
    reg = SessionRegistry(Limits(10), 3600.0)
    session, _ = reg.create(
        domain, SessionSettings.of("paper", 0.5, 300, start=domain.domain.start)
    )
    raw = dump(session)
    assert session.token.encode() not in raw
    assert peek(raw)["token_digest"] == token_digest(session.token)
    loaded = load(raw, domain, 500)
    assert loaded.token == "" and loaded.token_digest == session.token_digest


def test_a_session_of_another_map_is_refused(service: ServiceState, domain: DomainState) -> None:
    reg = SessionRegistry(Limits(10), 3600.0)
    session, _ = reg.create(
        domain, SessionSettings.of("paper", 0.5, 300, start=domain.domain.start)
    )
    raw = dump(session)
    with pytest.raises(CodecError, match="another map"):
        load(_renamed(raw), domain, 500)


def _renamed(raw: bytes) -> dict[str, Any]:
    v = peek(raw)
    v["map"] = v["map"][::-1]  # the digest of another map
    return v


def test_a_decisions_record_reads_back_as_its_batch_does(domain: DomainState) -> None:
    reg = SessionRegistry(Limits(10), 3600.0)
    session, _ = reg.create(domain, SessionSettings.of("guide", 0.0, 30))
    rng = np.random.default_rng(2)
    grid = domain.domain
    s = grid.start
    for a in rng.integers(0, 4, 40).tolist():
        adv = session.advisor
        before = (adv.advice_count, adv.benefit)
        d = reg.observe_one(session, s, a, int(grid.next_state[s, a]))
        s = d.state
        one = read_replay_record(decision_record(d, adv.kappa, *before))
        batch = read_replay_record(replay_record(DecisionBatch.of([d], adv.kappa, *before)))
        assert columns(one) == columns(batch)
        assert one.decisions() == [d]


def test_records_written_one_after_another_read_back_in_order(domain: DomainState) -> None:
    """Batches of any length, advised or not, one after another in one string (as Redis keeps
    them): each reads back whole, and a string cut anywhere inside a record is refused."""
    reg = SessionRegistry(Limits(10), 3600.0)
    session, _ = reg.create(domain, SessionSettings.of("paper", 0.0, 30))
    rng = np.random.default_rng(3)
    written, raw = [], b""
    for n in (1, 7, 0, 120, 3):
        if n == 0:
            continue
        moves = walk(domain, session.position, n, rng)
        batch = reg.observe_batch(session, moves)
        written.append(columns(batch))
        raw += replay_record(batch)
    assert [columns(b) for b in read_replay_records(raw)] == written
    assert read_replay_records(b"") == []
    for cut in (1, len(raw) // 2, len(raw) - 1):
        with pytest.raises(CodecError):
            read_replay_records(raw[:cut])


def test_packed_records_read_back_in_order_and_cut_ones_are_refused(domain: DomainState) -> None:
    """As Redis keeps them: each record packed (compressed when long enough) behind its
    length, one after another; they read back as written, and a string cut anywhere is
    refused rather than misread."""
    reg = SessionRegistry(Limits(10), 3600.0)
    session, _ = reg.create(domain, SessionSettings.of("paper", 0.0, 30))
    rng = np.random.default_rng(4)
    written, raw = [], b""
    for n in (1, 500, 2, 37):
        batch = reg.observe_batch(session, walk(domain, session.position, n, rng))
        written.append(columns(batch))
        raw += packed_record(replay_record(batch))
    assert [columns(b) for b in read_packed_records(raw)] == written
    assert read_packed_records(b"") == []
    for cut in (1, 5, len(raw) // 2, len(raw) - 1):
        with pytest.raises(CodecError):
            read_packed_records(raw[:cut])


@given(st.binary(max_size=2000))
def test_packed_data_unpacks_to_itself(data: bytes) -> None:
    assert unpacked(packed(data)) == data


def test_a_packed_state_loads_as_the_plain_one_and_a_plain_one_still_loads(
    domain: DomainState,
) -> None:
    reg = SessionRegistry(Limits(10), 3600.0)
    session, _ = reg.create(
        domain, SessionSettings.of("paper", 0.5, 300, start=domain.domain.start)
    )
    reg.observe_batch(session, walk(domain, session.position, 400, np.random.default_rng(5)))
    raw = dump(session, replay=False)
    small = packed(raw)
    assert len(small) < len(raw) // 2  # a window of the few values a map's tables hold
    assert unpacked(small) == raw
    assert unpacked(raw) == raw  # a state written before states were packed
    with pytest.raises(CodecError):
        unpacked(b"\x01not lz4")
    with pytest.raises(CodecError):
        unpacked(b"\x07")


def test_a_guide_session_saved_before_compliance_was_learned_loads_with_the_prior(
    domain: DomainState,
) -> None:
    """A guide session written by the version before guide learned compliance and checked
    where a reading can have come from (no ``_comply``, no ``_came`` slot) loads, starts from
    the prior's compliance, and goes on deciding."""
    reg = SessionRegistry(Limits(100), 3600.0, replay_steps=32)
    session, _ = reg.create(domain, SessionSettings.of("guide", 0.5, 40, params_for("guide")))
    reg.observe_batch(session, walk(domain, domain.domain.start, 30, np.random.default_rng(3)))
    state = advisor_state(session.advisor)
    assert {"_comply", "_came"} <= set(state["slots"])
    del state["slots"]["_comply"], state["slots"]["_came"]
    old = restore_advisor(state, domain, "*")
    assert old._comply == compliance_state() and old._came == -1  # type: ignore[attr-defined]
    assert old._loglik == session.advisor._loglik
    here = int(domain.domain.start)
    moves = walk(domain, here, 20, np.random.default_rng(4))
    assert len(old.observe_batch(*moves)) == 20


@pytest.mark.parametrize(
    "kept", [COMPLY_LEVELS + 3, COMPLY_LEVELS + 9, COMPLY_LEVELS + 11, COMPLY_LEVELS + 12]
)
def test_a_guide_session_saved_with_fewer_compliance_slots_loads(
    domain: DomainState, kept: int
) -> None:
    """A guide session whose compliance evidence was written by an earlier version, without
    the slots of undone advice (levels, chance, since, held only: ``COMPLY_LEVELS + 3``),
    without those of the way it is led (the last decision's advice, whether it walks it:
    ``+ 9``), without the advice budget's (``+ 11``) or without where the last piece was
    taken (``+ 12``), loads with them as a session starts them and decides as the same
    session with them so does."""
    reg = SessionRegistry(Limits(100), 3600.0, replay_steps=32)
    session, _ = reg.create(domain, SessionSettings.of("guide", 0.5, 40, params_for("guide")))
    reg.observe_batch(session, walk(domain, domain.domain.start, 30, np.random.default_rng(3)))
    state = advisor_state(session.advisor)
    comply = list(state["slots"]["_comply"])
    fresh = compliance_state()
    assert len(comply) == len(fresh) == COMPLY_LEVELS + 13
    state["slots"]["_comply"] = [*comply[:kept]]
    old = restore_advisor(state, domain, "*")
    assert old._comply == [*comply[:kept], *fresh[kept:]]  # type: ignore[attr-defined]
    same = restore_advisor(advisor_state(session.advisor), domain, "*")
    same._comply[kept:] = fresh[kept:]  # type: ignore[attr-defined]
    moves = walk(domain, int(domain.domain.start), 20, np.random.default_rng(4))
    got, want = old.observe_batch(*moves), same.observe_batch(*moves)
    assert got.advise.tolist() == want.advise.tolist() and got.kl.tolist() == want.kl.tolist()


def test_a_guide_session_saved_before_the_lost_models_la_and_ls_loads(
    domain: DomainState,
) -> None:
    """A guide session written with a sum per model but LA's and LS's (the version before
    them: 4 + 3 G) loads with theirs the open-moves model's, and decides as the same session
    whose LA and LS sums are that."""
    reg = SessionRegistry(Limits(100), 3600.0, replay_steps=32)
    session, _ = reg.create(domain, SessionSettings.of("guide", 0.5, 40, params_for("guide")))
    reg.observe_batch(session, walk(domain, domain.domain.start, 30, np.random.default_rng(3)))
    state = advisor_state(session.advisor)
    loglik = list(state["slots"]["_loglik"])
    n_goals = len(domain.domain.goals)
    assert len(loglik) == 4 + 3 * n_goals + 2
    state["slots"]["_loglik"] = loglik[:-2]
    old = restore_advisor(state, domain, "*")
    assert old._loglik == [*loglik[:-2], loglik[1], loglik[1]]
    same = restore_advisor(advisor_state(session.advisor), domain, "*")
    same._loglik[-2:] = [loglik[1], loglik[1]]
    moves = walk(domain, int(domain.domain.start), 20, np.random.default_rng(4))
    got, want = old.observe_batch(*moves), same.observe_batch(*moves)
    assert got.advise.tolist() == want.advise.tolist() and got.kl.tolist() == want.kl.tolist()
    assert old._loglik == same._loglik


def test_a_guide_session_saved_before_destinations_were_set_aside_loads(
    domain: DomainState,
) -> None:
    """A guide session written without the destinations' doubt (the version before a visit
    set one aside) loads with none set aside, and decides as the same session
    whose doubts are all 0."""
    reg = SessionRegistry(Limits(100), 3600.0, replay_steps=32)
    session, _ = reg.create(domain, SessionSettings.of("guide", 0.5, 40, params_for("guide")))
    reg.observe_batch(session, walk(domain, domain.domain.start, 30, np.random.default_rng(3)))
    state = advisor_state(session.advisor)
    assert "doubt" in state["slots"]
    del state["slots"]["doubt"]
    old = restore_advisor(state, domain, "*")
    n_goals = len(domain.domain.goals)
    assert old.doubt == [0] * n_goals  # type: ignore[attr-defined]
    same = restore_advisor(advisor_state(session.advisor), domain, "*")
    same.doubt = [0] * n_goals  # type: ignore[attr-defined]
    moves = walk(domain, int(domain.domain.start), 40, np.random.default_rng(5))
    got, want = old.observe_batch(*moves), same.observe_batch(*moves)
    assert got.advise.tolist() == want.advise.tolist() and got.kl.tolist() == want.kl.tolist()
    assert old.alive == same.alive and old.doubt == same.doubt  # type: ignore[attr-defined]


def test_a_guide_session_saved_before_purposeful_walks_were_left_alone_loads(
    domain: DomainState,
) -> None:
    """A guide session written without the states decided for since the last piece of
    advice (the version before a visitor walking a shortest path of its own was left alone)
    loads with none, and decides as the same session whose run is empty."""
    reg = SessionRegistry(Limits(100), 3600.0, replay_steps=32)
    session, _ = reg.create(domain, SessionSettings.of("guide", 0.5, 40, params_for("guide")))
    reg.observe_batch(session, walk(domain, domain.domain.start, 30, np.random.default_rng(3)))
    state = advisor_state(session.advisor)
    assert "_run" in state["slots"] and state["slots"]["_run"]
    del state["slots"]["_run"]
    old = restore_advisor(state, domain, "*")
    assert old._run == []  # type: ignore[attr-defined]
    same = restore_advisor(advisor_state(session.advisor), domain, "*")
    same._run = []  # type: ignore[attr-defined]
    moves = walk(domain, int(domain.domain.start), 40, np.random.default_rng(5))
    got, want = old.observe_batch(*moves), same.observe_batch(*moves)
    assert got.advise.tolist() == want.advise.tolist() and got.kl.tolist() == want.kl.tolist()
    assert old._run == same._run  # type: ignore[attr-defined]
