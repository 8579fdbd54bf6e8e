"""A map of several floors served: cells ``[floor, row, col]``, the actions ``U`` and ``D``,
errors that say which shape a cell has on which map, the prior and trajectories six actions
wide (over a restart), positions with their floor, the binary frame's wide form.

That sessions decide as the core on a building, over REST, the websocket, binary frames and
two workers sharing Redis, is ``tests/service/test_strategies.py`` and
``tests/service/test_workers.py`` (their maps: the shipped maze and ``TOWER``)."""

from __future__ import annotations

import json
import struct
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from advisor_client import protocol
from fastapi.testclient import TestClient

from app.domain.building import Building, U
from app.domain.grid import Frame
from app.domain.paths import expert_trajectory
from app.service.main import create_app
from app.service.state import ServiceState
from tests.service.conftest import make_settings, open_session, put_tiny
from tests.service.test_strategies import TOWER, put_tower


def a_stop(b: Building) -> int:
    """A state of the lowest floor from which ``U`` rides up."""
    return int(b.rides[b.cells[b.rides[:, 0], 0] == 0][0, 0])


def detail(r: object) -> str:
    assert r.status_code == 422, r.text  # type: ignore[attr-defined]
    said: str = r.json()["detail"]  # type: ignore[attr-defined]
    return said


def test_events_of_another_shape_are_refused_saying_what_a_cell_is(
    client: TestClient, admin: dict[str, str]
) -> None:
    b = put_tower(client, admin)
    put_tiny(client, admin)
    sid, auth, _ = open_session(client, "tower")
    tiny, tiny_auth, _ = open_session(client, "tiny")
    f, r, c = b.cell(b.start)
    wide = "this map has 2 floors: a cell is [floor, row, col]"
    body: Any
    for body in ({"state": [r, c], "action": "N"}, [{"state": [r, c], "action": "N"}],
                 [{"state": [f, r, c], "action": "N"}, {"state": [r, c], "action": "E"}],
                 {"state": [f, r, c], "next_state": [r, c]}):  # fmt: skip
        said = detail(client.post(f"/sessions/{sid}/events", json=body, headers=auth))
        assert said.endswith(wide), said
    one = "this map has one floor: a cell is [row, col]"
    said = detail(client.post(f"/sessions/{tiny}/events", json={"state": [0, 5, 1],
                              "action": "N"}, headers=tiny_auth))  # fmt: skip
    assert said == f"event 0: state [0, 5, 1]: {one}"
    for up in ("U", 4, "D", 5):
        for body in ({"state": [5, 1], "action": up}, [{"state": [5, 1], "action": up}]):
            said = detail(client.post(f"/sessions/{tiny}/events", json=body, headers=tiny_auth))
            assert said.startswith("event 0: action ") and "changes floor" in said, said
    # an expert's step up on one floor: the same words, located in the trajectory
    up_step = {"trajectories": [{"steps": [{"state": [5, 1], "action": "U"}]}]}
    refused = client.post("/domains/tiny/trajectories", json=up_step, headers=admin)
    assert detail(refused) == (
        "trajectories[0].steps[0]: action 'U' changes floor: this map has one floor (N, E, S, W)"
    )
    # off the building: the floor, the row or the column
    for cell in ([2, r, c], [f, 20, c], [f, r, 20]):
        said = detail(client.post(f"/sessions/{sid}/events", json={"state": cell, "action": "N"},
                                  headers=auth))  # fmt: skip
        assert said == f"event 0: state {cell} is off the 2x20x20 map"
    # a next_state on the floor above: one move (U) at a stop, not elsewhere
    stop = a_stop(b)
    here, above = list(b.cell(stop)), list(b.cell(int(b.next_state[stop, U])))
    r2 = client.post(f"/sessions/{sid}/events", json={"state": here, "next_state": above},
                     headers=auth)  # fmt: skip
    assert r2.status_code == 200 and r2.json()["state"] == above
    said = detail(client.post(f"/sessions/{sid}/events", json={"state": [f, r, c],
                              "next_state": [1, r, c]}, headers=auth))  # fmt: skip
    assert "is not one move from state" in said
    empty = client.post(f"/sessions/{sid}/events", json=[], headers=auth)
    assert empty.status_code == 200 and empty.json() == []
    # nothing refused was applied: the session made the one move it was sent, upstairs
    seen = client.get(f"/sessions/{sid}", headers=auth).json()
    assert seen["steps"] == 1 and seen["floor"] == b.floors[1].name
    assert "floor" not in client.get(f"/sessions/{tiny}", headers=tiny_auth).json()
    listed = client.get("/overview", headers=admin).json()["sessions"]
    assert {s["session_id"]: s.get("floor") for s in listed} == {sid: b.floors[1].name, tiny: None}
    # a start of the wrong shape is refused the same way
    r3 = client.post("/domains/tower/sessions", json={"start": [r, c]})
    assert detail(r3) == f"start: [{r}, {c}]: {wide}"


def test_a_building_s_prior_and_trajectories_are_six_actions_wide_over_a_restart(
    tmp_path: Path,
) -> None:
    data = make_settings(tmp_path / "data")
    rng = np.random.default_rng(4)
    with TestClient(create_app(data)) as client:
        service: ServiceState = client.app.state.service  # type: ignore[attr-defined]
        admin = {"X-API-Key": service.admin_key}
        b = put_tower(client, admin)
        goal = b.goals[-1]  # upstairs: the experts ride
        pairs = expert_trajectory(b, b.start, goal, rng)
        assert b.cells[goal, 0] == 1 and U in pairs[:, 1]
        steps = [{"state": list(b.cell(s)), "action": b.actions[a]} for s, a in pairs.tolist()]
        body = {"trajectories": [{"steps": steps, "goal": list(b.cell(goal)),
                                  "agent_type": "porter"}]}  # fmt: skip
        r = client.post("/domains/tower/trajectories", json=body, headers=admin)
        assert r.status_code == 201, r.text
        # a step of the wrong shape, or an action the map has not, is refused naming it
        bad = {"trajectories": [{"steps": [{"state": [1, 1], "action": "N"}]}]}
        r = client.post("/domains/tower/trajectories", json=bad, headers=admin)
        assert detail(r).startswith("trajectories[0].steps[0]: cell [1, 1]: this map has 2")
        prior = client.get("/domains/tower/prior", params={"agent_type": "porter"}).json()
        assert prior["actions"] == ["N", "E", "S", "W", "U", "D"]
        theta = prior["theta"]
        assert (len(theta), len(theta[0]), len(theta[0][0])) == (2, 20, 20)
        for s in range(b.n_states):  # walls null, free cells six numbers summing to 1
            row = theta[b.cells[s, 0]][b.cells[s, 1]][b.cells[s, 2]]
            assert len(row) == 6 and abs(sum(row) - 1) < 1e-12
        assert theta[0][0][0] is None
        stored = service.store.counts("tower")
        assert {k: t.counts.shape for k, t in stored.items()} == {
            "*": (b.n_states, 6), "porter": (b.n_states, 6),
        }  # fmt: skip
        assert all(
            np.array_equal(stored[k].counts, t.counts)
            for k, t in service.store.recount("tower", b.n_states, 6).items()
        )
        before = client.get("/domains/tower/prior", params={"agent_type": "porter"}).content
        shown = client.get("/domains/tower").json()
    with TestClient(create_app(data)) as again:
        assert again.get("/domains/tower/prior", params={"agent_type": "porter"}).content == before
        assert again.get("/domains/tower").json() == shown


def test_positions_on_a_building_are_read_with_their_floor(
    client: TestClient, admin: dict[str, str]
) -> None:
    b = replace(TOWER, frame=Frame(0.5, (0.0, 0.0, 0.0)))
    r = client.put("/domains/framed", content=b.to_text(), headers=admin | {
        "Content-Type": "text/plain"})  # fmt: skip
    assert r.status_code == 201, r.text
    stop = a_stop(b)
    up = int(b.next_state[stop, U])
    sid, auth, _ = open_session(client, "framed", start=list(b.cell(stop)))
    f, row, col = b.cell(up)
    x, y = b.frame.centre(row, col, b.shape[1])  # type: ignore[union-attr]
    r = client.post(f"/sessions/{sid}/positions", json={"positions": [[x, y, f]]}, headers=auth)
    assert r.status_code == 200, r.text
    assert [d["state"] for d in r.json()] == [[f, row, col]]
    said = detail(client.post(f"/sessions/{sid}/positions", json={"positions": [[x, y]]},
                              headers=auth))  # fmt: skip
    assert said.startswith("positions[0]: this map has 2 floors: a position is [x, y, floor]")
    said = detail(client.post(f"/sessions/{sid}/positions", json={"positions": [[x, y, 0.5]]},
                              headers=auth))  # fmt: skip
    assert "a position is [x, y, floor]" in said


def test_binary_frames_of_a_building_are_the_wide_form_and_one_floor_s_as_before(
    client: TestClient, admin: dict[str, str]
) -> None:
    b = put_tower(client, admin)
    put_tiny(client, admin)
    for name, cells in (("tower", [list(b.cell(b.start))]), ("tiny", [[5, 1]])):
        sid, _, created = open_session(client, name, kappa=0.0)
        url = f"/sessions/{sid}/stream?token={created['token']}&format=binary"
        with client.websocket_connect(url) as ws:
            ws.send_text(json.dumps([{"state": cells[0], "action": "N"}] * 3))
            raw = ws.receive_bytes()
        flags = protocol.HEADER.unpack_from(raw)[3]
        frame = protocol.unpack(raw)
        assert flags == (protocol.FLOORS if name == "tower" else 0)
        assert frame.cell.shape == (3, len(cells[0])) and frame.advise.all()
        assert frame.advice.shape == (3, 6 if name == "tower" else 4)
        assert set(frame.to_dicts()[0]["advice"]) == set("NESWUD"[: frame.advice.shape[1]])


def test_a_one_floor_frame_is_the_layout_it_always_was() -> None:
    """Byte for byte as format 1 wrote it before floors (struct by hand, flags 0)."""
    kl, p = np.array([0.5, 0.25]), np.array([0.75, 0.125])
    advice, cells = np.array([[0.1, 0.2, 0.3, 0.4]]), np.array([[1, 2], [3, 4]], np.int32)
    advise = np.array([True, False])
    frame = protocol.pack(7, 0.5, 2, 1.5, kl, p, advice, cells, advise)
    by_hand = struct.pack("<4sIIIqdqd", b"HGA1", 2, 1, 0, 7, 0.5, 2, 1.5)
    by_hand += struct.pack("<2d2d4d4i2B", *kl, *p, *advice[0], 1, 2, 3, 4, 1, 0)
    assert frame == by_hand
    with pytest.raises(protocol.FrameError, match="flags 2"):
        protocol.unpack(by_hand[:12] + b"\x02\x00\x00\x00" + by_hand[16:])
