"""Sessions and events over HTTP: every route, its errors and its credentials."""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest
from fastapi import FastAPI
from fastapi.routing import APIRoute
from fastapi.testclient import TestClient

from app.service.data.store import POOLED
from app.service.routes.sessions import EVENTS_PATH, DirectEvents
from app.service.state import ServiceState
from tests.service.conftest import open_session

E = {"state": [28, 0], "action": "E"}
JSON = {"Content-Type": "application/json"}


def test_create_session_defaults(client: TestClient) -> None:
    r = client.post("/domains/default/sessions")
    assert r.status_code == 201
    body = r.json()
    assert body["kappa"] == 0.5 and body["window"] == 300 and body["prior_table"] == POOLED
    assert len(body["token"]) >= 32 and body["session_id"] != body["token"]
    d = body["decision"]
    assert d["step"] == 0 and d["state"] == [28, 0] and d["p_normal"] == 0.5
    assert d["cost"] == {
        "advice_count": int(d["advise"]),
        "total": 0.5 * d["advise"],
        "benefit": d["kl"] * d["advise"],
    }


def test_create_session_with_options(client: TestClient) -> None:
    _, _, body = open_session(client, kappa=0.0, window=7, agent_type="visitor", start=[28, 3])
    assert (body["kappa"], body["window"], body["agent_type"]) == (0.0, 7, "visitor")
    assert body["prior_table"] == POOLED  # no visitor data yet: the pooled prior
    assert body["decision"]["state"] == [28, 3] and body["decision"]["advise"]  # kappa 0


@pytest.mark.parametrize(
    ("raw", "message"),
    [
        ('{"kappa": NaN}', "kappa: Input should be a finite number"),
        ('{"kappa": Infinity}', "kappa: Input should be a finite number"),
        ('{"kappa": 1e999}', "kappa: Input should be a finite number"),
        ('{"kappa": -0.1}', "kappa: Input should be greater than or equal to 0"),
        ('{"kappa": 1e308}', "kappa: Input should be less than or equal to 1000000"),
        ('{"kappa": "0.5"}', "kappa: Input should be a valid number"),
        ('{"window": 0}', "window: Input should be greater than or equal to 1"),
        ('{"window": -5}', "window: Input should be greater than or equal to 1"),
        ('{"window": 2.5}', "window: Input should be a valid integer"),
        ('{"window": true}', "window: Input should be a valid integer"),
        ('{"window": 1000000}', "window: 1000000 is larger than this service allows (10000)"),
        ('{"start": [27, 0]}', "start: cell [27, 0] is a wall"),
        ('{"start": [30, 0]}', "start: cell [30, 0] is off the 30x30 map"),
        ('{"agent_type": "\\u2603"}', "agent_type: String should match pattern"),
        ('{"colour": "red"}', "colour: Extra inputs are not permitted"),
        ('{"kappa": 0.5', "JSON decode error"),
        ("[1, 2]", "Input should be a valid dictionary"),
    ],
)
def test_create_session_refuses_bad_options(client: TestClient, raw: str, message: str) -> None:
    r = client.post("/domains/default/sessions", content=raw, headers=JSON)
    assert r.status_code == 422
    assert message in r.json()["detail"]


def test_create_session_in_an_unknown_domain_is_404(client: TestClient) -> None:
    assert client.post("/domains/nowhere/sessions").status_code == 404


def test_events_one_gets_one_decision_a_list_gets_a_list(client: TestClient) -> None:
    sid, auth, _ = open_session(client)
    r = client.post(f"/sessions/{sid}/events", json=E, headers=auth)
    assert r.status_code == 200
    one = r.json()
    assert one["step"] == 1 and one["state"] == [28, 1]
    assert set(one) == {"step", "state", "advise", "advice", "kl", "p_normal", "cost"}
    r = client.post(
        f"/sessions/{sid}/events", json=[{"state": [28, 1], "action": "W"}, E], headers=auth
    )
    assert r.status_code == 200
    assert [d["step"] for d in r.json()] == [2, 3] and r.json()[1]["state"] == [28, 1]
    r = client.post(f"/sessions/{sid}/events", json=[], headers=auth)
    assert r.status_code == 200 and r.json() == []


def test_events_advice_is_theta_where_advised(client: TestClient) -> None:
    sid, auth, _ = open_session(client, kappa=0.0)
    d = client.post(f"/sessions/{sid}/events", json=E, headers=auth).json()
    theta = client.get("/domains/default/prior").json()["theta"][28][1]
    assert d["advise"] and [d["advice"][a] for a in "NESW"] == theta


def test_events_a_refused_batch_changes_nothing(client: TestClient) -> None:
    sid, auth, _ = open_session(client)
    r = client.post(
        f"/sessions/{sid}/events", json=[E, E, {"state": [27, 0], "action": "N"}], headers=auth
    )
    assert r.status_code == 422
    assert r.json()["detail"] == "event 2: state [27, 0] is a wall"
    assert client.get(f"/sessions/{sid}", headers=auth).json()["steps"] == 0


def test_events_over_the_batch_limit_is_413(client: TestClient, service: ServiceState) -> None:
    service.settings.max_batch_events = 3
    sid, auth, _ = open_session(client)
    r = client.post(f"/sessions/{sid}/events", json=[E] * 4, headers=auth)
    assert r.status_code == 413
    assert "at most 3" in r.json()["detail"]


def test_session_routes_need_the_sessions_own_token(
    client: TestClient, admin: dict[str, str]
) -> None:
    sid, auth, _ = open_session(client)
    _, other, _ = open_session(client)
    for method, path, body in [
        ("POST", f"/sessions/{sid}/events", E),
        ("POST", f"/sessions/{sid}/positions", {"positions": [[0.5, 0.5]]}),
        ("GET", f"/sessions/{sid}", None),
        ("DELETE", f"/sessions/{sid}", None),
    ]:
        r = client.request(method, path, json=body)
        assert r.status_code == 401, path
        assert r.headers["WWW-Authenticate"] == "Bearer" and "Bearer" in r.json()["detail"]
        r = client.request(method, path, json=body, headers=other)
        assert r.status_code == 403, path
        assert "does not belong" in r.json()["detail"]
        r = client.request(method, path, json=body, headers={"Authorization": "Bearer nonsense"})
        assert r.status_code == 403, path
        r = client.request(method, path, json=body, headers={"Authorization": "Basic abc"})
        assert r.status_code == 401, path
    r = client.post(f"/sessions/{sid}/events", json=E, headers=admin)  # admin cannot act for it
    assert r.status_code == 401
    r = client.get("/sessions/0123456789abcdef", headers=auth)
    assert r.status_code == 404
    r = client.get("/sessions/bad%20id!", headers=auth)
    assert r.status_code == 422


def test_the_event_route_answers_as_fastapis_own_handler(client: TestClient) -> None:
    """The event route's direct handler against FastAPI's for the same requests: decisions,
    every error, every header that matters."""
    app: FastAPI = client.app  # type: ignore[assignment]
    route = next(r for r in app.routes if getattr(r, "path", "") == EVENTS_PATH)
    assert isinstance(route, APIRoute)
    direct = route.app
    assert isinstance(direct, DirectEvents)
    a, auth_a, _ = open_session(client)  # the same start: the same decisions
    b, auth_b, _ = open_session(client)
    _, other, _ = open_session(client)

    def both(request: Callable[[str, dict[str, str]], Any]) -> list[tuple[Any, ...]]:
        got = []
        for sid, auth, handler in ((a, auth_a, direct), (b, auth_b, direct.framework)):
            route.app = handler
            try:
                r = request(sid, auth)
            finally:
                route.app = direct
            kind, challenge = r.headers.get("content-type"), r.headers.get("www-authenticate")
            got.append((r.status_code, r.content.replace(sid.encode(), b"<id>"), kind, challenge))
        return got

    def post(body: Any, sid: str | None = None) -> Callable[[str, dict[str, str]], Any]:
        return lambda s, h: client.post(f"/sessions/{sid or s}/events", json=body, headers=h)

    walk = [E, [E, {"state": [28, 1], "action": "N"}], {"state": [28, 1], "action": "S"}]
    cases: list[Callable[[str, dict[str, str]], Any]] = [
        *(post(e) for e in walk),
        post(E | {"step": 2}),  # a retry
        post(E | {"step": 9}),  # out of turn: 409
        post({"state": [99, 0]}),  # off the map: 422
        post(E, "0123456789abcdef"),  # no such session: 404
        *(post(E, bad) for bad in ("bad.id", "a" * 65, "abc%0A", "%C3%A9t%C3%A9")),  # 422
        lambda s, h: client.post(f"/sessions/{s}/events", json=E),
        lambda s, h: client.post(f"/sessions/{s}/events", json=E, headers=other),
        lambda s, h: client.post(f"/sessions/{s}/events", json=E, headers={"Authorization": "x"}),
        lambda s, h: client.post(f"/sessions/{s}/events", content=b"{nope", headers=h | JSON),
        lambda s, h: client.post(f"/sessions/{s}/events", content=b"", headers=h),
        lambda s, h: client.post(
            f"/sessions/{s}/events", content=b"x=1", headers=h | {"Content-Type": "text/plain"}
        ),
        lambda s, h: client.get(f"/sessions/{s}/events", headers=h),
    ]
    answers = [both(case) for case in cases]
    for first, second in answers:
        assert first == second
    statuses = [first[0] for first, _ in answers]
    assert statuses[:12] == [200, 200, 200, 200, 409, 422, 404, 422, 422, 422, 422, 401]
    assert statuses[12:] == [403, 401, 422, 422, 415, 405]


def test_read_and_end_session(client: TestClient, admin: dict[str, str]) -> None:
    sid, auth, _ = open_session(client, kappa=0.0)
    client.post(
        f"/sessions/{sid}/events", json=[E, {"state": [28, 1], "action": "W"}], headers=auth
    )
    r = client.get(f"/sessions/{sid}", headers=auth)
    assert r.status_code == 200
    s = r.json()
    assert s["session_id"] == sid and s["steps"] == 2 and s["position"] == [28, 0]
    assert s["advice_count"] == 3 and s["total_cost"] == 0.0 and s["advice_per_100"] == 100.0
    assert "token" not in s
    assert client.get(f"/sessions/{sid}", headers=admin).status_code == 200  # admin may read
    r = client.delete(f"/sessions/{sid}", headers=auth)
    assert r.status_code == 200
    assert r.json()["steps"] == 2
    assert client.get(f"/sessions/{sid}", headers=auth).status_code == 404
    assert client.post(f"/sessions/{sid}/events", json=E, headers=auth).status_code == 404


def test_list_sessions_is_for_the_admin(client: TestClient, admin: dict[str, str]) -> None:
    open_session(client)
    sid, _, _ = open_session(client)
    assert client.get("/sessions").status_code == 401
    assert client.get("/sessions", headers={"X-API-Key": "x"}).status_code == 403
    r = client.get("/sessions", headers=admin)
    assert r.status_code == 200
    assert r.json()["total"] == 2 and r.json()["sessions"][0]["session_id"] == sid
    r = client.get("/sessions", params={"limit": 1, "domain": "default"}, headers=admin)
    assert r.json()["total"] == 2 and len(r.json()["sessions"]) == 1
    assert client.get("/sessions", params={"limit": 0}, headers=admin).status_code == 422


def test_sessions_beyond_the_maximum_get_503(client: TestClient, service: ServiceState) -> None:
    service.registry.max_sessions = 2
    sid, auth, _ = open_session(client)
    open_session(client)
    r = client.post("/domains/default/sessions")
    assert r.status_code == 503
    assert "maximum of 2 live sessions" in r.json()["detail"]
    client.delete(f"/sessions/{sid}", headers=auth)
    assert client.post("/domains/default/sessions").status_code == 201


def test_idle_sessions_expire(client: TestClient, service: ServiceState) -> None:
    sid, auth, _ = open_session(client)
    service.registry.idle_seconds = 1e-9  # everything is idle now
    assert service.registry.expire() == 1
    r = client.get(f"/sessions/{sid}", headers=auth)
    assert r.status_code == 404
    assert "expired" in r.json()["detail"]


def test_a_full_registry_first_drops_idle_sessions(
    client: TestClient, service: ServiceState
) -> None:
    service.registry.max_sessions = 1
    open_session(client)
    service.registry.idle_seconds = 1e-9
    assert client.post("/domains/default/sessions").status_code == 201


def test_explorer_events_never_change_the_prior(client: TestClient, service: ServiceState) -> None:
    before = client.get("/domains/default/prior").json()
    counts = service.store.counts("default")
    sid, auth, _ = open_session(client)
    rng = np.random.default_rng(0)
    events = [{"state": [28, 0], "action": "NESW"[int(a)]} for a in rng.integers(0, 4, 200)]
    assert client.post(f"/sessions/{sid}/events", json=events, headers=auth).status_code == 200
    assert client.get("/domains/default/prior").json() == before
    after = service.store.counts("default")
    assert all(np.array_equal(after[k].counts, counts[k].counts) for k in counts)


def test_bodies_over_the_size_limit_get_413(client: TestClient, service: ServiceState) -> None:
    sid, auth, _ = open_session(client)
    limit = service.settings.max_body_bytes
    big = json.dumps([E] * (limit // 20))
    r = client.post(f"/sessions/{sid}/events", content=big, headers=auth | JSON)
    assert r.status_code == 413
    assert f"larger than {limit} bytes" in r.json()["detail"]

    def chunks() -> Iterator[bytes]:  # no Content-Length: counted as it arrives
        yield big.encode()

    r = client.post(f"/sessions/{sid}/events", content=chunks(), headers=auth | JSON)
    assert r.status_code == 413


def test_the_largest_kappa_keeps_every_figure_a_finite_json_number(client: TestClient) -> None:
    """kappa 1e6 with the 'always' rule: the total cost grows with every event and stays a
    number JSON can carry (a larger kappa is refused, above)."""
    created = client.post(
        "/domains/default/sessions", json={"kappa": 1e6, "strategy": "always"}
    ).json()
    auth = {"Authorization": f"Bearer {created['token']}"}
    events = [{"state": created["decision"]["state"], "action": "W"}] * 50
    r = client.post(f"/sessions/{created['session_id']}/events", json=events, headers=auth)
    assert r.status_code == 200 and "Infinity" not in r.text
    assert r.json()[-1]["cost"]["total"] == 1e6 * 51
