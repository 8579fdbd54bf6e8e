"""Load: 100 websocket explorers at once, with expert trajectories ingested all the while.

Against the real server (uvicorn, one process): 100 sessions on ``default`` with assorted
kappa and window are opened, then all 100 websockets connect, and each explorer pipelines its
frames (random batches of 1-80 events in all three event forms, sent without waiting for
answers) while reading its answers. Meanwhile a writer posts expert trajectory batches, and a
reader polls ``/overview``, until the explorers are done (bounded in count and time).

Consistency with the core: ingestion goes into a *different* domain (``ingest``), so the
prior the explorers are advised from does not change during the run; each explorer's
expected decisions are those of a core ``Advisor`` (``AdviceTables.paper`` of the theta that
``GET /domains/default/prior`` served before the run), fed the same moves. The test asserts
that ``default``'s prior is the same after the run, that every answer frame equals the core's
decisions for its frame, in order (so none lost, duplicated or reordered), that each session
counted every event, that every trajectory batch was acknowledged and stored, and that the
server logged no error. (Ingesting into ``default`` itself would make the expected decisions
depend on when each batch landed between two frames; tests/service/test_decisions_property.py
covers prior changes mid-stream for one explorer at a time.)
"""

from __future__ import annotations

import asyncio
import json
import multiprocessing
import threading
import time
from dataclasses import dataclass
from typing import Any

import httpx
import numpy as np
import websockets

from app.advice.advisor import Advisor
from app.advice.models import AdviceTables
from app.domain.grid import ACTIONS, GridDomain
from app.service.data.store import Store
from app.service.wire.encode import decision_dict
from tests.client.test_client import run_async
from tests.reliability.conftest import Live, server_errors
from tests.service.conftest import TINY

EXPLORERS = 100
FRAMES = 25
MAX_BATCH = 60
WRITERS = 4  # trajectory writers, each posting batches one after another
TIME_LIMIT = 120.0  # seconds: a bound, never an expectation


@dataclass
class Explorer:
    kappa: float
    window: int
    start: tuple[int, int]
    frames: list[str]  # what it sends
    expected: list[Any]  # the core's decisions, per frame (an object for a one-event frame)
    start_decision: dict[str, Any]
    n_events: int


def wire(d: Any, grid: GridDomain) -> Any:
    out: Any = json.loads(json.dumps(decision_dict(d, grid)))
    return out


def plan(i: int, grid: GridDomain, tables: AdviceTables) -> Explorer:
    """Explorer i's frames and the core's answers to them (computed before the run)."""
    rng = np.random.default_rng(1000 + i)
    kappa = float(rng.choice([0.0, 0.2, 0.5, 1.0, 1.39]))
    window = int(rng.choice([1, 7, 50, 300]))
    s = int(rng.integers(grid.n_states))
    start = grid.cell(s)
    core = Advisor(tables, kappa=kappa, window=window)
    start_decision = wire(core.start(s), grid)
    frames, expected, n = [], [], 0
    for _ in range(FRAMES):
        events: list[dict[str, Any]] = []
        answers = []
        for _ in range(int(rng.integers(1, MAX_BATCH + 1))):
            a = int(rng.integers(4))
            s2 = int(grid.next_state[s, a])
            cell, nxt = list(grid.cell(s)), list(grid.cell(s2))
            form = int(rng.integers(3))
            if form == 2 and s2 != s:
                events.append({"state": cell, "next_state": nxt})
            elif form == 1:
                events.append({"state": cell, "action": ACTIONS[a], "next_state": nxt})
            else:
                events.append({"state": cell, "action": a if rng.random() < 0.3 else ACTIONS[a]})
            answers.append(wire(core.observe(s, a, s2), grid))
            s = s2
        n += len(events)
        single = len(events) == 1
        frames.append(json.dumps(events[0] if single else events))
        expected.append(answers[0] if single else answers)
    return Explorer(kappa, window, start, frames, expected, start_decision, n)


def trajectory_batch(grid: GridDomain, rng: np.random.Generator) -> dict[str, Any]:
    trajs = []
    for _ in range(int(rng.integers(1, 6))):
        s, steps = int(rng.integers(grid.n_states)), []
        for a in rng.integers(0, 4, int(rng.integers(1, 25))).tolist():
            steps.append({"state": list(grid.cell(s)), "action": ACTIONS[a]})
            s = int(grid.next_state[s, a])
        trajs.append({"steps": steps, "agent_type": ["staff", None][int(rng.integers(2))]})
    return {"trajectories": trajs}


def background(url: str, key: str, started: Any, done: Any, out: Any) -> None:
    """In a process of its own (so the explorers' busy event loop does not pace it): post
    trajectory batches to ``ingest`` and poll ``/overview`` until ``done`` is set."""
    stats: dict[str, Any] = {"batches": 0, "trajectories": 0, "polls": 0, "errors": []}
    lock = threading.Lock()

    def ingest() -> None:
        rng = np.random.default_rng(threading.get_ident() % 2**32)
        grid = GridDomain.from_strings(TINY)
        with httpx.Client(base_url=url, timeout=30, headers={"X-API-Key": key}) as http:
            while not done.is_set() and stats["batches"] < 5000:
                body = trajectory_batch(grid, rng)
                r = http.post("/domains/ingest/trajectories", json=body)
                with lock:
                    if r.status_code != 201:
                        stats["errors"].append(r.text)
                        return
                    stats["batches"] += 1
                    stats["trajectories"] += len(body["trajectories"])
                started.set()

    def poll() -> None:
        with httpx.Client(base_url=url, timeout=30) as http:
            while not done.wait(0.02):
                r = http.get("/overview", params={"limit": 50})
                if r.status_code != 200:
                    stats["errors"].append(r.text)
                    return
                stats["polls"] += 1

    threads = [threading.Thread(target=ingest) for _ in range(WRITERS)]
    threads.append(threading.Thread(target=poll))
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    out.put(stats)


async def stored_trajectories(http: httpx.AsyncClient) -> int:
    """Trajectories stored in ``ingest`` so far."""
    n: int = (await http.get("/domains/ingest")).json()["trajectories"]
    return n


async def run(live: Live, explorers: list[Explorer]) -> dict[str, Any]:
    ws_base = live.url.replace("http://", "ws://")
    ctx = multiprocessing.get_context("spawn")
    started, done, out = ctx.Event(), ctx.Event(), ctx.Queue()
    stats: dict[str, Any] = {}
    async with httpx.AsyncClient(base_url=live.url, timeout=30) as http:
        created = []
        for e in explorers:
            body = {"kappa": e.kappa, "window": e.window, "start": list(e.start)}
            r = await http.post("/domains/default/sessions", json=body)
            assert r.status_code == 201, r.text
            created.append(r.json())

        async def explore(e: Explorer, c: dict[str, Any], ready: asyncio.Barrier) -> list[Any]:
            url = f"{ws_base}/sessions/{c['session_id']}/stream?token={c['token']}"
            async with websockets.connect(url, max_size=None) as ws:
                await ready.wait()  # all 100 connected before anyone streams

                async def send_all() -> None:
                    for frame in e.frames:
                        await ws.send(frame)

                sender = asyncio.create_task(send_all())
                got = [json.loads(await ws.recv()) for _ in e.frames]
                await sender
                return got

        ready = asyncio.Barrier(EXPLORERS)
        side = ctx.Process(target=background, args=(live.url, live.admin_key, started, done, out))
        side.start()
        # the explorers start once the writers have stored a first batch
        assert await asyncio.to_thread(started.wait, 60)
        before = await stored_trajectories(http)
        t0 = time.monotonic()
        try:
            pairs = zip(explorers, created, strict=True)
            streams = asyncio.gather(*(explore(e, c, ready) for e, c in pairs))
            answers = await asyncio.wait_for(streams, TIME_LIMIT)
        finally:
            stats["seconds"] = time.monotonic() - t0
            stats["during"] = await stored_trajectories(http) - before
            done.set()
            stats.update(await asyncio.to_thread(out.get, True, 60))
            side.join(30)
        steps = []
        for c in created:
            auth = {"Authorization": f"Bearer {c['token']}"}
            steps.append((await http.get(f"/sessions/{c['session_id']}", headers=auth)).json())
    stats.update(created=created, answers=answers, sessions=steps)
    return stats


def tables_n(rows: list[str]) -> int:
    return GridDomain.from_strings(rows).n_states


def test_100_websocket_explorers_with_concurrent_ingestion(live: Live) -> None:
    with httpx.Client(base_url=live.url, timeout=30) as http:
        assert (
            http.put("/domains/ingest", json={"map": TINY}, headers=live.admin).status_code == 201
        )
        grid = GridDomain.from_strings(http.get("/domains/default").json()["map"])
        theta_before = http.get("/domains/default/prior").json()["theta"]
    table = np.array([theta_before[r][c] for r, c in grid.cells.tolist()])
    tables = AdviceTables.paper(table)
    explorers = [plan(i, grid, tables) for i in range(EXPLORERS)]

    stats = run_async(run(live, explorers))

    assert stats["errors"] == []
    assert stats["during"] > 0  # batches stored while the explorers ran
    for e, c, got, final in zip(
        explorers, stats["created"], stats["answers"], stats["sessions"], strict=True
    ):
        assert c["decision"] == e.start_decision
        assert len(got) == len(e.expected)
        for k, (answer, want) in enumerate(zip(got, e.expected, strict=True)):
            assert answer == want, (c["session_id"], "frame", k)
        assert final["steps"] == e.n_events
    with httpx.Client(base_url=live.url, timeout=30) as http:
        assert http.get("/domains/default/prior").json()["theta"] == theta_before
        assert http.get("/domains/ingest").json()["trajectories"] == stats["trajectories"]
    store = Store(f"sqlite:///{live.data_dir / 'advisor.db'}")
    try:
        assert len(store.trajectories("ingest")) == stats["trajectories"]
        counts, recount = store.counts("ingest"), store.recount("ingest", tables_n(TINY))
        assert sorted(counts) == sorted(recount)
        for key in counts:
            np.testing.assert_array_equal(counts[key].counts, recount[key].counts)
    finally:
        store.close()
    assert server_errors(live) == []
    events = sum(e.n_events for e in explorers)
    frames = EXPLORERS * FRAMES
    print(
        f"\nload: {EXPLORERS} websocket explorers, {frames} frames, {events} events, "
        f"in {stats['seconds']:.1f} s; meanwhile {stats['during']} trajectories stored "
        f"(in all {stats['batches']} batches, {stats['trajectories']} trajectories) and "
        f"{stats['polls']} /overview polls"
    )
