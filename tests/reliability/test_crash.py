"""Crash safety: SIGKILL the real server while trajectory batches stream in, restart it, and
check that nothing acknowledged was lost and that the prior still equals its trajectories.

Three writers post batches of expert trajectories (random walks on the tiny map, a few agent
types, some with goals) as fast as the server takes them. After a number of acknowledged
batches the server is killed (SIGKILL: no shutdown hook runs) with requests in flight,
restarted on the same data directory, streamed to again and killed again. Then:

* every acknowledged trajectory is stored (compared as a multiset of (agent type, pairs,
  goal)); a batch in flight at the kill is either stored whole or not at all, and nothing
  else is stored;
* the stored counts of every prior table equal a recount from the stored trajectories
  (``Store.counts`` == ``Store.recount``), for the streamed domain and for ``default``;
* what the restarted service serves (trajectory count, theta) equals a prior fitted from
  the stored trajectories.

It runs on SQLite with one process, and on PostgreSQL with one process and with two workers
sharing Redis (``serve --workers 2``): writers' requests then reach both workers, which
ingest at once into one database, and the kill takes every process of the server.

This is a process crash: the OS survives, so it shows that an answer is sent only after the
commit and that a transaction is never half-applied; it cannot show what a power cut does
to the disk (SQLite is set to fsync at every commit for that).
"""

from __future__ import annotations

import os
import signal
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from app.advice.priors import ActionPrior
from app.domain.grid import ACTIONS, GridDomain
from app.service.data.store import Store, Trajectory
from tests.reliability.conftest import Live, server_errors, start, stop
from tests.reliability.test_workers import workers_of
from tests.service.conftest import (
    REDIS_URL,
    TINY,
    drop_redis_keys,
    redis_prefix,
    redis_problem,
)

WRITERS = 3
KILL_AFTER = 25  # acknowledged batches per round before the kill
ROUNDS = 2
TYPES = [None, "staff", "visitor"]
Key = tuple[str | None, tuple[int, ...], int | None]


@dataclass
class Journal:
    """What the writers sent: acknowledged batches, and batches whose fate is unknown."""

    acked: list[list[Key]] = field(default_factory=list)
    unknown: list[list[Key]] = field(default_factory=list)
    refused: list[str] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)


def batch(grid: GridDomain, rng: np.random.Generator) -> tuple[dict[str, Any], list[Key]]:
    """A request body of 1-8 random walks, and their keys as the store will hold them."""
    trajs, keys = [], []
    for _ in range(int(rng.integers(1, 9))):
        s = int(rng.integers(grid.n_states))
        pairs = []
        for a in rng.integers(0, 4, int(rng.integers(1, 30))).tolist():
            pairs.append((s, a))
            s = int(grid.next_state[s, a])
        agent = TYPES[int(rng.integers(len(TYPES)))]
        goal = grid.goals[int(rng.integers(len(grid.goals)))] if rng.random() < 0.5 else None
        steps = [{"state": list(grid.cell(p)), "action": ACTIONS[q]} for p, q in pairs]
        body: dict[str, Any] = {"steps": steps, "agent_type": agent}
        if goal is not None:
            body["goal"] = list(grid.cell(goal))
        trajs.append(body)
        keys.append((agent, tuple(v for pair in pairs for v in pair), goal))
    return {"trajectories": trajs}, keys


def writer(url: str, key: str, seed: int, journal: Journal, stop_at: float) -> None:
    grid = GridDomain.from_strings(TINY)
    rng = np.random.default_rng(seed)
    with httpx.Client(base_url=url, timeout=10, headers={"X-API-Key": key}) as http:
        while time.monotonic() < stop_at:
            body, keys = batch(grid, rng)
            try:
                r = http.post("/domains/crash/trajectories", json=body)
            except httpx.TransportError:  # killed: this batch may or may not have committed
                with journal.lock:
                    journal.unknown.append(keys)
                return
            pairs = sum(len(k[1]) // 2 for k in keys)
            with journal.lock:
                if r.status_code != 201 or r.json() != {"accepted": len(keys), "pairs": pairs}:
                    journal.refused.append(r.text)  # the test fails on any
                    return
                journal.acked.append(keys)


def crash_round(live: Live, journal: Journal, seed: int) -> None:
    """Stream from WRITERS threads; SIGKILL the server once KILL_AFTER more batches are
    acknowledged (writers keep posting, so requests are in flight); wait for the writers."""
    before = len(journal.acked)
    stop_at = time.monotonic() + 60  # a bound if the kill never comes
    threads = [
        threading.Thread(
            target=writer, args=(live.url, live.admin_key, seed * 10 + i, journal, stop_at)
        )
        for i in range(WRITERS)
    ]
    for t in threads:
        t.start()
    deadline = time.monotonic() + 60
    while len(journal.acked) - before < KILL_AFTER and time.monotonic() < deadline:
        time.sleep(0.005)
    assert len(journal.acked) - before >= KILL_AFTER, "the writers did not get through"
    for pid in workers_of(live):  # every worker too (none of them shuts down cleanly)
        os.kill(pid, signal.SIGKILL)
    stop(live, signal.SIGKILL)
    for t in threads:
        t.join(30)
        assert not t.is_alive()
    assert journal.refused == []


def stored_keys(trajs: list[Trajectory]) -> Counter[Key]:
    return Counter((t.agent_type, tuple(t.pairs.ravel().tolist()), t.goal) for t in trajs)


@pytest.mark.parametrize("workers", [1, 2])
def test_sigkill_mid_stream_loses_no_acknowledged_trajectory(
    tmp_path: Path,
    db_url: str,
    workers: int,
) -> None:
    if workers > 1 and db_url.startswith("sqlite"):
        pytest.skip("several workers ingest at once on PostgreSQL (SQLite: one process)")
    env: dict[str, Any] = {"ADVISOR_DATABASE_URL": db_url}
    prefix = redis_prefix()
    if workers > 1:
        problem = redis_problem()
        if problem:
            pytest.skip(f"Redis at {REDIS_URL}: {problem}")
        env |= {"ADVISOR_WORKERS": str(workers), "ADVISOR_REDIS_URL": REDIS_URL,
                "ADVISOR_REDIS_PREFIX": prefix}  # fmt: skip
    data = tmp_path / "data"
    live = start(data, **env)
    assert len(workers_of(live)) == (workers if workers > 1 else 0)
    r = httpx.put(f"{live.url}/domains/crash", json={"map": TINY}, headers=live.admin)
    assert r.status_code == 201
    journal = Journal()
    servers = [live]
    try:
        for round_ in range(ROUNDS):
            crash_round(live, journal, round_)
            assert live.process.returncode == -signal.SIGKILL
            live = start(data, **env)  # the same data directory and database, a new port
            servers.append(live)
        check_after_restart(live, journal, db_url)
    finally:
        stop(live)
        drop_redis_keys(prefix)
    assert [server_errors(s) for s in servers] == [[]] * len(servers)


def check_after_restart(live: Live, journal: Journal, url: str) -> None:
    grid = GridDomain.from_strings(TINY)
    store = Store(url)
    try:
        stored = stored_keys(store.trajectories("crash"))
        acked = Counter(k for keys in journal.acked for k in keys)
        assert not acked - stored, "acknowledged trajectories are missing"
        extra = stored - acked
        # what is stored beyond the acknowledged: whole in-flight batches, nothing else
        whole = [Counter(keys) for keys in journal.unknown if not Counter(keys) - extra]
        assert sum(whole, Counter()) == extra
        default_map = httpx.get(f"{live.url}/domains/default").json()["map"]
        sizes = {"crash": grid.n_states, "default": GridDomain.from_strings(default_map).n_states}
        for name, n_states in sizes.items():
            counts, recount = store.counts(name), store.recount(name, n_states)
            assert sorted(counts) == sorted(recount)
            for table in counts:
                assert counts[table].n_trajectories == recount[table].n_trajectories
                np.testing.assert_array_equal(counts[table].counts, recount[table].counts)
        trajs = store.trajectories("crash")
    finally:
        store.close()
    # the restarted service serves the prior of exactly what is stored
    served = httpx.get(f"{live.url}/domains/crash").json()
    assert served["trajectories"] == len(trajs) == sum(stored.values())
    prior = ActionPrior(alpha0=1.0).fit([t.pairs for t in trajs], grid.n_states)
    theta = httpx.get(f"{live.url}/domains/crash/prior").json()["theta"]
    got = np.array([theta[r][c] for r, c in grid.cells.tolist()])
    np.testing.assert_allclose(got, prior.theta(), rtol=0, atol=1e-15)
    print(
        f"\ncrash: {ROUNDS} SIGKILLs, {len(journal.acked)} acknowledged batches "
        f"({sum(acked.values())} trajectories), {len(journal.unknown)} in flight at the kills "
        f"({len(whole)} of them committed), {len(trajs)} stored"
    )
