"""Domains, trajectories and priors over HTTP: every route, its errors, status first."""

from __future__ import annotations

from typing import Any

import numpy as np
from fastapi.testclient import TestClient

from app.domain.grid import GridDomain
from app.service.data.store import POOLED
from app.service.public import prior_public
from app.service.state import ServiceState
from tests.service.conftest import TINY, open_session, put_tiny

DOMAIN = GridDomain.from_strings(TINY)


def walk(cells_actions: list[tuple[tuple[int, int], str]]) -> list[dict[str, Any]]:
    return [{"state": list(c), "action": a} for c, a in cells_actions]


# a path walked on TINY from the start [5, 1] up to the goal [1, 1]
PATH = walk([((5, 1), "E"), ((5, 2), "E"), ((5, 3), "N"), ((4, 3), "N"), ((3, 3), "W"),
             ((3, 2), "W"), ((3, 1), "N"), ((2, 1), "N")])  # fmt: skip


def test_read_domains_lists_the_default_domain(client: TestClient) -> None:
    r = client.get("/domains")
    assert r.status_code == 200
    (default,) = r.json()
    assert default["name"] == "default" and default["rows"] == 30 and default["cols"] == 30
    assert default["start"] == [28, 0] and len(default["goals"]) == 8
    assert default["actions"] == ["N", "E", "S", "W"]
    assert default["trajectories"] == 2 * 8  # bootstrap_per_goal=2 in the test settings


def test_read_domain_not_found(client: TestClient) -> None:
    r = client.get("/domains/nowhere")
    assert r.status_code == 404
    assert "nowhere" in r.json()["detail"]


def test_read_domain_refuses_odd_names(client: TestClient) -> None:
    r = client.get("/domains/caf%C3%A9%E2%98%83")
    assert r.status_code == 422
    assert "path.name" in r.json()["detail"]


def test_put_domain_needs_the_admin_key(client: TestClient) -> None:
    r = client.put("/domains/tiny", json={"map": TINY})
    assert r.status_code == 401
    assert "X-API-Key" in r.json()["detail"]
    r = client.put("/domains/tiny", json={"map": TINY}, headers={"X-API-Key": "wrong"})
    assert r.status_code == 403


def test_put_domain_creates_then_replaces(client: TestClient, admin: dict[str, str]) -> None:
    r = client.put("/domains/tiny", json={"map": TINY, "alpha0": 0.5}, headers=admin)
    assert r.status_code == 201
    body = r.json()
    assert body["map"] == TINY and body["alpha0"] == 0.5 and body["start"] == [5, 1]
    assert body["goals"] == [[1, 1], [1, 5]] and body["n_states"] == DOMAIN.n_states
    r = client.put("/domains/tiny", json={"map": TINY}, headers=admin)
    assert r.status_code == 200
    assert r.json()["created_at"] == body["created_at"]
    assert [d["name"] for d in client.get("/domains").json()] == ["default", "tiny"]


def test_put_domain_explains_a_bad_map(client: TestClient, admin: dict[str, str]) -> None:
    bad = [*TINY[:2], "#.x...#", *TINY[3:]]
    r = client.put("/domains/tiny", json={"map": bad}, headers=admin)
    assert r.status_code == 422
    assert r.json()["detail"] == (
        "map: line 3, column 3: unknown character 'x': use '#' wall, '.' free, 'S' start, 'G' goal"
    )
    r = client.put("/domains/tiny", json={"map": ["###", "#S#", "###"]}, headers=admin)
    assert r.status_code == 422
    assert "no goal" in r.json()["detail"]
    r = client.put("/domains/tiny", json={"map": "#S.G#"}, headers=admin)
    assert r.status_code == 422
    r = client.put("/domains/tiny", json={"map": TINY, "alpha0": 0}, headers=admin)
    assert r.status_code == 422
    assert "alpha0" in r.json()["detail"]


def test_put_domain_refuses_maps_over_the_size_limit(
    client: TestClient, admin: dict[str, str], service: ServiceState
) -> None:
    service.catalog.max_cells = 40
    r = client.put("/domains/tiny", json={"map": TINY}, headers=admin)
    assert r.status_code == 422
    assert "larger than 40 cells" in r.json()["detail"]


def test_delete_domain_ends_its_sessions(client: TestClient, admin: dict[str, str]) -> None:
    put_tiny(client, admin)
    sid, auth, _ = open_session(client, "tiny")
    r = client.delete("/domains/tiny")
    assert r.status_code == 401
    r = client.delete("/domains/tiny", headers=admin)
    assert r.status_code == 204
    assert client.get("/domains/tiny").status_code == 404
    assert client.get(f"/sessions/{sid}", headers=auth).status_code == 404
    assert client.delete("/domains/tiny", headers=admin).status_code == 404


def test_add_trajectories_updates_the_prior_at_once(
    client: TestClient, admin: dict[str, str]
) -> None:
    put_tiny(client, admin)
    before = client.get("/domains/tiny/prior").json()
    assert before["trajectories"] == 0 and before["theta"][5][1] == [0.25] * 4
    body = {
        "trajectories": [
            {"steps": PATH, "goal": [1, 1]},
            {"agent_type": "staff", "steps": PATH[:3]},
        ]
    }
    r = client.post("/domains/tiny/trajectories", json=body, headers=admin)
    assert r.status_code == 201
    assert r.json() == {"accepted": 2, "pairs": len(PATH) + 3}
    after = client.get("/domains/tiny/prior").json()
    assert after["trajectories"] == 2 and after["table"] == POOLED
    # [5, 1] was left going E by both trajectories: alpha = 1 + (0, 2, 0, 0) over 4 + 2
    np.testing.assert_allclose(after["theta"][5][1], [1 / 6, 3 / 6, 1 / 6, 1 / 6])
    staff = client.get("/domains/tiny/prior", params={"agent_type": "staff"}).json()
    assert staff["table"] == "staff" and staff["trajectories"] == 1
    np.testing.assert_allclose(staff["theta"][5][1], [1 / 5, 2 / 5, 1 / 5, 1 / 5])
    assert client.get("/domains/tiny").json()["agent_types"] == ["staff"]


def test_prior_is_rows_by_cols_by_4_with_walls_null(client: TestClient) -> None:
    r = client.get("/domains/default/prior")
    assert r.status_code == 200
    body = r.json()
    theta = body["theta"]
    assert len(theta) == 30 and all(len(row) == 30 for row in theta)
    rows = client.get("/domains/default").json()["map"]
    for r_, line in enumerate(rows):
        for c, ch in enumerate(line):
            assert (theta[r_][c] is None) == (ch == "#")
            if ch != "#":
                assert abs(sum(theta[r_][c]) - 1.0) < 1e-12
    assert body["actions"] == ["N", "E", "S", "W"] and body["alpha0"] == 1.0


def test_prior_of_a_type_without_data_is_the_pooled_one(client: TestClient) -> None:
    r = client.get("/domains/default/prior", params={"agent_type": "visitor"})
    assert r.status_code == 200
    assert r.json()["agent_type"] == "visitor" and r.json()["table"] == POOLED
    r = client.get("/domains/default/prior", params={"agent_type": "b@d name"})
    assert r.status_code == 422


def _post(client: TestClient, admin: dict[str, str], body: Any) -> tuple[int, str]:
    r = client.post("/domains/tiny/trajectories", json=body, headers=admin)
    return r.status_code, r.json()["detail"]


def test_add_trajectories_refuses_bad_ones_with_reasons(
    client: TestClient, admin: dict[str, str], service: ServiceState
) -> None:
    put_tiny(client, admin)
    T = "trajectories"
    cases = [
        (
            {T: [{"steps": walk([((0, 0), "E")])}]},
            "trajectories[0].steps[0]: cell [0, 0] is a wall",
        ),
        (
            {T: [{"steps": walk([((5, 1), "E"), ((9, 9), "E")])}]},
            "trajectories[0].steps[1]: cell [9, 9] is off the 7x7 map",
        ),
        (
            {T: [{"steps": PATH}, {"steps": walk([((5, 1), "E"), ((5, 3), "E")])}]},
            "trajectories[1].steps[1]: state [5, 3] is not where the previous step leads ([5, 2])",
        ),
        ({T: [{"steps": walk([((5, 1), "X")])}]}, "trajectories[0].steps[0].action: an action is"),
        ({T: [{"steps": []}]}, "trajectories[0].steps: List should have at least 1 item"),
        ({T: []}, "trajectories: List should have at least 1 item"),
        ({T: [{"steps": PATH, "goal": [0, 0]}]}, "trajectories[0].goal: cell [0, 0] is a wall"),
        ({T: [{"steps": PATH, "agent_type": "*"}]}, "agent_type: String should match pattern"),
        ({T: [{"steps": PATH, "agent_type": "sta ff☃"}]}, "agent_type: String should match"),
        (
            {T: [{"steps": PATH, "extra": 1}]},
            "trajectories[0].extra: Extra inputs are not permitted",
        ),
        ({"trajectory": []}, "trajectories: Field required"),
    ]
    for body, message in cases:
        status, detail = _post(client, admin, body)
        assert status == 422, (body, detail)
        assert message in detail, (message, detail)
    service.settings.max_trajectory_steps = 5
    status, detail = _post(client, admin, {"trajectories": [{"steps": PATH}]})
    assert status == 413 and "at most 5" in detail
    # nothing of the refused requests was stored
    assert client.get("/domains/tiny/prior").json()["trajectories"] == 0
    assert service.store.counts("tiny") == {}


def test_add_trajectories_to_an_unknown_domain_is_404(
    client: TestClient, admin: dict[str, str]
) -> None:
    r = client.post("/domains/nowhere/trajectories", json={"trajectories": []}, headers=admin)
    assert r.status_code == 404


def test_replacing_the_map_ends_sessions_and_the_same_map_keeps_them(
    client: TestClient, admin: dict[str, str]
) -> None:
    put_tiny(client, admin)
    client.post(
        "/domains/tiny/trajectories", json={"trajectories": [{"steps": PATH}]}, headers=admin
    )
    sid, auth, _ = open_session(client, "tiny")
    r = client.put("/domains/tiny", json={"map": TINY, "alpha0": 2.0}, headers=admin)
    assert r.status_code == 200
    assert r.json()["trajectories"] == 1  # same map: data kept, only alpha0 changed
    assert client.get(f"/sessions/{sid}", headers=auth).status_code == 200
    new_map = [*TINY[:1], "#G..#.#", *TINY[2:]]  # one goal fewer
    r = client.put("/domains/tiny", json={"map": new_map}, headers=admin)
    assert r.status_code == 200
    assert r.json()["trajectories"] == 0
    assert client.get(f"/sessions/{sid}", headers=auth).status_code == 404


def test_the_prior_s_answer_is_the_readable_form_s(
    client: TestClient, admin: dict[str, str], service: ServiceState
) -> None:
    """GET /domains/{name}/prior is made once per prior version as text (orjson over numpy,
    walls turned to null: app/service/answers.py); it says what the readable form, pydantic
    over Python lists (``public.prior_public``), says, for every table and an unknown type."""
    put_tiny(client, admin)
    steps = [{"state": [5, 1], "action": "E"}, {"state": [5, 2], "action": "E"}]
    body = {"trajectories": [{"agent_type": "staff", "steps": steps}]}
    assert client.post("/domains/tiny/trajectories", json=body, headers=admin).status_code == 201
    for agent_type in (None, "staff", "martian"):
        params = {} if agent_type is None else {"agent_type": agent_type}
        got = client.get("/domains/tiny/prior", params=params).json()
        readable = prior_public(service.catalog.get("tiny"), agent_type)
        assert got == readable.model_dump(mode="json")
