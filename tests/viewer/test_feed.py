"""The viewer's feed from a service over HTTP (``RemoteFeed`` reading ``GET /viewer/snapshot``
with the operator key, maps and priors fetched when they change), and ``GET /viewer``."""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.domain.building import Building, building_of
from app.domain.floorplans import generate_floors
from app.domain.grid import Frame, GridDomain, MapError
from app.service.config import Settings
from app.service.main import create_app
from app.viewer.remote import RemoteFeed
from tests.viewer.conftest import free_port

ADMIN = "viewer-test-admin-key"


def settings(tmp: Path, viewer: bool) -> Settings:
    return Settings(
        data_dir=tmp,
        admin_key=ADMIN,
        viewer_enabled=viewer,
        viewer_port=free_port(),
        bootstrap_per_goal=2,
        overview_seconds=0.0,  # every read sees the events before it
    )


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    app = create_app(settings(tmp_path_factory.mktemp("feed"), viewer=False))
    with TestClient(app) as c:
        yield c


def walk(client: TestClient, moves: str, kappa: float = 0.5) -> tuple[str, dict[str, str]]:
    """A new session that makes ``moves`` one event at a time; its id and auth header."""
    created = client.post("/domains/default/sessions", json={"kappa": kappa})
    assert created.status_code == 201
    body = created.json()
    auth = {"Authorization": f"Bearer {body['token']}"}
    state = body["decision"]["state"]
    for a in moves:
        event = {"state": state, "action": a}
        answer = client.post(f"/sessions/{body['session_id']}/events", json=event, headers=auth)
        assert answer.status_code == 200
        state = answer.json()["state"]
    return body["session_id"], auth


def remote(client: TestClient) -> RemoteFeed:
    """The viewer's feed, reading this service with the read-only operator key."""
    return RemoteFeed(client, client.app.state.service.operator_key)  # type: ignore[attr-defined]


def test_feed_snapshot_holds_domains_with_their_prior(client: TestClient) -> None:
    feed = remote(client)
    snap = feed()
    view = snap.domains["default"]
    prior = client.get("/domains/default/prior").json()
    grid = np.array([[v if v is not None else [np.nan] * 4 for v in row] for row in prior["theta"]])
    cells = view.domain.cells
    np.testing.assert_allclose(view.theta, grid[cells[:, 0], cells[:, 1]], rtol=1e-12)
    assert feed().domains["default"] is view  # nothing changed: the same view, same version


def test_feed_snapshot_holds_each_session_as_the_service_sees_it(client: TestClient) -> None:
    sid, auth = walk(client, "EEEWW", kappa=0.0)  # kappa 0: advised at every decision
    snap = remote(client)()
    mine = next(s for s in snap.sessions if s.session_id == sid)
    summary = client.get(f"/sessions/{sid}", headers=auth).json()
    assert mine.steps == summary["steps"] == 5
    assert list(mine.position) == summary["position"]
    assert mine.p_normal == pytest.approx(summary["p_normal"])
    assert mine.advice_count == summary["advice_count"]
    assert mine.total_cost == pytest.approx(summary["total_cost"])
    assert [list(c) for c in mine.path] == [[28, 0], [28, 1], [28, 2], [28, 3], [28, 2], [28, 1]]
    assert len(mine.p_normal_history) == 6
    assert len(mine.advice) == mine.advice_count == 6
    for (_, cell, probabilities), at in zip(mine.advice, mine.path, strict=True):
        assert tuple(cell) == tuple(at) and sum(probabilities) == pytest.approx(1.0)
    assert [step for step, _, _ in mine.advice] == list(range(6))


def test_feed_gives_the_sessions_most_recently_active_first(client: TestClient) -> None:
    first, first_auth = walk(client, "E")
    second, _ = walk(client, "E")
    order = [s.session_id for s in remote(client)().sessions]
    assert order.index(second) < order.index(first)
    event = {"state": [28, 1], "action": "E"}
    answer = client.post(f"/sessions/{first}/events", json=event, headers=first_auth)
    assert answer.status_code == 200
    order = [s.session_id for s in remote(client)().sessions]
    assert order.index(first) < order.index(second)


def test_feed_prior_version_goes_up_when_trajectories_arrive(client: TestClient) -> None:
    feed = remote(client)
    before = feed().domains["default"]
    steps = [{"state": [28, c], "action": "E"} for c in range(0, 6)]
    answer = client.post(
        "/domains/default/trajectories",
        json={"trajectories": [{"steps": steps}]},
        headers={"X-API-Key": ADMIN},
    )
    assert answer.status_code == 201
    after = feed().domains["default"]
    assert after.prior_version > before.prior_version
    assert after.domain is before.domain  # the map was not fetched again
    assert not np.array_equal(after.theta, before.theta)


def test_viewer_status_says_disabled_without_a_viewer(client: TestClient) -> None:
    answer = client.get("/viewer")
    assert answer.status_code == 200
    assert answer.json() == {"enabled": False, "running": False, "port": None, "host": None}


def test_viewer_status_says_where_serve_starts_it(tmp_path: Path) -> None:
    cfg = settings(tmp_path, viewer=True)
    with TestClient(create_app(cfg)) as c:
        status = c.get("/viewer").json()
    # no viewer process of this app's (TestClient starts none): taken to be running
    assert status == {
        "enabled": True,
        "running": True,
        "port": cfg.viewer_port,
        "host": "127.0.0.1",
    }


def test_the_snapshot_is_for_the_operator_and_admin_keys_only(client: TestClient) -> None:
    assert client.get("/viewer/snapshot").status_code == 401
    assert client.get("/viewer/snapshot", headers={"X-API-Key": "nope"}).status_code == 403
    assert client.get("/viewer/snapshot", headers={"X-API-Key": ADMIN}).status_code == 200


def test_feed_carries_a_goal_aware_sessions_goal_posterior(client: TestClient) -> None:
    grid = client.app.state.service.catalog.get("default").domain  # type: ignore[attr-defined]
    goal = grid.goals[0]
    move = next(a for a in range(4) if grid.next_state[goal, a] != goal)
    body = {"strategy": "goal_aware", "params": {"beta": 0.5}, "start": grid.cell(goal)}
    created = client.post("/domains/default/sessions", json=body).json()
    auth = {"Authorization": f"Bearer {created['token']}"}
    event = {"state": grid.cell(goal), "action": "NESW"[move]}
    assert client.post(f"/sessions/{created['session_id']}/events", json=event, headers=auth)
    snap = remote(client)()
    mine = next(s for s in snap.sessions if s.session_id == created["session_id"])
    assert mine.strategy == "goal_aware" and mine.goals is not None
    summary = client.get(f"/sessions/{created['session_id']}", headers=auth).json()
    assert [[list(c), p, out] for c, p, out in mine.goals] == [
        [g["goal"], g["p"], g["ruled_out"]] for g in summary["goals"]
    ]
    assert mine.goals[0][2] and not any(out for _, _, out in mine.goals[1:])
    sid, _ = walk(client, "E")
    paper = next(s for s in remote(client)().sessions if s.session_id == sid)
    assert paper.strategy == "paper" and paper.goals is None


def test_the_viewers_tick_time_reaches_the_metrics(client: TestClient) -> None:
    """The viewer process reports each tick's duration with its next snapshot request; the
    service counts it in ``advisor_viewer_tick_seconds``; a value that is not a duration is
    ignored, not an error."""

    def ticks() -> float:
        m = re.search(
            r"^advisor_viewer_tick_seconds_count (\S+)$", client.get("/metrics").text, re.M
        )
        return float(m.group(1)) if m else 0.0

    before = ticks()
    feed = RemoteFeed(client, ADMIN)
    feed.report_tick(0.012)
    feed()
    assert ticks() == before + 1
    assert feed.last_tick is None  # sent once
    for bad in ("nan", "-1", "1e9", "soon", "9" * 100):
        r = client.get("/viewer/snapshot", headers={"X-API-Key": ADMIN, "X-Viewer-Tick": bad})
        assert r.status_code == 200
    assert ticks() == before + 1


def test_feed_carries_destination_names_and_what_the_advisor_believes(
    client: TestClient,
) -> None:
    """A domain's named destinations reach the viewer's grid (its labels); a guide session's
    beliefs (figures, the destination its advice leads to) reach its view."""
    rows = ["#######", "#G..#G#", "#.#.#.#", "#...#.#", "###...#", "#S....#", "#######"]
    text = "destination: 1 1 Lobby\ndestination: 1 5 Exit\n" + "\n".join(rows)
    put = client.put("/domains/named-feed?experts=start&per_goal=2", content=text,
                     headers={"X-API-Key": ADMIN, "Content-Type": "text/plain"})  # fmt: skip
    assert put.status_code == 201, put.text
    made = client.post("/domains/named-feed/sessions", json={"strategy": "guide", "kappa": 0})
    sid, token = made.json()["session_id"], made.json()["token"]
    auth = {"Authorization": f"Bearer {token}"}
    moved = client.post(f"/sessions/{sid}/events", json={"state": [5, 1], "action": "S"},
                        headers=auth)  # fmt: skip
    assert moved.status_code == 200 and moved.json()["advise"]
    snap = remote(client)()
    grid = snap.domains["named-feed"].domain
    assert grid.goal_names == ("Lobby", "Exit")
    assert [grid.goal_label(i) for i in range(2)] == ["Lobby", "Exit"]
    view = next(s for s in snap.sessions if s.session_id == sid)
    assert [(f.name, f.symbol) for f in view.figures] == [
        ("looks lost", "P(lost|H)"), ("on its way", "P(M1|H)"), ("takes the advice", "P(take)"),
    ]  # fmt: skip
    assert view.leads_to is not None
    assert view.leads_to.name == ("Lobby", "Exit")[view.leads_to.goal]
    assert view.leads_to.label == f"{view.leads_to.name} (G{view.leads_to.goal})"
    said = moved.json()["leads_to"]  # the decision's own
    assert view.leads_to == (said["goal"], tuple(said["cell"]), said["name"])


TOWER = generate_floors(20, 20, 2, np.random.default_rng(3), n_goals=3, purpose="hospital")


def test_feed_rebuilds_a_building_with_its_prior_and_sessions(client: TestClient) -> None:
    """A map of several floors comes back as the Building that was put (floors, connections,
    destinations' names), its prior (S, 6) in state order, its sessions' cells [floor, row,
    col] and their advice over six actions; the one-floor domain is read as before."""
    admin = {"X-API-Key": ADMIN}
    body = {"text": TOWER.to_text(), "experts": {"per_goal": 2}}
    assert client.put("/domains/tower-feed", json=body, headers=admin).status_code == 201
    lift = TOWER.connections[0].stops[1]  # the lift's stop upstairs
    made = client.post("/domains/tower-feed/sessions", json={"kappa": 0.0, "start": list(lift)})
    assert made.status_code == 201, made.text
    sid, auth = made.json()["session_id"], {"Authorization": f"Bearer {made.json()['token']}"}
    moved = client.post(f"/sessions/{sid}/events", json={"state": list(lift), "action": "D"},
                        headers=auth)  # fmt: skip
    assert moved.status_code == 200 and moved.json()["state"] == list(TOWER.connections[0].stops[0])
    feed = remote(client)
    snap = feed()
    view = snap.domains["tower-feed"]
    building = view.domain
    assert isinstance(building, Building) and building.name == "tower-feed"
    assert building.to_text() == TOWER.to_text()
    assert building.goal_names == TOWER.goal_names and building.n_actions == 6
    prior = np.array(
        [[[v if v is not None else [np.nan] * 6 for v in row] for row in floor]
         for floor in client.get("/domains/tower-feed/prior").json()["theta"]]
    )  # fmt: skip
    assert view.theta.shape == (TOWER.n_states, 6)
    cells = building.cells
    np.testing.assert_allclose(view.theta, prior[cells[:, 0], cells[:, 1], cells[:, 2]], rtol=1e-12)
    mine = next(s for s in snap.sessions if s.session_id == sid)
    assert mine.path == [lift, TOWER.connections[0].stops[0]]
    assert mine.position == TOWER.connections[0].stops[0]
    assert [cell for _, cell, _ in mine.advice] == mine.path
    assert all(len(p) == 6 and sum(p) == pytest.approx(1.0) for _, _, p in mine.advice)
    assert isinstance(snap.domains["default"].domain, GridDomain)
    assert feed().domains["tower-feed"] is view  # nothing changed: not fetched again


def test_building_of_reads_the_frame_and_leaves_unnamed_goals_unnamed() -> None:
    floors = [(-1, "Basement", None, ["S.#", "..G"]), (0, "Hall", 0.0, ["..#", "G.."])]
    steps = {"kind": "stairs", "name": "Steps", "cost": 3, "stops": [[0, 0, 1], [1, 0, 1]]}
    info = {
        "floors": [
            {"index": i, "ordinal": o, "name": n, "elevation": e, "map": m}
            for i, (o, n, e, m) in enumerate(floors)
        ],
        "connections": [steps],
        "goals": [[0, 1, 2], [1, 1, 0]],
        "goal_names": [None, "Desk"],
        "resolution": 0.5,
        "origin": [1.0, 2.0, 0.0],
    }  # fmt: skip
    b = building_of(info, "small")
    assert b.frame == Frame(0.5, (1.0, 2.0, 0.0))
    assert b.goal_names == (None, "Desk") and [f.ordinal for f in b.floors] == [-1, 0]
    assert b.connections[0].stops == ((0, 0, 1), (1, 0, 1))
    with pytest.raises(MapError):
        building_of({**info, "goals": [[0, 0, 2]], "goal_names": ["Wall"]}, "bad")
