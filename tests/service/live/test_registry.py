"""What a session reserves of the registry's budget bounds what it takes, for every strategy,
after its window filled and after a prior update made it keep the values of its pairs; the
budget, the session limit and the per-client quotas admit and refuse as they say."""

from __future__ import annotations

import asyncio
import threading
import tracemalloc

import numpy as np
import pytest

from app.advice.advisor import Decision
from app.advice.params import StrategyParams
from app.service.config import Settings
from app.service.data.domains import DomainState
from app.service.data.store import Trajectory
from app.service.live.registry import (
    SESSION_OVERHEAD,
    ClientQuotaReached,
    Limits,
    SessionMemoryFull,
    SessionRegistry,
    SessionSettings,
    TooManySessions,
)
from app.service.state import ServiceState
from app.strategies import names

STRATEGIES = names()

WINDOW = Settings.model_fields["max_window"].default  # the largest a session may ask: 10,000
PER_STRATEGY = 4


def _moves(domain: DomainState, n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    grid = domain.domain
    s = rng.integers(0, grid.n_states, n)
    a = rng.integers(0, 4, n)
    return s, a, grid.next_state[s, a]


def _prepared(service: ServiceState) -> DomainState:
    domain = service.catalog.get("default")
    service.catalog.guide_map(domain)  # the domain's shared tables, built before measuring
    return domain


@pytest.mark.parametrize("strategy", STRATEGIES)
def test_a_session_takes_no_more_than_it_reserves(service: ServiceState, strategy: str) -> None:
    domain = _prepared(service)
    registry = SessionRegistry(Limits(10_000), 3600.0)
    params = StrategyParams(beta=0.5) if strategy == "goal_aware" else StrategyParams()
    moves = _moves(domain, WINDOW + 7, 1)
    one = (moves[0][:1], moves[1][:1], moves[2][:1])

    def session_lives() -> list[str]:
        ids = []
        for _ in range(PER_STRATEGY):
            s, _ = registry.create(domain, SessionSettings.of(strategy, 0.5, WINDOW, params))
            registry.observe_batch(s, moves)  # the window full, rings full, advice logged
            ids.append(s.id)
        return ids

    for sid in session_lives():  # warm-up: compiled code loaded, caches made
        registry.end(sid)
    more = [Trajectory(None, np.array([[0, 1], [1, 2]]), domain.domain.goals[0])]
    tracemalloc.start()
    try:
        # one more session's life, traced: the interpreter's free lists (up to 2,000 tuples of
        # each size, which a rule's batch makes by the thousand) then hold traced objects, so
        # they are in ``before`` rather than counted as the sessions' (about 144 kB in all)
        s, _ = registry.create(domain, SessionSettings.of(strategy, 0.5, WINDOW, params))
        registry.observe_batch(s, moves)
        registry.end(s.id)
        before = tracemalloc.get_traced_memory()[0]
        ids = session_lives()
        # a prior update: sessions keep the values of the pairs added before it (the new
        # tables are the domain's, shared: not the sessions')
        mid = tracemalloc.get_traced_memory()[0]
        updated = service.catalog.add_trajectories(domain, more)
        tables = tracemalloc.get_traced_memory()[0] - mid
        registry.retable(updated)
        for sid in ids:
            registry.observe_batch(registry.get(sid), one)
        after = tracemalloc.get_traced_memory()[0]
    finally:
        tracemalloc.stop()
    per_session = (after - before - tables) / PER_STRATEGY
    reserved = registry.reserved / PER_STRATEGY
    print(f"\n{strategy}: {per_session:,.0f} bytes a session, {reserved:,.0f} reserved")
    assert per_session <= reserved
    assert reserved - per_session < SESSION_OVERHEAD + 8 * WINDOW  # and not far above it


def test_the_memory_budget_refuses_what_it_cannot_hold(service: ServiceState) -> None:
    domain = _prepared(service)
    probe = SessionRegistry(Limits(10), 3600.0)
    s, _ = probe.create(domain, SessionSettings.of("paper", 0.5, 5000))
    need = s.reserved
    assert need == probe.reserved > 5000 * 21  # keys, flags and two models' kept values
    registry = SessionRegistry(Limits(100, max_memory=3 * need), 3600.0)
    made = [registry.create(domain, SessionSettings.of("paper", 0.5, 5000))[0] for _ in range(3)]
    with pytest.raises(SessionMemoryFull):
        registry.create(domain, SessionSettings.of("paper", 0.5, 5000))
    registry.end(made[0].id)
    registry.create(domain, SessionSettings.of("paper", 0.5, 5000))
    assert len(registry) == 3


def test_client_quotas_count_sessions_and_bytes_per_client(service: ServiceState) -> None:
    domain = _prepared(service)
    registry = SessionRegistry(Limits(100, client_sessions=2), 3600.0)
    a = [registry.create(domain, SessionSettings.of(), client="a")[0] for _ in range(2)]
    with pytest.raises(ClientQuotaReached) as refused:
        registry.create(domain, SessionSettings.of(), client="a")
    assert refused.value.args == ("a", "sessions", 2)
    registry.create(domain, SessionSettings.of(), client="b")  # another client is not held up
    registry.create(domain, SessionSettings.of())  # nor one without a quota (the admin)
    registry.end(a[0].id)
    registry.create(domain, SessionSettings.of(), client="a")
    assert registry.client_usage("a")[0] == 2
    registry.end_domain("default")
    assert registry.client_usage("a") == (0, 0) and registry.reserved == 0
    with pytest.raises(TooManySessions):
        tight = SessionRegistry(Limits(1), 3600.0)
        tight.create(domain, SessionSettings.of())
        tight.create(domain, SessionSettings.of())


def test_a_long_batch_runs_in_slices_and_an_event_meanwhile_waits_for_it(
    service: ServiceState,
) -> None:
    """A 'mistake' session (one Python call an event: 500-event slices) sent 2,300 events:
    the loop is free between slices; a single event sent meanwhile is decided after the whole
    batch; the decisions are those of one batch in one go."""
    domain = _prepared(service)
    registry = SessionRegistry(Limits(10), 3600.0)
    sliced, _ = registry.create(domain, SessionSettings.of("mistake", 0.3, 300))
    whole, _ = registry.create(domain, SessionSettings.of("mistake", 0.3, 300))
    moves = _moves(domain, 2300, 4)
    s, a, s2 = (int(v[0]) for v in moves)
    ticks = 0

    async def run() -> tuple[list[Decision], Decision]:
        nonlocal ticks

        async def other_clients() -> None:
            nonlocal ticks
            while True:
                ticks += 1
                await asyncio.sleep(0)

        other = asyncio.create_task(other_clients())
        batch = asyncio.create_task(registry.observe_sliced(sliced, moves))
        await asyncio.sleep(0)  # the batch has started: its first slice ran
        one = await registry.observe_after(sliced, s, a, s2)
        out = await batch
        other.cancel()
        return out.decisions(), one

    got: list[tuple[list[Decision], Decision]] = []
    # a loop of its own, in a thread: the session's browser fixture may hold this thread's
    thread = threading.Thread(target=lambda: got.append(asyncio.run(run())))
    thread.start()
    thread.join(timeout=120)
    decisions, one = got[0]
    assert ticks >= 4  # the loop ran others between the 5 slices
    expected = registry.observe_batch(whole, moves).decisions()
    assert decisions == expected
    assert one == registry.observe_one(whole, s, a, s2)  # after the batch: step 2301
