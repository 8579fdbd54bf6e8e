"""A soak of create / stream / abandon cycles against the real server, measuring its resident
memory (VmRSS of the server process, /proc/<pid>/status). Used by
``tests/reliability/test_bounds.py``; from the command line it prints its figures, e.g. with
eviction effectively off, to see what sessions kept alive would cost::

    .venv/bin/python -m tests.reliability.soak --idle 3600 --max-sessions 100000
"""

from __future__ import annotations

import argparse
import asyncio
import json
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import httpx
import websockets

from tests.client.test_client import run_async
from tests.reliability.conftest import Live, server_errors, start, stop

CYCLES, WARM_UP, PER_CYCLE = 12, 4, 25
WINDOW, EVENTS = 1000, 1000  # each session fills its window: 16 kB of it in use
E = {"state": [28, 0], "action": "E"}
W = {"state": [28, 1], "action": "W"}


@dataclass
class Soak:
    baseline_mib: float  # after the warm-up cycles, once their sessions were evicted
    after_mib: float  # after the measured cycles, once their sessions were evicted
    drained: bool  # the registry emptied after the measured cycles
    sessions: int  # created in all
    errors: list[str]  # tracebacks in the server's log

    @property
    def growth_mib(self) -> float:
        return self.after_mib - self.baseline_mib


def eventually(check: Callable[[], bool], limit: float = 15.0) -> bool:
    """Poll ``check`` until it holds or ``limit`` seconds pass."""
    deadline = time.monotonic() + limit
    while time.monotonic() < deadline:
        if check():
            return True
        time.sleep(0.02)
    return check()


def rss_mib(pid: int) -> float:
    with open(f"/proc/{pid}/status", encoding="ascii") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    raise AssertionError("no VmRSS")


async def cycle(http: httpx.AsyncClient, ws_base: str, n: int) -> None:
    """n explorers at once: each opens a session, streams EVENTS events in two frames over its
    websocket, then closes the connection without ending the session (abandons it)."""

    async def explorer() -> None:
        r = await http.post("/domains/default/sessions", json={"window": WINDOW})
        assert r.status_code == 201, r.text
        c = r.json()
        url = f"{ws_base}/sessions/{c['session_id']}/stream?token={c['token']}"
        async with websockets.connect(url) as ws:
            for _ in range(2):
                await ws.send(json.dumps([E, W] * (EVENTS // 4)))
                answer = json.loads(await ws.recv())
                assert len(answer) == EVENTS // 2

    await asyncio.gather(*(explorer() for _ in range(n)))


def soak(data_dir: Path, idle: float = 2.0, max_sessions: int = 8 * PER_CYCLE) -> Soak:
    """WARM_UP cycles, the baseline, CYCLES cycles, the final figure (each RSS read once the
    abandoned sessions are gone, or after a bounded wait if they never go)."""
    live: Live = start(
        data_dir,
        ADVISOR_SESSION_IDLE_SECONDS=str(idle),
        ADVISOR_SWEEP_SECONDS="0.1",
        ADVISOR_MAX_SESSIONS=str(max_sessions),
    )
    ws_base = live.url.replace("http://", "ws://")

    async def cycles(n: int) -> None:
        async with httpx.AsyncClient(base_url=live.url, timeout=30) as http:
            for _ in range(n):
                # paced: a cycle lasts idle / 4 at least, so that at most about 5 cycles'
                # sessions are live at once however fast the service is (unpaced, a faster
                # service fitted more than max_sessions into one idle period: 503)
                started = time.monotonic()
                await cycle(http, ws_base, PER_CYCLE)
                await asyncio.sleep(max(0.0, idle / 4 - (time.monotonic() - started)))

    def drained() -> bool:
        sessions: int = httpx.get(f"{live.url}/health").json()["sessions"]
        return sessions == 0

    wait = min(idle + 2.0, 15.0)
    try:
        run_async(cycles(WARM_UP))  # allocator and caches warm up first
        eventually(drained, wait)
        baseline = rss_mib(live.pid())
        run_async(cycles(CYCLES))
        empty = eventually(drained, wait)
        after = rss_mib(live.pid())
    finally:
        stop(live)
    return Soak(baseline, after, empty, (WARM_UP + CYCLES) * PER_CYCLE, server_errors(live))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--idle", type=float, default=2.0, help="session idle seconds")
    parser.add_argument("--max-sessions", type=int, default=8 * PER_CYCLE)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        s = soak(Path(tmp) / "data", args.idle, args.max_sessions)
    print(
        f"soak: {s.sessions} sessions x {EVENTS} events (window {WINDOW}); RSS "
        f"{s.baseline_mib:.1f} MiB after {WARM_UP} warm-up cycles, {s.after_mib:.1f} MiB after "
        f"{CYCLES} more: {s.growth_mib:+.1f} MiB; registry drained: {s.drained}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
