"""Bounded resources: idle sessions are evicted, the session limit answers 503 saying why, and
memory stays flat over a soak of create / stream / abandon cycles.

The first two run the app in-process (TestClient, whose portal runs the lifespan's sweeper);
the soak runs the real server and reads its resident memory (VmRSS in /proc/<pid>/status).
Waits are polls with generous bounds; nothing asserts how fast anything is.
"""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import httpx
import pytest
import websockets
from fastapi.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

from app.service.main import create_app
from tests.client.test_client import run_async
from tests.reliability.conftest import Live, server_errors, start, stop
from tests.service.conftest import make_settings, open_session

E = {"state": [28, 0], "action": "E"}
W = {"state": [28, 1], "action": "W"}


def eventually(check: Callable[[], bool], limit: float = 15.0) -> bool:
    """Poll ``check`` until it holds or ``limit`` seconds pass."""
    deadline = time.monotonic() + limit
    while time.monotonic() < deadline:
        if check():
            return True
        time.sleep(0.02)
    return check()


@pytest.fixture
def short_lived(tmp_path: Path) -> Iterator[TestClient]:
    """Sessions expire after 0.5 s idle; the sweeper runs every 0.05 s; at most 3 live."""
    settings = make_settings(
        tmp_path / "data", session_idle_seconds=0.5, sweep_seconds=0.05, max_sessions=3
    )
    with TestClient(create_app(settings)) as client:
        yield client


def live_sessions(client: TestClient) -> int:
    n: int = client.get("/health").json()["sessions"]
    return n


def test_idle_sessions_are_evicted_and_active_ones_kept(short_lived: TestClient) -> None:
    client = short_lived
    idle_id, idle_auth, _ = open_session(client)
    kept_id, kept_auth, _ = open_session(client)
    ws_id, _, created = open_session(client)
    with client.websocket_connect(f"/sessions/{ws_id}/stream?token={created['token']}") as ws:
        ws.send_text(json.dumps(E))
        assert json.loads(ws.receive_text())["step"] == 1

        def idle_gone() -> bool:  # the kept session is used meanwhile; /overview reads
            # sessions without touching them (reading one with its token would keep it alive)
            assert client.post(f"/sessions/{kept_id}/events", json=E, headers=kept_auth)
            listed = {s["session_id"] for s in client.get("/overview").json()["sessions"]}
            return not {idle_id, ws_id} & listed

        assert eventually(idle_gone)
        r = client.get(f"/sessions/{idle_id}", headers=idle_auth)
        assert r.status_code == 404 and "expired" in r.json()["detail"]
        assert client.get(f"/sessions/{kept_id}", headers=kept_auth).status_code == 200
        # the websocket's session idled too: its next frame closes the connection with 4404
        ws.send_text(json.dumps(W))
        with pytest.raises(WebSocketDisconnect) as closed:
            ws.receive_text()
        assert closed.value.code == 4404
    assert eventually(lambda: live_sessions(client) == 0)


def test_beyond_max_sessions_new_ones_get_503_saying_why(short_lived: TestClient) -> None:
    client = short_lived
    opened = [open_session(client) for _ in range(3)]
    r = client.post("/domains/default/sessions", json={})
    assert r.status_code == 503
    detail = r.json()["detail"]
    assert "maximum of 3 live sessions" in detail and "DELETE /sessions/{id}" in detail
    # the live ones still work while the service is full
    sid, auth, _ = opened[0]
    assert client.post(f"/sessions/{sid}/events", json=E, headers=auth).status_code == 200
    # ending one frees a place
    assert client.delete(f"/sessions/{opened[1][0]}", headers=opened[1][1]).status_code == 200
    assert client.post("/domains/default/sessions", json={}).status_code == 201
    assert client.post("/domains/default/sessions", json={}).status_code == 503
    # and so does idling: once they expire, new sessions are admitted again
    assert eventually(lambda: client.post("/domains/default/sessions", json={}).status_code == 201)


CYCLES, WARM_UP, PER_CYCLE = 16, 5, 25
WINDOW, EVENTS = 1000, 1000  # each session fills its window: 16 kB of it in use
#: Allowed growth of the server's RSS over the measured cycles. Measured (docs/RELIABILITY.md):
#: -1 to +0.6 MiB; with eviction switched off (400 sessions kept) the same cycles add 5.4 MiB.
GROWTH_MIB = 3.0


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


def test_memory_stays_bounded_over_create_stream_abandon_cycles(tmp_path: Path) -> None:
    live: Live = start(
        tmp_path / "data",
        ADVISOR_SESSION_IDLE_SECONDS="1",
        ADVISOR_SWEEP_SECONDS="0.1",
        # fewer than the soak abandons: unless they are evicted, creation fails (503)
        ADVISOR_MAX_SESSIONS=str(8 * PER_CYCLE),
    )
    ws_base = live.url.replace("http://", "ws://")

    async def soak(cycles: int) -> None:
        async with httpx.AsyncClient(base_url=live.url, timeout=30) as http:
            for _ in range(cycles):
                await cycle(http, ws_base, PER_CYCLE)

    def drained() -> bool:
        return httpx.get(f"{live.url}/health").json()["sessions"] == 0

    try:
        run_async(soak(WARM_UP))  # allocator and caches warm up first
        assert eventually(drained)
        baseline = rss_mib(live.pid())
        run_async(soak(CYCLES))
        assert eventually(drained)  # every abandoned session was evicted
        after = rss_mib(live.pid())
    finally:
        stop(live)
    sessions = (WARM_UP + CYCLES) * PER_CYCLE
    print(
        f"\nsoak: {sessions} sessions ({sessions * EVENTS} events), RSS {baseline:.1f} MiB "
        f"after warm-up, {after:.1f} MiB after {CYCLES} more cycles"
    )
    assert after - baseline < GROWTH_MIB
    assert server_errors(live) == []
