"""Workers that share Redis answer any session exactly as one process would.

Two services in this process (each a worker: its own catalog, registry and event loop) share
one database and one Redis (a prefix of keys of the test's own). Events of one session hop
between them at random, one by one, in batches and over websockets (JSON and binary), with
new expert data sent to either of them mid-stream; every decision must equal the core
advisor's, built from what the database holds. Limits, quotas, idle expiry, retries and
domains made or deleted are the same seen from either worker."""

from __future__ import annotations

import json
from collections.abc import Iterator
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from advisor_client.protocol import unpack
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from starlette.websockets import WebSocketDisconnect

from app import strategies
from app.advice.guide import GuideMap
from app.advice.params import StrategyParams
from app.domain.grid import ACTIONS
from app.service.data.domains import service_leads
from app.service.main import create_app
from app.service.state import ServiceState
from app.strategies import make_advisor, names
from tests.service.conftest import (
    REDIS_URL,
    TINY,
    drop_redis_keys,
    make_settings,
    open_session,
    redis_prefix,
    redis_problem,
)
from tests.service.test_decisions_property import core_tables, expected_json
from tests.service.test_strategies import add_expert, core_goal_priors, led, moves, put_tower

STRATEGIES = names()

PROBLEM = redis_problem()
pytestmark = pytest.mark.skipif(PROBLEM is not None, reason=f"Redis at {REDIS_URL}: {PROBLEM}")

Workers = tuple[list[TestClient], ServiceState]


def start_workers(tmp: Path, n: int, **overrides: Any) -> tuple[list[TestClient], str]:
    prefix = redis_prefix()
    url = f"sqlite:///{tmp / 'advisor.db'}"
    clients = []
    for _ in range(n):
        settings = make_settings(
            tmp, database_url=url, redis_url=REDIS_URL, redis_prefix=prefix, **overrides
        )
        client = TestClient(create_app(settings))
        client.__enter__()
        clients.append(client)
    return clients, prefix


@pytest.fixture(scope="module")
def workers(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Workers]:
    clients, prefix = start_workers(Path(tmp_path_factory.mktemp("data")), 2)
    try:
        service: ServiceState = clients[0].app.state.service  # type: ignore[attr-defined]
        put_tower(clients[0], {"X-API-Key": service.admin_key})
        yield clients, service
    finally:
        for c in clients:
            c.__exit__(None, None, None)
        drop_redis_keys(prefix)


class _Nothing:
    def __enter__(self) -> None:
        return None

    def __exit__(self, *exc: object) -> None:
        return None


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 2**32 - 1),
    strategy=st.sampled_from([*STRATEGIES, "goal_aware", "guide"]),
    kappa=st.sampled_from([0.0, 0.3, 0.8]),
    window=st.sampled_from([1, 7, 60, 300]),
    beta=st.sampled_from([0.0, 0.5]),
    domain=st.sampled_from(["default", "tower"]),
)
def test_events_hopping_between_workers_decide_as_the_core(
    workers: Workers, seed: int, strategy: str, kappa: float, window: int, beta: float,
    domain: str,
) -> None:  # fmt: skip
    """On the shipped maze and on a building of two floors (Redis keeps six actions' advice
    for its retries)."""
    clients, service = workers
    grid = service.catalog.get(domain).domain
    rng = np.random.default_rng(seed)
    start = grid.start if rng.random() < 0.5 else int(rng.integers(grid.n_states))
    params = StrategyParams(beta=beta, rate=0.4, seed=seed % 1000, n_steps=7, threshold=0.3)
    given = strategies.get(strategy).in_force(params)
    maker = clients[int(rng.integers(2))]
    sid, auth, created = open_session(
        maker, domain, kappa=kappa, window=window, start=grid.cell(start), strategy=strategy,
        params=given,
    )  # fmt: skip
    goal_priors = core_goal_priors(service, domain)
    core = make_advisor(
        strategy, core_tables(service, domain), kappa, window, params, goal_priors,
        GuideMap.of(grid, goal_priors, leads=service_leads(grid, service.catalog.lead_cells)),
    )  # fmt: skip
    expect = partial(expected_json, service=service, name=domain)
    assert created["decision"] == led(expect(core.start(start)), core, grid)
    token = auth["Authorization"].removeprefix("Bearer ")
    s, step = start, 1
    for _ in range(int(rng.integers(2, 7))):
        if rng.random() < 0.3:  # new expert data, through either worker: both follow it
            add_expert(clients[int(rng.integers(2))], service, grid, rng, domain)
            core.use_tables(core_tables(service, domain), core_goal_priors(service, domain))
        events, expected, one = [], [], []  # one: as one event's answer has it
        for a in moves(grid, s, rng):
            s2 = int(grid.next_state[s, a])
            events.append({"state": grid.cell(s), "action": grid.actions[a]})
            expected.append(expect(core.observe(s, a, s2)))
            one.append(led(expected[-1], core, grid))
            s = s2
        if not events:
            continue
        client = clients[int(rng.integers(2))]
        how = rng.choice(["one by one", "rest", "websocket", "binary"])
        if how == "one by one":
            got = []
            for e in events:  # each event to a worker of its own
                c = clients[int(rng.integers(2))]
                r = c.post(f"/sessions/{sid}/events", json=e | {"step": step}, headers=auth)
                assert r.status_code == 200, r.text
                got.append(r.json())
                step += 1
        elif how == "rest":
            r = client.post(f"/sessions/{sid}/events", json=events, headers=auth)
            assert r.status_code == 200, r.text
            got = r.json()
            step += len(events)
        else:
            url = f"/sessions/{sid}/stream?token={token}" + "&format=binary" * (how == "binary")
            with client.websocket_connect(url) as ws:
                ws.send_text(json.dumps(events))
                got = (
                    unpack(ws.receive_bytes()).to_dicts()
                    if how == "binary"
                    else json.loads(ws.receive_text())
                )
            step += len(events)
        assert got == (one if how == "one by one" else expected)
        if rng.random() < 0.3:  # a retry of the last event, to the other worker: its answer
            other = clients[int(rng.integers(2))]
            last = events[-1] | {"step": step - 1}
            r = other.post(f"/sessions/{sid}/events", json=last, headers=auth)
            assert r.status_code == 200 and r.json() == one[-1], r.text
    for c in clients:  # both see the same figures
        summary = c.get(f"/sessions/{sid}", headers=auth).json()
        assert summary["steps"] == core.steps and summary["advice_count"] == core.advice_count
        assert summary["benefit"] == core.benefit
    assert clients[int(rng.integers(2))].delete(f"/sessions/{sid}", headers=auth).status_code == 200
    for c in clients:
        assert c.get(f"/sessions/{sid}", headers=auth).status_code == 404


def test_limits_and_quotas_hold_across_workers(tmp_path: Path) -> None:
    clients, prefix = start_workers(tmp_path, 2, max_sessions=3, client_max_sessions=2)
    try:
        a, b = clients
        assert a.post("/domains/default/sessions", json={}).status_code == 201
        assert b.post("/domains/default/sessions", json={}).status_code == 201
        r = a.post("/domains/default/sessions", json={})  # this client's third: its quota
        assert r.status_code == 429 and "ADVISOR_CLIENT_MAX_SESSIONS" in r.json()["detail"]
        admin = {"X-API-Key": a.app.state.service.admin_key}  # type: ignore[attr-defined]
        assert b.post("/domains/default/sessions", json={}, headers=admin).status_code == 201
        r = a.post("/domains/default/sessions", json={}, headers=admin)  # the fourth in all
        assert r.status_code == 503 and "maximum of 3 live sessions" in r.json()["detail"]
        for c in clients:
            assert c.get("/health").json()["sessions"] == 3
    finally:
        for c in clients:
            c.__exit__(None, None, None)
        drop_redis_keys(prefix)


def test_idle_sessions_expire_for_every_worker(tmp_path: Path) -> None:
    clients, prefix = start_workers(tmp_path, 2, session_idle_seconds=0.5, sweep_seconds=0.1)
    try:
        a, b = clients
        sid, auth, _ = open_session(a)
        assert b.get(f"/sessions/{sid}", headers=auth).status_code == 200
        import time

        deadline = time.monotonic() + 10
        while b.get(f"/sessions/{sid}", headers=auth).status_code != 404:
            assert time.monotonic() < deadline, "the idle session never expired"
            time.sleep(0.1)
        assert a.get(f"/sessions/{sid}", headers=auth).status_code == 404
        assert a.get("/health").json()["sessions"] == 0
    finally:
        for c in clients:
            c.__exit__(None, None, None)
        drop_redis_keys(prefix)


def test_domains_made_or_deleted_by_one_worker_are_seen_by_the_other(workers: Workers) -> None:
    (a, b), service = workers
    admin = {"X-API-Key": service.admin_key}
    assert a.put("/domains/hall", json={"map": TINY}, headers=admin).status_code == 201
    assert b.get("/domains/hall").status_code == 200
    assert "hall" in [d["name"] for d in b.get("/domains").json()]
    sid, auth, _ = open_session(b, "hall")
    steps = {"trajectories": [{"steps": [{"state": [5, 1], "action": "E"}]}]}
    assert b.post("/domains/hall/trajectories", json=steps, headers=admin).status_code == 201
    assert a.get("/domains/hall").json()["trajectories"] == 1
    r = a.put("/domains/hall", json={"map": TINY, "alpha0": 0.5}, headers=admin)
    assert r.status_code == 200 and b.get("/domains/hall").json()["alpha0"] == 0.5
    assert b.get(f"/sessions/{sid}", headers=auth).status_code == 200  # the same map: kept
    assert a.delete("/domains/hall", headers=admin).status_code == 204
    assert b.get("/domains/hall").status_code == 404
    assert b.get(f"/sessions/{sid}", headers=auth).status_code == 404
    assert "hall" not in [d["name"] for d in b.get("/domains").json()]


def test_redis_not_answering_is_503_and_nothing_applied(
    workers: Workers, monkeypatch: pytest.MonkeyPatch
) -> None:
    from app.service.live.lanes import Lane, LaneError

    (a, _), _ = workers
    sid, auth, _ = open_session(a)
    event = {"state": [28, 0], "action": "E", "step": 1}

    async def down(self: Lane, *args: Any) -> Any:
        raise LaneError("Redis closed the connection")

    with monkeypatch.context() as m:
        m.setattr(Lane, "call", down)
        r = a.post(f"/sessions/{sid}/events", json=event, headers=auth)
        assert r.status_code == 503 and "Redis, which does not answer" in r.json()["detail"]
        token = auth["Authorization"].removeprefix("Bearer ")
        with a.websocket_connect(f"/sessions/{sid}/stream?token={token}") as ws:
            with pytest.raises(WebSocketDisconnect) as closed:  # the session not reachable
                ws.receive_text()
            assert closed.value.code == 1013
    r = a.post(f"/sessions/{sid}/events", json=event, headers=auth)  # the retry, once it answers
    assert r.status_code == 200 and r.json()["step"] == 1
    with a.websocket_connect(f"/sessions/{sid}/stream?token={token}") as ws:  # mid-stream
        frame = json.dumps([event | {"step": 2}])
        with monkeypatch.context() as m:
            m.setattr(Lane, "call", down)
            ws.send_text(frame)
            assert json.loads(ws.receive_text())["status"] == 503
        ws.send_text(frame)  # the same frame again: applied once
        assert [d["step"] for d in json.loads(ws.receive_text())] == [2]
    assert a.get(f"/sessions/{sid}", headers=auth).json()["steps"] == 2


def test_a_retry_of_any_kept_step_is_answered_again_by_any_worker(tmp_path: Path) -> None:
    """With 6 steps kept, requests of 1 to 4 events alternate between the workers; after each, a
    retry of a random run of steps among the last 6 (the older of Redis' two records strings
    included) through either worker gets the answers those steps got, and nothing is applied;
    a step older than anything kept is refused with 409."""
    clients, prefix = start_workers(tmp_path, 2, replay_steps=6)
    try:
        sid, auth, _ = open_session(clients[0])
        grid = clients[0].app.state.service.catalog.get("default").domain  # type: ignore[attr-defined]
        rng = np.random.default_rng(5)
        s, step, answers = grid.start, 1, {}
        events: dict[int, dict[str, Any]] = {}
        for _ in range(40):
            batch: list[dict[str, Any]] = []
            for a in rng.integers(0, 4, int(rng.integers(1, 5))).tolist():
                events[step + len(batch)] = {"state": grid.cell(s), "action": ACTIONS[a]}
                batch.append(events[step + len(batch)])
                s = int(grid.next_state[s, a])
            c = clients[int(rng.integers(2))]
            r = c.post(f"/sessions/{sid}/events", json=[batch[0] | {"step": step}, *batch[1:]],
                       headers=auth)  # fmt: skip
            assert r.status_code == 200, r.text
            for d in r.json():
                answers[d["step"]] = d
            step += len(batch)
            last = step - 1
            lo = int(rng.integers(max(1, last - 5), last + 1))
            hi = int(rng.integers(lo, last + 1))
            again = [events[k] | {"step": k} for k in range(lo, hi + 1)]
            r = clients[int(rng.integers(2))].post(
                f"/sessions/{sid}/events", json=again, headers=auth
            )
            assert r.status_code == 200, r.text
            assert r.json() == [answers[k] for k in range(lo, hi + 1)]
        assert clients[1].get(f"/sessions/{sid}", headers=auth).json()["steps"] == step - 1
        r = clients[0].post(f"/sessions/{sid}/events", json=events[1] | {"step": 1}, headers=auth)
        assert r.status_code == 409 and "no longer kept" in r.json()["detail"]
    finally:
        for c in clients:
            c.__exit__(None, None, None)
        drop_redis_keys(prefix)


def test_every_key_of_a_session_lives_no_longer_than_its_time_to_live(tmp_path: Path) -> None:
    """The commit renews the keys' time to live only once a quarter of it has gone by: still,
    every key a session holds in Redis (its state, its two strings of kept decisions) has one,
    at most the full time, through the records' rotations; and once a quarter has gone by, the
    next event renews all of them."""
    import redis

    clients, prefix = start_workers(tmp_path, 1, replay_steps=6)
    r = redis.Redis.from_url(REDIS_URL, decode_responses=True)

    def pttl(key: str) -> int:
        return int(r.pttl(key))  # type: ignore[arg-type]

    try:
        c = clients[0]
        sid, auth, _ = open_session(c)
        service = c.app.state.service  # type: ignore[attr-defined]
        ttl = service.sessions._ttl()
        grid = service.catalog.get("default").domain
        rng = np.random.default_rng(3)
        s, step = grid.start, 1

        def send(n: int) -> None:
            nonlocal s, step
            batch = []
            for a in rng.integers(0, 4, n).tolist():
                batch.append({"state": grid.cell(s), "action": ACTIONS[a]})
                s = int(grid.next_state[s, a])
            got = c.post(f"/sessions/{sid}/events", json=[batch[0] | {"step": step}, *batch[1:]],
                         headers=auth)  # fmt: skip
            assert got.status_code == 200, got.text
            step += n

        keys = [f"{prefix}:s:{sid}", f"{prefix}:r:{sid}", f"{prefix}:r:{sid}:old"]
        for n in [1] * 9 + [4, 6, 1, 3, 7, 1, 1]:  # rotations in one piece and by copy
            send(n)
            for key in keys:
                left = pttl(key)
                assert left == -2 or 0 < left <= ttl, (key, left)  # gone, or a time to live
        assert all(r.exists(key) for key in keys)
        for key in keys:
            r.pexpire(key, 5_000)
        r.hset(keys[0], "touched", "0")  # as if a quarter of the time had gone by
        send(1)
        assert all(pttl(key) > ttl - 5_000 for key in keys), [pttl(k) for k in keys]
    finally:
        for c in clients:
            c.__exit__(None, None, None)
        drop_redis_keys(prefix)


@pytest.mark.parametrize("kept", ["retired strategy", "garbled"])
def test_a_session_another_version_kept_in_redis_is_410_with_a_log_line(
    workers: Workers, kept: str, caplog: pytest.LogCaptureFixture
) -> None:
    """A session Redis holds that this service cannot read (a strategy it does not know, or
    bytes of another format) is refused 410 saying so, and logged; never a 500."""
    import msgspec
    import redis

    from app.service.live import codec

    clients, service = workers
    sid, auth, _ = open_session(clients[0])  # the other worker has never seen it
    r = redis.Redis.from_url(REDIS_URL)
    key = f"{service.sessions.prefix}:s:{sid}"  # type: ignore[attr-defined]
    v = codec.peek(codec.unpacked(r.hget(key, "blob")))  # type: ignore[arg-type]
    v["advisor"]["strategy"] = "retired"
    blob = codec.packed(msgspec.msgpack.encode(v)) if kept != "garbled" else b"\x05garbled"
    r.hset(key, "blob", blob)  # type: ignore[arg-type]  # redis-py takes bytes too
    with caplog.at_level("WARNING", logger="advisor.shared"):
        got = clients[1].get(f"/sessions/{sid}", headers=auth)
    assert got.status_code == 410, got.text
    assert "cannot read" in got.json()["detail"] and "start a new session" in got.json()["detail"]
    assert any("cannot be read" in m for m in caplog.messages)


def test_a_budget_and_a_mute_hold_whichever_worker_answers(workers: Workers) -> None:
    """The budget's bucket and the mute travel with the session's state in Redis."""
    clients, service = workers
    grid = service.catalog.get("default").domain
    sid, auth, created = open_session(clients[0], kappa=0.0, budget={"total": 4})
    assert created["decision"]["advise"] and created["decision"]["cost"]["advice_count"] == 1
    rng = np.random.default_rng(8)
    s, events = grid.start, []
    for a in rng.integers(0, 4, 8).tolist():
        events.append({"state": list(grid.cell(s)), "action": ACTIONS[a]})
        s = int(grid.next_state[s, a])
    first = clients[1].post(f"/sessions/{sid}/events", json=events[:2], headers=auth).json()
    assert [d["advise"] for d in first] == [True, True]  # the start's and two: three of four
    assert clients[0].post(f"/sessions/{sid}/mute", headers=auth).json()["muted"] is True
    muted = clients[1].post(f"/sessions/{sid}/events", json=events[2:4], headers=auth).json()
    assert [d["advise"] for d in muted] == [False, False]
    clients[1].post(f"/sessions/{sid}/mute", json={"muted": False}, headers=auth)
    rest = clients[0].post(f"/sessions/{sid}/events", json=events[4:], headers=auth).json()
    assert [d["advise"] for d in rest] == [True, False, False, False]  # the fourth, then none
    seen = clients[1].get(f"/sessions/{sid}", headers=auth).json()
    assert seen["budget"]["left"] == 0 and seen["muted"] is False
