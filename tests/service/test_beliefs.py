"""What an advisor believes, in plain words: every session answer carries its strategy's
reading (figures with a name, a symbol and a tone; the destination its advice leads to), and
guide's one-event decisions name the destination their advice leads to."""

from __future__ import annotations

import json
from typing import Any

import pytest
from fastapi.testclient import TestClient

from app.domain.grid import GridDomain
from app.service.state import ServiceState
from tests.service.conftest import TINY, open_session

#: TINY with its two destinations, [1, 1] and [1, 5]; the second named
NAMED = "destination: 1 5 Café (east)\n" + "\n".join(TINY)
GRID = GridDomain.from_text(NAMED)
PAPER_FIGURES = ("moves like someone who knows the building", "P(M1|H)"), ("looks lost", "P(M2|H)")


@pytest.fixture
def named(client: TestClient, admin: dict[str, str]) -> str:
    r = client.put("/domains/named?experts=start&per_goal=3", content=NAMED,
                   headers=admin | {"Content-Type": "text/plain"})  # fmt: skip
    assert r.status_code == 201, r.text
    return "named"


def event(client: TestClient, sid: str, auth: dict[str, str], cell: list[int], a: str) -> Any:
    r = client.post(f"/sessions/{sid}/events", json={"state": cell, "action": a}, headers=auth)
    assert r.status_code == 200, r.text
    return r.json()


def summary(client: TestClient, sid: str, auth: dict[str, str]) -> dict[str, Any]:
    """GET /sessions/{id} with the session's token."""
    r = client.get(f"/sessions/{sid}", headers=auth)
    assert r.status_code == 200, r.text
    body: dict[str, Any] = r.json()
    return body


def test_a_paper_session_believes_the_paper_s_two_figures(client: TestClient) -> None:
    sid, auth, created = open_session(client)
    assert "leads_to" not in created["decision"]  # the paper's answers as they were
    d = event(client, sid, auth, created["decision"]["state"], "E")
    assert "leads_to" not in d
    seen = summary(client, sid, auth)
    p = seen["p_normal"]
    got = seen["beliefs"]
    assert [(f["name"], f["symbol"]) for f in got["figures"]] == list(PAPER_FIGURES)
    assert [f["p"] for f in got["figures"]] == [p, 1.0 - p]
    assert got["leads_to"] is None
    tone = "good" if p >= 0.5 else "bad"
    assert got["headline"] == (0 if p >= 0.5 else 1)
    assert got["figures"][got["headline"]]["tone"] == tone


def test_a_paper_session_that_looks_lost_reads_bad(client: TestClient) -> None:
    sid, auth, created = open_session(client)
    cell = created["decision"]["state"]
    for a in "SSWWSSWWSSWW":  # into the walls of the start's corner
        cell = event(client, sid, auth, cell, a)["state"]
    got = summary(client, sid, auth)
    assert got["p_normal"] < 0.5
    lost = got["beliefs"]["figures"][got["beliefs"]["headline"]]
    assert (lost["name"], lost["symbol"], lost["tone"]) == ("looks lost", "P(M2|H)", "bad")


def led_walk(
    client: TestClient, domain: str, moves: int, bumps: int = 6, **body: Any
) -> tuple[str, dict[str, str], list[dict[str, Any]]]:
    """A guide session (kappa 0: advice wherever it helps, a piece in four decisions at most)
    whose walker bumps into walls for its first ``bumps`` moves, then follows the advice it
    is given: (id, auth, every one-event answer)."""
    sid, auth, created = open_session(client, domain, strategy="guide", kappa=0.0, **body)
    answers = [created["decision"]]
    cell = created["decision"]["state"]
    for i in range(moves):
        last = answers[-1]
        if i < bumps or not last["advise"]:
            a = "SW"[i % 2]  # the start [5, 1] has walls south and west
        else:
            a = max("NESW", key=lambda k: last["advice"][k])
        answers.append(event(client, sid, auth, cell, a))
        cell = answers[-1]["state"]
    return sid, auth, answers


def test_guide_s_decisions_name_the_destination_their_advice_leads_to(
    client: TestClient, named: str
) -> None:
    sid, auth, answers = led_walk(client, named, 12)
    advised = [d for d in answers if d["advise"]]
    assert advised, "guide at kappa 0 advised nothing"
    for d in answers:
        assert ("leads_to" in d) == d["advise"]  # only advice leads somewhere
    for d in advised:
        goal = d["leads_to"]["goal"]
        assert d["leads_to"]["cell"] == list(GRID.goal_cells[goal])
        assert d["leads_to"]["name"] == GRID.goal_names[goal]  # type: ignore[index]
    seen = summary(client, sid, auth)["beliefs"]
    assert seen["leads_to"] == advised[-1]["leads_to"]


def test_guide_reads_a_lost_walker_it_leads_as_neutral_and_one_it_cannot_as_bad(
    client: TestClient, named: str
) -> None:
    sid, auth, answers = led_walk(client, named, 24, bumps=22)
    seen = summary(client, sid, auth)
    p = seen["p_normal"]
    got = seen["beliefs"]
    assert [(f["name"], f["symbol"]) for f in got["figures"]] == [
        ("looks lost", "P(lost|H)"), ("on its way", "P(M1|H)"), ("takes the advice", "P(take)"),
    ]  # fmt: skip
    assert [f["p"] for f in got["figures"][:2]] == [pytest.approx(1.0 - p), p]
    # it walked into walls whatever the advice: guide has learned that it ignores advice
    assert got["figures"][2]["p"] < 0.25 and got["figures"][2]["tone"] == "neutral"
    assert p < 0.5, "the walker bumped into walls: guide should think it lost"
    assert got["headline"] == 0
    assert {f["tone"] for f in got["figures"][:2]} == {"neutral"}  # being led, not red
    # muted, guide cannot lead it: now it reads bad
    assert client.post(f"/sessions/{sid}/mute", headers=auth).status_code == 200
    event(client, sid, auth, answers[-1]["state"], "S")
    muted = summary(client, sid, auth)["beliefs"]
    assert muted["figures"][muted["headline"]]["tone"] == "bad"


def test_guide_reads_a_walker_on_its_way_as_good(client: TestClient, named: str) -> None:
    """A walker that walks a shortest path to the named destination, [1, 5]."""
    sid, auth, created = open_session(client, named, strategy="guide", kappa=0.0)
    cell = created["decision"]["state"]
    for a in "EEENEE":  # [5, 1] -> [5, 4] -> [4, 4] ... on the way to [1, 5]
        cell = event(client, sid, auth, cell, a)["state"]
    got = summary(client, sid, auth)
    assert got["p_normal"] >= 0.5
    headline = got["beliefs"]["figures"][got["beliefs"]["headline"]]
    assert (headline["name"], headline["tone"]) == ("on its way", "good")


def test_a_websocket_s_one_event_answer_names_the_destination_and_a_binary_frame_does_not(
    client: TestClient, named: str
) -> None:
    sid, auth, created = open_session(client, named, strategy="guide", kappa=0.0)
    token = auth["Authorization"].removeprefix("Bearer ")
    cell = created["decision"]["state"]
    with client.websocket_connect(f"/sessions/{sid}/stream?token={token}") as ws:
        ws.send_text(json.dumps({"state": cell, "action": "S"}))
        one = json.loads(ws.receive_text())
        ws.send_text(json.dumps([{"state": one["state"], "action": "W"}]))
        batch = json.loads(ws.receive_text())
    assert one["advise"] and one["leads_to"]["cell"] in [list(c) for c in GRID.goal_cells]
    assert "leads_to" not in batch[0]  # a batch's decisions: the session's beliefs say it


def test_the_overview_and_the_viewer_feed_carry_the_beliefs_and_the_key_s_role(
    client: TestClient, service: ServiceState, admin: dict[str, str], named: str
) -> None:
    sid, auth, _ = led_walk(client, named, 8)
    own = summary(client, sid, auth)["beliefs"]
    operator = {"X-API-Key": service.operator_key}
    listed = client.get("/overview", headers=operator).json()
    assert listed["role"] == "operator"
    mine = next(s for s in listed["sessions"] if s["session_id"] == sid)
    assert mine["beliefs"] == own
    assert client.get("/overview", headers=admin).json()["role"] == "admin"
    anyone = client.get("/overview").json()
    assert anyone["role"] is None and anyone["sessions"] == []
    snap = client.get("/viewer/snapshot", headers=operator).json()
    assert next(s for s in snap["sessions"] if s["session_id"] == sid)["beliefs"] == own
