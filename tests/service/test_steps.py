"""Events with ``step`` over REST and the websocket: a retry is answered as it was the first
time and applies nothing; a step out of turn is a 409 JSON answer that changes nothing."""

from __future__ import annotations

import json
from typing import Any

import numpy as np
from fastapi.testclient import TestClient

from app.domain.building import Domain
from app.domain.grid import ACTIONS
from app.service.state import ServiceState
from tests.service.conftest import open_session


def _events(grid: Domain, n: int, first: int, seed: int) -> list[dict[str, Any]]:
    rng = np.random.default_rng(seed)
    s, out = grid.start, []
    for i, a in enumerate(rng.integers(0, 4, n).tolist()):
        out.append({"state": list(grid.cell(s)), "action": ACTIONS[a], "step": first + i})
        s = grid.step(s, a)
    return out


def test_a_retried_rest_event_is_answered_again_and_applied_once(
    client: TestClient, service: ServiceState
) -> None:
    grid = service.catalog.get("default").domain
    sid, auth, _ = open_session(client, kappa=0.0)
    events = _events(grid, 30, 1, seed=4)
    first = [client.post(f"/sessions/{sid}/events", json=e, headers=auth) for e in events[:10]]
    assert [r.status_code for r in first] == [200] * 10
    again = client.post(f"/sessions/{sid}/events", json=events[9], headers=auth)
    assert again.status_code == 200 and again.json() == first[9].json()
    batch = client.post(f"/sessions/{sid}/events", json=events[10:30], headers=auth)
    overlap = client.post(f"/sessions/{sid}/events", json=events[5:30], headers=auth)
    assert overlap.status_code == 200
    assert overlap.json() == [r.json() for r in first[5:]] + batch.json()
    assert client.get(f"/sessions/{sid}", headers=auth).json()["steps"] == 30


def test_a_step_out_of_turn_is_409_and_changes_nothing(
    client: TestClient, service: ServiceState
) -> None:
    grid = service.catalog.get("default").domain
    sid, auth, _ = open_session(client)
    events = _events(grid, 5, 1, seed=1)
    assert client.post(f"/sessions/{sid}/events", json=events[:2], headers=auth).status_code == 200
    r = client.post(f"/sessions/{sid}/events", json=events[3], headers=auth)
    assert r.status_code == 409
    assert r.json()["detail"].startswith("step 4 is not the next step"), r.json()
    assert client.get(f"/sessions/{sid}", headers=auth).json()["steps"] == 2
    shuffled = [dict(events[2], step=3), dict(events[3], step=5)]
    r = client.post(f"/sessions/{sid}/events", json=shuffled, headers=auth)
    assert r.status_code == 422 and "does not follow the batch's numbering" in r.json()["detail"]


def test_a_websocket_client_resending_its_frames_gets_the_same_answers(
    client: TestClient, service: ServiceState
) -> None:
    grid = service.catalog.get("default").domain
    sid, auth, _ = open_session(client, kappa=0.2)
    events = _events(grid, 60, 1, seed=9)
    frames = [events[i : i + 20] for i in range(0, 60, 20)]
    with client.websocket_connect(f"/sessions/{sid}/stream", headers=auth) as ws:
        answers = []
        for frame in frames:
            ws.send_text(json.dumps(frame))
            answers.append(json.loads(ws.receive_text()))
    with client.websocket_connect(f"/sessions/{sid}/stream", headers=auth) as ws:
        for frame, answer in zip(frames[1:], answers[1:], strict=True):  # as after a reconnect
            ws.send_text(json.dumps(frame))
            assert json.loads(ws.receive_text()) == answer
        ws.send_text(json.dumps(events[0] | {"step": 62}))
        refused = json.loads(ws.receive_text())
        assert refused["status"] == 409
    assert client.get(f"/sessions/{sid}", headers=auth).json()["steps"] == 60
