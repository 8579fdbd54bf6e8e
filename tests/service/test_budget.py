"""A session's advice budget (in all, per minute) and a visitor's mute: decisions past the
budget, or while muted, do not advise; the advisor goes on watching; the answers show what is
left. The per-minute bucket runs on the registry's clock, given here."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.domain.grid import ACTIONS
from app.service.state import ServiceState
from tests.service.conftest import open_session


def walk(service: ServiceState, n: int, seed: int) -> list[dict[str, Any]]:
    """``n`` random events from the default domain's start."""
    grid = service.catalog.get("default").domain
    rng = np.random.default_rng(seed)
    s, out = grid.start, []
    for a in rng.integers(0, 4, n).tolist():
        out.append({"state": list(grid.cell(s)), "action": ACTIONS[a]})
        s = int(grid.next_state[s, a])
    return out


def test_a_total_budget_stops_advice_and_the_session_says_what_is_left(
    client: TestClient, service: ServiceState
) -> None:
    sid, auth, created = open_session(client, kappa=0.0, budget={"total": 3})  # kappa 0: always
    assert created["decision"]["advise"]
    got = client.post(f"/sessions/{sid}/events", json=walk(service, 10, 1), headers=auth).json()
    assert [d["advise"] for d in got] == [True, True] + [False] * 8
    assert got[-1]["cost"]["advice_count"] == 3 and got[-1]["kl"] >= 0.0
    seen = client.get(f"/sessions/{sid}", headers=auth).json()
    assert seen["budget"] == {"total": 3, "per_minute": None, "left": 0, "left_this_minute": None}
    assert seen["steps"] == 10 and seen["muted"] is False


def test_a_per_minute_budget_refills_at_its_rate(client: TestClient, service: ServiceState) -> None:
    now = [1000.0]
    service.registry.wall = lambda: now[0]
    sid, auth, created = open_session(client, kappa=0.0, budget={"per_minute": 2})
    events = walk(service, 12, 2)

    def advised(lo: int, hi: int) -> list[bool]:
        got = client.post(f"/sessions/{sid}/events", json=events[lo:hi], headers=auth).json()
        return [d["advise"] for d in got]

    assert created["decision"]["advise"]  # one of the minute's two
    assert advised(0, 3) == [True, False, False]
    now[0] += 30.0  # half a minute: one piece back
    assert advised(3, 6) == [True, False, False]
    now[0] += 600.0  # ten minutes: the bucket holds two at most
    assert advised(6, 10) == [True, True, False, False]
    seen = client.get(f"/sessions/{sid}", headers=auth).json()
    assert seen["budget"]["left_this_minute"] == 0 and seen["budget"]["left"] is None
    now[0] += 30.0
    assert client.get(f"/sessions/{sid}", headers=auth).json()["budget"]["left_this_minute"] == 1


def test_a_muted_visitor_gets_no_advice_until_it_asks_again(
    client: TestClient, service: ServiceState
) -> None:
    sid, auth, _ = open_session(client, kappa=0.0)
    events = walk(service, 6, 3)
    muted = client.post(f"/sessions/{sid}/mute", headers=auth)
    assert muted.status_code == 200 and muted.json()["muted"] is True
    got = client.post(f"/sessions/{sid}/events", json=events[:3], headers=auth).json()
    assert [d["advise"] for d in got] == [False, False, False]
    assert got[-1]["step"] == 3  # the advisor still watches
    back = client.post(f"/sessions/{sid}/mute", json={"muted": False}, headers=auth)
    assert back.json()["muted"] is False
    got = client.post(f"/sessions/{sid}/events", json=events[3:], headers=auth).json()
    assert all(d["advise"] for d in got)


def test_only_the_session_s_token_mutes_it(client: TestClient, service: ServiceState) -> None:
    sid, _, _ = open_session(client)
    _, other, _ = open_session(client)
    assert client.post(f"/sessions/{sid}/mute").status_code == 401
    assert client.post(f"/sessions/{sid}/mute", headers=other).status_code == 403


@pytest.mark.parametrize(
    "budget", [{"total": -1}, {"per_minute": 0}, {"total": 1.5}, {"total": True}, {"every": 3}]
)
def test_a_budget_out_of_bounds_is_refused(client: TestClient, budget: dict[str, Any]) -> None:
    r = client.post("/domains/default/sessions", json={"budget": budget})
    assert r.status_code == 422 and "budget" in r.json()["detail"]
