"""Memory an anonymous client can make the service take (issue: 150 goal_aware sessions at
the largest window cost 323 MiB; a 999-goal map cost 116-155 MiB a session; a 200,000-goal
map answered 500). Over the real server, reading its resident memory (VmRSS)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import httpx
import numpy as np
from websockets.sync.client import connect

from app.domain.grid import ACTIONS, GridDomain
from tests.reliability.conftest import Live, server_errors, start, stop
from tests.reliability.soak import rss_mib

SESSIONS = 150
WINDOW = 10_000  # the largest window the service allows by default
BOUND_MIB = 150.0


def walk(grid: GridDomain, n: int, seed: int) -> list[dict[str, Any]]:
    """``n`` events of a random walk from the start (valid moves, some into walls)."""
    rng = np.random.default_rng(seed)
    s, out = grid.start, []
    for a in rng.integers(0, 4, n).tolist():
        out.append({"state": list(grid.cell(s)), "action": ACTIONS[a]})
        s = int(grid.next_state[s, a])
    return out


def stream(live: Live, created: dict[str, Any], frames: list[str]) -> None:
    """Send ``frames`` over the session's websocket (binary answers), each answered."""
    url = live.url.replace("http", "ws") + f"/sessions/{created['session_id']}/stream"
    with connect(f"{url}?format=binary", additional_headers=_bearer(created)) as ws:
        for frame in frames:
            ws.send(frame)
            assert isinstance(ws.recv(), bytes)


def _bearer(created: dict[str, Any]) -> dict[str, str]:
    return {"Authorization": f"Bearer {created['token']}"}


def test_150_goal_aware_sessions_at_the_largest_window_stay_within_150_mib(
    tmp_path: Path,
) -> None:
    live = start(tmp_path / "data")
    try:
        with httpx.Client(base_url=live.url, timeout=60) as http:
            grid = GridDomain.from_strings(http.get("/domains/default").json()["map"])
            events = walk(grid, WINDOW, 0)
            frames = [json.dumps(events[i : i + 5000]) for i in range(0, WINDOW, 5000)]
            body = {"strategy": "goal_aware", "window": WINDOW, "params": {"beta": 0.5}}

            def session() -> dict[str, Any]:
                r = http.post("/domains/default/sessions", json=body)
                assert r.status_code == 201, r.text
                created: dict[str, Any] = r.json()
                return created

            warm = session()  # the domain's goal tables and the compiled loops, once
            stream(live, warm, frames)
            http.delete(f"/sessions/{warm['session_id']}", headers=_bearer(warm))
            before = rss_mib(live.pid())
            made = [session() for _ in range(SESSIONS)]
            for created in made:  # every window full
                stream(live, created, frames)
            filled = rss_mib(live.pid())
            # new expert data: each session keeps its pairs' values (models and goals) exactly
            more = {
                "trajectories": [{"steps": events[:50], "goal": list(grid.cell(grid.goals[0]))}]
            }
            r = http.post("/domains/default/trajectories", json=more, headers=live.admin)
            assert r.status_code == 201, r.text
            for created in made:
                stream(live, created, [json.dumps(events[:1])])
            after = rss_mib(live.pid())
            for created in made:
                http.delete(f"/sessions/{created['session_id']}", headers=_bearer(created))
            ended = rss_mib(live.pid())
    finally:
        stop(live)
    print(
        f"\n{SESSIONS} goal_aware sessions, window {WINDOW}: RSS {before:.1f} MiB before, "
        f"{filled:.1f} with full windows, {after:.1f} after a prior update, {ended:.1f} ended"
    )
    assert after - before < BOUND_MIB
    assert server_errors(live) == []


def many_goals(cols: int) -> list[str]:
    """One row: the start, then ``cols - 1`` goals."""
    return ["#" * (cols + 2), "#S" + "G" * (cols - 1) + "#", "#" * (cols + 2)]


def test_goal_tables_are_per_domain_and_sessions_pay_for_their_window(tmp_path: Path) -> None:
    """999 goals x 1,000 cells: the domain's tables are built once (by the first goal_aware
    session); each further session costs what its window and goals reserve, not goals x
    cells; goals x window over the limit, and goals x cells over it, are refused saying so."""
    live = start(tmp_path / "data")
    try:
        with httpx.Client(base_url=live.url, timeout=60, headers=live.admin) as http:
            r = http.put("/domains/line", json={"map": many_goals(1000)})
            assert r.status_code == 201, r.text
            body = {"strategy": "goal_aware", "window": 1000, "params": {"beta": 0.5}}
            first = http.post("/domains/line/sessions", json=body)
            assert first.status_code == 201, first.text
            events = [{"state": [1, 1 + i % 2], "action": "E" if i % 2 == 0 else "W"}
                      for i in range(1000)]  # fmt: skip
            stream(live, first.json(), [json.dumps(events)])
            before = rss_mib(live.pid())
            for _ in range(20):
                r = http.post("/domains/line/sessions", json=body)
                assert r.status_code == 201, r.text
                stream(live, r.json(), [json.dumps(events)])
            grown = rss_mib(live.pid()) - before
            over = http.post("/domains/line/sessions", json=body | {"window": 2000})
            block = ["S" + "G" * 499] + ["G" * 500] * 399  # 199,999 goals
            huge = http.put("/domains/huge", json={"map": block})
    finally:
        stop(live)
    print(f"\n20 goal_aware sessions on a 999-goal map: RSS +{grown:.1f} MiB")
    assert grown < 20 * 1.0  # under 1 MiB a session (it was 116-155 MiB)
    assert over.status_code == 422, over.text
    assert "999 goals x window 2000" in over.json()["detail"]
    assert "ADVISOR_MAX_GOAL_WINDOW" in over.json()["detail"]
    assert huge.status_code == 422, huge.text
    assert "199999 goals x 200000 free cells" in huge.json()["detail"]
    assert server_errors(live) == []
