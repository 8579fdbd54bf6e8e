"""Public read-only routes: /health, /overview (no tokens), / and /walk, /static."""

from __future__ import annotations

from pathlib import Path

from fastapi.testclient import TestClient

from app.service.main import create_app
from app.service.state import ServiceState
from tests.service.conftest import make_settings, open_session


def test_health(client: TestClient) -> None:
    r = client.get("/health")
    assert r.status_code == 200
    body = r.json()
    assert body["status"] == "ok" and body["database"] == "sqlite"
    assert body["domains"] == 1 and body["sessions"] == 0 and body["uptime_seconds"] >= 0
    head = client.head("/health")  # load balancers and probes ask HEAD
    assert head.status_code == 200 and head.content == b""


def test_overview_shows_figures_and_never_tokens(client: TestClient, service: ServiceState) -> None:
    sid, auth, created = open_session(client, kappa=0.0)
    moves = [{"state": [28, 0], "action": "E"}, {"state": [28, 1], "action": "W"}] * 60
    client.post(f"/sessions/{sid}/events", json=moves, headers=auth)
    open_session(client)
    operator = {"X-API-Key": service.operator_key}
    r = client.get("/overview", headers=operator)
    assert r.status_code == 200
    assert created["token"] not in r.text
    body = r.json()
    assert body["total_sessions"] == 2 and body["detail"] is True
    assert body["domains"] == [
        {"name": "default", "rows": 30, "cols": 30, "n_states": body["domains"][0]["n_states"],
         "trajectories": 16, "sessions": 2, "steps": 120, "advice_count": 121,
         "advice_per_100": 100.0 * 121 / 122, "looking_lost": body["domains"][0]["looking_lost"]}
    ]  # fmt: skip
    s = next(x for x in body["sessions"] if x["session_id"] == sid)
    assert s["steps"] == 120 and s["position"] == [28, 0] and s["advice_count"] == 121
    assert len(s["path"]) == 100 and s["path"][-2:] == [[28, 1], [28, 0]]
    assert len(s["p_normal_history"]) == 120 + 1  # start + every step, under the 200 kept
    assert s["last_advice"]["step"] == 120 and s["last_advice"]["state"] == [28, 0]
    assert set(s["last_advice"]["advice"]) == {"N", "E", "S", "W"}
    r = client.get("/overview", params={"limit": 1}, headers=operator)
    assert len(r.json()["sessions"]) == 1 and r.json()["total_sessions"] == 2


def test_overview_without_an_operator_key_shows_figures_per_domain_only(
    client: TestClient, service: ServiceState
) -> None:
    sid, auth, _ = open_session(client)
    client.post(f"/sessions/{sid}/events", json={"state": [28, 0], "action": "E"}, headers=auth)
    r = client.get("/overview")
    assert r.status_code == 200
    body = r.json()
    assert body["detail"] is False and body["sessions"] == [] and body["total_sessions"] == 1
    assert body["domains"][0]["sessions"] == 1 and body["domains"][0]["steps"] == 1
    assert sid not in r.text and "path" not in r.text and "position" not in r.text
    r = client.get("/overview", headers={"X-API-Key": "not-a-key"})
    assert r.status_code == 403 and "operator key" in r.json()["detail"]
    admin = client.get("/overview", headers={"X-API-Key": service.admin_key}).json()
    assert admin["detail"] is True and admin["sessions"][0]["session_id"] == sid


def test_pages_are_404_json_when_not_installed(client: TestClient) -> None:
    for path in ("/", "/walk"):
        r = client.get(path)
        assert r.status_code == 404
        assert "not installed" in r.json()["detail"]
    assert client.get("/static/app.js").status_code == 404


def test_pages_and_static_files_are_served(tmp_path: Path) -> None:
    static = tmp_path / "static"
    static.mkdir()
    (static / "index.html").write_text("<h1>dashboard</h1>")
    (static / "walk.html").write_text("<h1>walk</h1>")
    (static / "app.js").write_text("let x = 1;")
    with TestClient(create_app(make_settings(tmp_path / "data", static_dir=static))) as client:
        r = client.get("/")
        assert r.status_code == 200 and "dashboard" in r.text
        assert r.headers["content-type"].startswith("text/html")
        assert client.get("/walk").text == "<h1>walk</h1>"
        assert client.get("/static/app.js").text == "let x = 1;"
        assert client.get("/static/../config.py").status_code == 404


def test_overview_says_which_key_asked_so_the_dashboard_offers_what_it_may_do(
    client: TestClient, service: ServiceState
) -> None:
    """The admin key may end sessions, the operator key only read them: the answer says
    which (and answers for one key are never served to the other from the cache)."""
    open_session(client)
    operator = client.get("/overview", headers={"X-API-Key": service.operator_key}).json()
    admin = client.get("/overview", headers={"X-API-Key": service.admin_key}).json()
    anyone = client.get("/overview").json()
    assert (operator["role"], admin["role"], anyone["role"]) == ("operator", "admin", None)
    assert operator["detail"] and admin["detail"] and not anyone["detail"]
