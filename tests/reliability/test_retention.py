"""Where explorers were is kept ``ADVISOR_PATH_RETENTION_SECONDS`` at most (the issue: live
positions and paths are personal data; a retention setting bounds how long explorer paths are
kept). At 1 s: one explorer walks, then walks on after the retention has passed; another walks
and stops. Every answer that shows where they were (``GET /overview`` with the operator key,
``GET /viewer/snapshot``, ``GET /sessions/{id}`` with the admin key) holds none of the cells
they left more than a second before, nor advice given there: in one process and with sessions
in Redis, with no sweep in between (each read drops them; a session written to Redis is
written without them, which the test reads there)."""

from __future__ import annotations

import time
from collections.abc import Iterator
from itertools import pairwise
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.domain.grid import ACTIONS, GridDomain
from app.domain.paths import path_within
from app.service.live import codec
from app.service.main import create_app
from tests.service.conftest import (
    REDIS_URL,
    drop_redis_keys,
    make_settings,
    redis_prefix,
    redis_problem,
)

RETENTION = 1.0
STEPS = 12  # cells of each leg of a walk
REDIS_PROBLEM = redis_problem()

Cell = tuple[int, int]


@pytest.fixture(params=["one process", "redis"])
def http(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[TestClient]:
    extra: dict[str, Any] = {}
    prefix = ""
    if request.param == "redis":
        if REDIS_PROBLEM is not None:
            pytest.skip(f"Redis at {REDIS_URL}: {REDIS_PROBLEM}")
        prefix = redis_prefix()
        extra = {"redis_url": REDIS_URL, "redis_prefix": prefix}
    # no sweep meanwhile: what is checked is that reads and writes drop old cells themselves
    settings = make_settings(
        tmp_path / "data", path_retention_seconds=RETENTION, sweep_seconds=3600, **extra
    )
    try:
        with TestClient(create_app(settings)) as client:
            yield client
    finally:
        if prefix:
            drop_redis_keys(prefix)


def corridor(grid: GridDomain) -> list[int]:
    """A walk of distinct cells from the start: a shortest path to the farthest cell."""
    distance = grid.distances_to(grid.start)
    far = int(np.argmax(distance))
    path = path_within(grid, grid.start, far, int(distance[far]))
    assert path is not None
    return path


def events(grid: GridDomain, cells: list[int]) -> list[dict[str, Any]]:
    """The moves from each cell of ``cells`` to the next."""
    out = []
    for s, t in pairwise(cells):
        a = next(a for a in range(4) if int(grid.next_state[s, a]) == t)
        out.append({"state": list(grid.cell(s)), "action": ACTIONS[a]})
    return out


def shown(
    http: TestClient, sid: str, token: str, keys: dict[str, dict[str, str]]
) -> dict[str, Any]:
    """Where each answer says the session is and was: cells of its path, its position, and
    the steps and cells of its advice."""
    overview = http.get("/overview", headers=keys["operator"]).json()
    o = next(s for s in overview["sessions"] if s["session_id"] == sid)
    snap = http.get("/viewer/snapshot", headers=keys["operator"]).json()
    v = next(s for s in snap["sessions"] if s["session_id"] == sid)
    admin = http.get(f"/sessions/{sid}", headers=keys["admin"]).json()
    own = http.get(f"/sessions/{sid}", headers={"Authorization": f"Bearer {token}"}).json()
    last = o["last_advice"]
    return {
        "paths": [tuple(c) for c in o["path"]] + [tuple(c) for c in v["path"]],
        "positions": {
            tuple(o["position"]),
            tuple(v["position"]),
            tuple(admin["position"]),
            tuple(own["position"]),
        },
        "advice_steps": [a[0] for a in v["advice"]] + ([last["step"]] if last else []),
        "advice_cells": [tuple(a[1]) for a in v["advice"]]
        + ([tuple(last["state"])] if last else []),
    }


def test_cells_older_than_the_retention_are_in_no_answer(http: TestClient) -> None:
    state = http.app.state.service  # type: ignore[attr-defined]
    keys = {"admin": {"X-API-Key": state.admin_key}, "operator": {"X-API-Key": state.operator_key}}
    grid = GridDomain.from_strings(http.get("/domains/default").json()["map"])
    walk = corridor(grid)
    assert len(walk) > 2 * STEPS + 1
    first, second = walk[: STEPS + 1], walk[STEPS : 2 * STEPS + 1]
    old: set[Cell] = {grid.cell(s) for s in first[:-1]}  # all but where the second leg starts

    def open_walking(cells: list[int]) -> tuple[str, str]:
        r = http.post("/domains/default/sessions", json={"kappa": 0.0})  # advice at every step
        assert r.status_code == 201, r.text
        sid, token = r.json()["session_id"], r.json()["token"]
        auth = {"Authorization": f"Bearer {token}"}
        r = http.post(f"/sessions/{sid}/events", json=events(grid, cells), headers=auth)
        assert r.status_code == 200 and all(d["advise"] for d in r.json()), r.text
        return sid, token

    walker, walker_token = open_walking(first)
    stopped, stopped_token = open_walking(first)
    left = time.monotonic()
    # while within the retention, the path is shown (read at once: well within a second, as
    # a rule; a slower read may find it forgotten already, which the rest does not need)
    seen = shown(http, walker, walker_token, keys)
    if time.monotonic() - left < RETENTION / 2:
        assert old <= set(seen["paths"]) and seen["advice_steps"]

    deadline = left + RETENTION + 0.2
    while time.monotonic() < deadline:  # the retention passes (the clock is the condition)
        time.sleep(0.05)
    auth = {"Authorization": f"Bearer {walker_token}"}
    r = http.post(f"/sessions/{walker}/events", json=events(grid, second), headers=auth)
    assert r.status_code == 200, r.text

    for sid, token, here in (
        (walker, walker_token, second[-1]),
        (stopped, stopped_token, first[-1]),
    ):
        seen = shown(http, sid, token, keys)
        assert seen["positions"] == {grid.cell(here)}
        assert not old & set(seen["paths"]), (sid, seen["paths"])
        assert not old & set(seen["advice_cells"]), (sid, seen["advice_cells"])
        assert all(step > STEPS for step in seen["advice_steps"]), seen["advice_steps"]
    if state.sessions.shared:  # what Redis holds of the session that walked on: no old cell
        session = codec.load(_blob(state, walker), state.catalog.get("default"), 0)
        kept = {grid.cell(int(s)) for s in session.path.array()} if session.path else set()
        assert not old & kept, kept
        log = session.advice_log
        assert log is None or all(step > STEPS for step, _, _ in log.items())


def _blob(state: Any, sid: str) -> bytes:
    import redis

    store = redis.Redis.from_url(REDIS_URL)
    try:
        blob = store.hget(f"{state.settings.redis_prefix}:s:{sid}", "blob")
    finally:
        store.close()
    assert isinstance(blob, bytes)
    return codec.unpacked(blob)  # as Redis keeps it: packed
