"""Two workers (``serve --workers 2``) sharing Redis, as a campus would run them: one worker is
killed (SIGKILL) in the middle of streams, then every worker is restarted. Explorers go on
through the shipped client, which numbers its events with their steps and sends a call again
when it got no answer (REST), or opens its stream again and sends the unanswered frame
(websocket). Nothing acknowledged is lost, nothing is applied twice, and every decision is the
core advisor's for the same moves, whichever worker made it.

Without Redis, the embedded default: a graceful restart (SIGTERM) keeps the live sessions."""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from advisor_client import AdvisorClient, AdvisorError
from advisor_client.api import Session

from app.advice.advisor import Advisor
from app.advice.guide import GuideMap
from app.advice.models import AdviceTables
from app.advice.params import StrategyParams
from app.advice.priors import ActionPrior, GoalPriors
from app.domain.grid import ACTIONS, GridDomain
from app.service.data.domains import service_leads
from app.service.data.store import Store
from app.service.wire.encode import decision_dict
from app.strategies import make_advisor
from tests.client.conftest import free_port
from tests.reliability.conftest import Live, start, stop
from tests.service.conftest import REDIS_URL, drop_redis_keys, redis_prefix, redis_problem
from tests.service.test_strategies import led

PROBLEM = redis_problem()
needs_redis = pytest.mark.skipif(PROBLEM is not None, reason=f"Redis at {REDIS_URL}: {PROBLEM}")

EXPLORERS = [  # (strategy, transport): every strategy family, both transports
    ("paper", "rest"), ("goal_aware", "rest"), ("guide", "rest"), ("random", "rest"),
    ("paper", "websocket"), ("guide", "websocket"),
]  # fmt: skip
STEPS = 240  # events per explorer before the restart, 60 after


def workers_of(live: Live) -> list[int]:
    """The pids of the server's worker processes (uvicorn's spawned children)."""
    out = []
    for child in Path(f"/proc/{live.pid()}/task/{live.pid()}/children").read_text().split():
        cmdline = Path(f"/proc/{child}/cmdline").read_bytes()
        if b"spawn_main" in cmdline:
            out.append(int(child))
    return out


def holder(pids: list[int], client_port: int) -> int | None:
    """Which of ``pids`` holds the server's end of the connection from ``client_port``
    (/proc/net/tcp gives its socket's inode, /proc/<pid>/fd who has it open)."""
    inodes = set()
    for line in Path("/proc/net/tcp").read_text().splitlines()[1:]:
        fields = line.split()
        if int(fields[2].split(":")[1], 16) == client_port:
            inodes.add(fields[9])
    for pid in pids:
        for fd in Path(f"/proc/{pid}/fd").iterdir():
            try:
                target = os.readlink(fd)
            except OSError:
                continue
            if target.startswith("socket:[") and target[8:-1] in inodes:
                return pid
    return None


def references(db: Path, grid: GridDomain) -> tuple[AdviceTables, GoalPriors]:
    """The prior and the goal priors, rebuilt by the core from what the database holds."""
    store = Store(f"sqlite:///{db}")
    stored = store.trajectories("default")
    store.close()
    prior = ActionPrior(alpha0=1.0).fit([t.pairs for t in stored], grid.n_states)
    index = [grid.goals.index(t.goal) if t.goal in grid.goals else None for t in stored]
    goals = GoalPriors(grid.n_states, grid.goals, 1.0).add([t.pairs for t in stored], index)
    return AdviceTables.paper(prior.theta()), goals


def core_for(strategy: str, tables: AdviceTables, goals: GoalPriors, grid: GridDomain) -> Advisor:
    params = StrategyParams(rate=0.3, seed=7) if strategy == "random" else StrategyParams()
    return make_advisor(strategy, tables, 0.4, 50, params, goals,
                        GuideMap.of(grid, goals, leads=service_leads(grid)))  # fmt: skip


class Explorer:
    """One explorer walking at random and sending each move (REST, one call per event) or
    each 12 moves (its websocket), keeping every decision the service answered."""

    def __init__(self, url: str, grid: GridDomain, strategy: str, transport: str, seed: int):
        self.client = AdvisorClient(url, retries=40, backoff=0.05, timeout=10)
        self.grid, self.strategy, self.transport = grid, strategy, transport
        self.rng = np.random.default_rng(seed)
        params = {"rate": 0.3, "seed": 7} if strategy == "random" else None
        self.session: Session = self.client.create_session(
            kappa=0.4, window=50, strategy=strategy, params=params
        )
        self.position = grid.start
        self.moves: list[tuple[int, int, int]] = []
        self.answers: list[dict[str, Any]] = []
        self.todo = STEPS
        self.failure: BaseException | None = None
        self.reconnects = 0
        self.stream: Any = None  # its websocket now (the websocket explorers)

    def walk(self, n: int) -> list[dict[str, Any]]:
        events = []
        for a in self.rng.integers(0, 4, n).tolist():
            s2 = int(self.grid.next_state[self.position, a])
            self.moves.append((self.position, a, s2))
            events.append({"state": list(self.grid.cell(self.position)), "action": ACTIONS[a]})
            self.position = s2
        return events

    def run(self) -> None:
        try:
            if self.transport == "rest":
                for _ in range(self.todo):
                    self.answers.append(self.client.events(self.session, self.walk(1)[0]))
                return
            left = self.todo
            stream = self.stream = self.client.stream(self.session)
            while left:
                frame = self.walk(min(12, left))
                while True:
                    try:  # the stream's worker gone, the client opens a new stream itself
                        self.answers += stream.send(frame)
                        break
                    except AdvisorError:  # and if its retries ran out: a new stream, again
                        self.reconnects += 1 + stream.reconnects
                        time.sleep(0.05)
                        stream = self.stream = self.client.stream(self.session)
                left -= len(frame)
                time.sleep(0.02)  # a walker's pace: the stream stays open a while
            self.reconnects += stream.reconnects
            stream.close()
        except BaseException as exc:  # reported by the test
            self.failure = exc


def run_all(explorers: list[Explorer], during: Any = None) -> None:
    """Every explorer in a thread of its own (``during``: what the test does meanwhile)."""
    threads = [threading.Thread(target=e.run, daemon=True) for e in explorers]
    for t in threads:
        t.start()
    if during is not None:
        during()
    for e, t in zip(explorers, threads, strict=True):
        t.join(300)
        assert not t.is_alive(), "an explorer never finished"
        assert e.failure is None, repr(e.failure)


@needs_redis
def test_a_killed_worker_and_a_full_restart_lose_nothing(tmp_path: Path) -> None:
    prefix = redis_prefix()
    port = free_port()
    env: dict[str, Any] = {
        "ADVISOR_WORKERS": "2", "ADVISOR_REDIS_URL": REDIS_URL, "ADVISOR_REDIS_PREFIX": prefix,
    }  # fmt: skip
    data = tmp_path / "data"
    live = start(data, port=port, **env)
    try:
        pids = workers_of(live)
        assert len(pids) == 2, pids
        grid = GridDomain.from_strings(httpx.get(f"{live.url}/domains/default").json()["map"])
        explorers = [Explorer(live.url, grid, s, t, seed) for seed, (s, t) in enumerate(EXPLORERS)]

        watched = next(e for e in explorers if e.transport == "websocket")
        killed: list[int] = []

        def kill_one_worker() -> None:  # the one holding a websocket, mid-stream
            while len(watched.answers) < STEPS // 3:
                time.sleep(0.001)
            pid = holder(pids, watched.stream.connection.socket.getsockname()[1])
            assert pid is not None, "no worker holds the watched websocket"
            os.kill(pid, signal.SIGKILL)
            killed.append(pid)

        run_all(explorers, kill_one_worker)
        deadline = time.monotonic() + 60
        while len(workers_of(live)) < 2:  # uvicorn's supervisor starts another
            assert time.monotonic() < deadline, "no worker took the killed one's place"
            time.sleep(0.1)
        assert killed[0] not in workers_of(live)
        assert watched.reconnects >= 1  # its stream died with the worker, and went on
        print(f"\nworker {killed[0]} killed; websocket reconnects: "
              f"{[e.reconnects for e in explorers if e.transport == 'websocket']}")  # fmt: skip
        stop(live)  # every worker, gracefully
        live = start(data, port=port, **env)  # all of them again: the sessions are in Redis
        for e in explorers:
            e.client = AdvisorClient(live.url, retries=40, backoff=0.05, timeout=10)
            e.todo = 60
        run_all(explorers)
        tables, goals = references(data / "advisor.db", grid)
        for e in explorers:
            core = core_for(e.strategy, tables, goals, grid)
            core.start(grid.start)
            want = [expected(core, m, grid, e.transport) for m in e.moves]
            assert len(e.answers) == len(e.moves) == STEPS + 60
            assert [_wire(a) for a in e.answers] == [_wire(w) for w in want], e.strategy
            info = e.client.session(e.session)  # applied once each: steps, costs, as the core
            assert info["steps"] == core.steps and info["advice_count"] == core.advice_count
            assert info["total_cost"] == core.total_cost and info["benefit"] == core.benefit
    finally:
        stop(live)
        drop_redis_keys(prefix)
    log = live.log.read_text(errors="replace")
    assert "Exception in ASGI application" not in log


def expected(core: Advisor, move: tuple[int, int, int], grid: GridDomain, transport: str) -> Any:
    """The core's decision as the explorer's transport answers it: a one-event answer (REST)
    names the destination guide's advice leads to, a websocket frame's batch does not."""
    d = decision_dict(core.observe(*move), grid)
    return led(d, core, grid) if transport == "rest" else d


def _wire(d: Any) -> Any:
    """A decision as JSON reads it back (tuples as lists)."""
    import json

    return json.loads(json.dumps(d))


def test_without_redis_a_graceful_restart_keeps_live_sessions(tmp_path: Path) -> None:
    port = free_port()
    data = tmp_path / "data"
    live = start(data, port=port)
    try:
        grid = GridDomain.from_strings(httpx.get(f"{live.url}/domains/default").json()["map"])
        explorers = [
            Explorer(live.url, grid, s, "rest", i) for i, s in enumerate(["paper", "guide"])
        ]
        for e in explorers:
            e.todo = 80
        run_all(explorers)
        stop(live)  # SIGTERM: a graceful shutdown writes the sessions to the database
        assert "Kept 2 live sessions for the next start" in live.log.read_text()
        live = start(data, port=port)
        for e in explorers:
            e.client = AdvisorClient(live.url, retries=5, backoff=0.05)
            e.todo = 40
        run_all(explorers)
        tables, goals = references(data / "advisor.db", grid)
        for e in explorers:
            core = core_for(e.strategy, tables, goals, grid)
            core.start(grid.start)
            want = [expected(core, m, grid, e.transport) for m in e.moves]
            assert [_wire(a) for a in e.answers] == [_wire(w) for w in want], e.strategy
    finally:
        stop(live)
    assert "Restored 2 live sessions" in live.log.read_text()
