"""Domains placed in metres (resolution, origin) and sessions fed positions in metres."""

from __future__ import annotations

from itertools import pairwise
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.domain.grid import Frame, GridDomain
from app.service.main import create_app
from app.service.state import ServiceState
from tests.service.conftest import TINY, make_settings, open_session

FRAME = {"resolution": 0.5, "origin": [10.0, 20.0]}
GRID = GridDomain.from_strings(TINY, frame=Frame(0.5, (10.0, 20.0, 0.0)))


def centre(row: int, col: int, jitter: float = 0.0) -> list[float]:
    assert GRID.frame is not None
    x, y = GRID.frame.centre(row, col, len(TINY))
    return [x + jitter, y - jitter]


def put(client: TestClient, admin: dict[str, str], **extra: object) -> dict[str, object]:
    r = client.put("/domains/tiny", json={"map": TINY, **extra}, headers=admin)
    assert r.status_code in (200, 201), r.text
    body: dict[str, object] = r.json()
    return body


def test_domain_keeps_its_frame_and_a_new_frame_keeps_the_data(
    client: TestClient, admin: dict[str, str]
) -> None:
    body = put(client, admin, **FRAME)
    assert body["resolution"] == 0.5 and body["origin"] == [10.0, 20.0, 0.0]
    steps = [{"state": [5, 1], "action": "E"}, {"state": [5, 2], "action": "E"}]
    r = client.post("/domains/tiny/trajectories", json={"trajectories": [{"steps": steps}]},
                    headers=admin)  # fmt: skip
    assert r.status_code == 201
    again = put(client, admin, resolution=0.25, origin=[0, 0, 1.5])
    assert again["origin"] == [0.0, 0.0, 1.5] and again["trajectories"] == 1
    plain = put(client, admin)
    assert plain["resolution"] is None and plain["origin"] is None and plain["trajectories"] == 1


def test_frame_survives_a_restart(tmp_path: Path) -> None:
    settings = make_settings(tmp_path / "data")
    with TestClient(create_app(settings)) as client:
        service: ServiceState = client.app.state.service  # type: ignore[attr-defined]
        put(client, {"X-API-Key": service.admin_key}, **FRAME)
    with TestClient(create_app(settings)) as client:
        body = client.get("/domains/tiny").json()
        assert body["resolution"] == 0.5 and body["origin"] == [10.0, 20.0, 0.0]
        assert body["map"] == TINY


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        ({"origin": [1, 2]}, "origin needs resolution"),
        ({"resolution": 0}, "greater than 0"),
        ({"resolution": -1}, "greater than 0"),
        ({"resolution": 1e9}, "less than or equal"),
        ({"resolution": 1, "origin": [1]}, "at least 2"),
        ({"resolution": 1, "origin": [1, 2, 3, 4]}, "at most 3"),
        ({"resolution": 1, "origin": [1, "x"]}, "valid number"),
    ],
)
def test_bad_frames_are_refused_by_name(
    client: TestClient, admin: dict[str, str], extra: dict[str, object], message: str
) -> None:
    r = client.put("/domains/tiny", json={"map": TINY, **extra}, headers=admin)
    assert r.status_code == 422
    assert message in r.json()["detail"]
    for raw in (
        '{"map": ["#S.G#"], "resolution": NaN}',
        '{"map": ["#S.G#"], "resolution": 1, "origin": [Infinity, 0]}',
    ):
        r = client.put(
            "/domains/tiny", content=raw, headers=admin | {"Content-Type": "application/json"}
        )
        assert r.status_code == 422, raw


def test_positions_give_the_decisions_the_same_moves_give_as_events(
    client: TestClient, admin: dict[str, str]
) -> None:
    put(client, admin, **FRAME)
    rng = np.random.default_rng(3)
    for _ in range(5):
        walk = [GRID.start]
        for _ in range(30):
            walk.append(GRID.step(walk[-1], int(rng.integers(4))))
        sid_p, auth_p, _ = open_session(client, "tiny", kappa=0.1, window=7)
        sid_e, auth_e, _ = open_session(client, "tiny", kappa=0.1, window=7)
        readings = [centre(*GRID.cell(s), jitter=float(rng.uniform(-0.2, 0.2))) for s in walk]
        got = client.post(f"/sessions/{sid_p}/positions", json={"positions": readings},
                          headers=auth_p)  # fmt: skip
        assert got.status_code == 200, got.text
        moves = [(s, t) for s, t in pairwise(walk) if s != t]
        events = [{"state": list(GRID.cell(s)), "next_state": list(GRID.cell(t))} for s, t in moves]
        want = client.post(f"/sessions/{sid_e}/events", json=events, headers=auth_e)
        assert got.json() == want.json()
        assert len(got.json()) == len(moves)  # standing still adds no move


def test_a_jump_is_walked_along_a_shortest_path(
    client: TestClient, admin: dict[str, str], service: ServiceState
) -> None:
    put(client, admin, **FRAME)
    sid, auth, _ = open_session(client, "tiny")
    r = client.post(f"/sessions/{sid}/positions", json={"positions": [centre(5, 5)]},
                    headers=auth)  # fmt: skip
    assert r.status_code == 200
    assert [d["state"] for d in r.json()] == [[5, 2], [5, 3], [5, 4], [5, 5]]
    service.settings.max_jump = 2
    far = centre(1, 5)  # 3 moves up the right-hand corridor
    r = client.post(f"/sessions/{sid}/positions", json={"positions": [centre(4, 5), far]},
                    headers=auth)  # fmt: skip
    assert r.status_code == 422
    assert r.json()["detail"].startswith(
        "positions[1]: (12.75, 22.75) m is cell [1, 5], more than 2"
    )
    assert client.get(f"/sessions/{sid}", headers=auth).json()["steps"] == 4  # nothing applied


@pytest.mark.parametrize(
    ("point", "message"),
    [
        (centre(0, 0), "positions[0]: position (10.25, 23.25) m: cell [0, 0] is a wall"),
        ([0.0, 0.0], "is off the 7x7 map"),
    ],
)
def test_positions_in_walls_or_off_the_map_are_refused(
    client: TestClient, admin: dict[str, str], point: list[float], message: str
) -> None:
    put(client, admin, **FRAME)
    sid, auth, _ = open_session(client, "tiny")
    r = client.post(f"/sessions/{sid}/positions", json={"positions": [point]}, headers=auth)
    assert r.status_code == 422 and message in r.json()["detail"]


def test_positions_need_a_frame_a_token_and_a_bounded_walk(
    client: TestClient, admin: dict[str, str], service: ServiceState
) -> None:
    sid, auth, _ = open_session(client)  # the default domain has no frame
    r = client.post(f"/sessions/{sid}/positions", json={"positions": [[1, 2]]}, headers=auth)
    assert r.status_code == 422 and "has no resolution" in r.json()["detail"]
    put(client, admin, **FRAME)
    sid, auth, _ = open_session(client, "tiny")
    assert (
        client.post(f"/sessions/{sid}/positions", json={"positions": [[1, 2]]}).status_code == 401
    )
    r = client.post(f"/sessions/{sid}/positions", json={"positions": []}, headers=auth)
    assert r.status_code == 422
    service.settings.max_batch_events = 4
    r = client.post(f"/sessions/{sid}/positions", json={"positions": [centre(5, 5)]}, headers=auth)
    assert r.status_code == 200 and len(r.json()) == 4  # four moves: at the limit
    r = client.post(
        f"/sessions/{sid}/positions", json={"positions": [centre(5, 1), centre(5, 5)]}, headers=auth
    )
    assert r.status_code == 413 and "more than 4" in r.json()["detail"]


def test_one_reading_off_by_a_cell_through_positions_sets_a_destination_aside(
    client: TestClient, admin: dict[str, str]
) -> None:
    """A guide session fed positions in metres: a visitor walks up the right-hand corridor
    towards the destination [1, 5] and one reading, next to it, is seen on it. Walked, that
    is a step onto it and back: [1, 5] is set aside, not ruled out. Once the visitor has
    passed the other destination too, both come back; a second visit rules one out."""
    put(client, admin, **FRAME)
    sid, auth, _ = open_session(client, "tiny", strategy="guide")
    walk = [(5, 2), (5, 3), (5, 4), (5, 5), (4, 5), (3, 5), (2, 5)]
    readings = [centre(*cell) for cell in walk] + [centre(1, 5), centre(2, 5)]
    r = client.post(f"/sessions/{sid}/positions", json={"positions": readings}, headers=auth)
    assert r.status_code == 200, r.text

    def goals() -> list[dict[str, object]]:
        got: list[dict[str, object]] = client.get(f"/sessions/{sid}", headers=auth).json()["goals"]
        assert [g["goal"] for g in got] == [[1, 1], [1, 5]]
        return got

    assert goals()[1]["ruled_out"] and not goals()[0]["ruled_out"]  # set aside
    # down, across and up to [1, 1], over it and on: set aside too, so both come back
    walk = [(3, 5), (4, 5), (4, 4), (4, 3), (3, 3), (2, 3), (1, 3), (1, 2), (1, 1), (2, 1)]
    r = client.post(f"/sessions/{sid}/positions", json={"positions": [centre(*c) for c in walk]},
                    headers=auth)  # fmt: skip
    assert r.status_code == 200, r.text
    assert not any(g["ruled_out"] for g in goals())
    # over [1, 1] a second time: ruled out, and [1, 5] is where the visitor is bound
    walk = [(1, 1), (1, 2)]
    r = client.post(f"/sessions/{sid}/positions", json={"positions": [centre(*c) for c in walk]},
                    headers=auth)  # fmt: skip
    assert r.status_code == 200, r.text
    now = goals()
    assert now[0]["ruled_out"] and not now[1]["ruled_out"]
    assert now[1]["p"] == pytest.approx(1.0)
