"""The protocol's edges over the real server (the issue: kappa 1e308 with ``always`` answered
``"total": Infinity``; session creation and domain PUT without a JSON Content-Type answered 422
"Input should be a valid dictionary" while events and trajectories took text/plain; a
5,000-digit window got a vague 400; the OpenAPI document stated none of the limits)."""

from __future__ import annotations

import json
import math
from typing import Any

import httpx
import pytest
from pydantic import BaseModel
from websockets.sync.client import connect

from app.domain.grid import GridDomain
from app.service.schemas import (
    DecisionPublic,
    DomainPublic,
    HealthPublic,
    Overview,
    PriorPublic,
    SessionCreated,
    SessionList,
    SessionPublic,
    ViewerSnapshot,
)
from app.strategies import names
from tests.reliability.conftest import Live
from tests.reliability.test_memory import walk

STRATEGIES = names()


def strict(text: str | bytes) -> Any:
    """JSON as the RFC has it: NaN, Infinity and -Infinity are not JSON."""

    def refuse(name: str) -> None:
        raise AssertionError(f"{name} in an answer: not JSON")

    return json.loads(text, parse_constant=refuse)


def checked(r: httpx.Response, model: type[BaseModel] | None, status: int = 200) -> Any:
    """The answer's JSON, strict, and (``model``) every number a number: pydantic refuses a
    null where its schema says number."""
    assert r.status_code == status, r.text
    body = strict(r.content)
    if model is not None:
        if isinstance(body, list):
            for item in body:
                model.model_validate(item)
        else:
            model.model_validate(body)
    return body


def test_every_answer_is_strict_json_at_the_largest_kappa(live: Live) -> None:
    """kappa 1e6 (the largest allowed: a larger one is refused at creation, since a total cost
    of kappa x advice count must stay finite), advice at every step, 5,000 events in a batch,
    every strategy: every figure finite on every route that answers them, the sessions' own
    read with the operator key (``/overview``, ``/viewer/snapshot``)."""
    with httpx.Client(base_url=live.url, timeout=60) as http:
        grid = GridDomain.from_strings(http.get("/domains/default").json()["map"])
        events = walk(grid, 5000, 3)
        made: dict[str, str] = {}
        for strategy in STRATEGIES:
            r = http.post("/domains/default/sessions", json={"kappa": 1e6, "strategy": strategy})
            created = checked(r, SessionCreated, 201)
            sid = created["session_id"]
            made[sid] = strategy
            auth = {"Authorization": f"Bearer {created['token']}"}
            checked(http.post(f"/sessions/{sid}/events", json=events[0], headers=auth),
                    DecisionPublic)  # fmt: skip
            checked(http.post(f"/sessions/{sid}/events", json=events[1:], headers=auth),
                    DecisionPublic)  # fmt: skip
            url = live.url.replace("http", "ws") + f"/sessions/{sid}/stream"
            with connect(url, additional_headers=auth, max_size=None) as ws:
                ws.send(json.dumps(events[:500]))
                for d in strict(ws.recv()):
                    DecisionPublic.model_validate(d)
            checked(http.get(f"/sessions/{sid}", headers=auth), SessionPublic)
            if strategy == "always":
                assert created["kappa"] == 1e6
                total = http.get(f"/sessions/{sid}", headers=auth).json()["total_cost"]
                assert total == 1e6 * 5501  # every decision advised, at 1e6 each
        checked(http.get("/overview", params={"limit": 1000}), Overview)  # figures only
        # the sessions' own figures, as the operator key reads them (the dashboard, the viewer)
        operator = {"X-API-Key": (live.data_dir / "operator_key").read_text().strip()}
        r = http.get("/overview", params={"limit": 1000}, headers=operator)
        listed = {s["session_id"]: s for s in checked(r, Overview)["sessions"]}
        snap = checked(http.get("/viewer/snapshot", headers=operator), ViewerSnapshot)
        drawn = {s["session_id"]: s for s in snap["sessions"]}
        for sid, strategy in made.items():
            for shown in (listed[sid], drawn[sid]):
                assert shown["strategy"] == strategy and shown["kappa"] == 1e6
                assert shown["steps"] == 5500 and math.isfinite(shown["total_cost"])
                if strategy == "always":
                    assert shown["total_cost"] == 1e6 * 5501
        checked(http.get("/sessions", headers=live.admin), SessionList)
        checked(http.get("/domains"), DomainPublic)
        checked(http.get("/domains/default/prior"), PriorPublic)
        checked(http.get("/health"), HealthPublic)
        r = http.post("/domains/default/sessions", json={"kappa": 1.1e6})
        assert r.status_code == 422 and "kappa" in r.json()["detail"]


STEPS = '{"trajectories": [{"steps": [{"state": [1, 1], "action": "E"}]}]}'
BODIES: list[tuple[str, str, str, bool]] = [  # method, path, body, needs the admin key
    ("POST", "/domains/default/sessions", "{}", False),
    ("PUT", "/domains/edge", '{"map": ["#####", "#S.G#", "#####"]}', True),
    ("POST", "/domains/edge/trajectories", STEPS, True),
]


@pytest.mark.parametrize("kind", ["text/plain", "application/x-www-form-urlencoded",
                                  "multipart/form-data; boundary=x"])  # fmt: skip
def test_a_body_that_is_not_json_is_415_on_every_route_but_a_map_file(
    live: Live, kind: str
) -> None:
    with httpx.Client(base_url=live.url, timeout=30) as http:
        created = http.post("/domains/default/sessions", json={}).json()
        auth = {"Authorization": f"Bearer {created['token']}"}
        sid = created["session_id"]
        session_routes = [
            ("POST", f"/sessions/{sid}/events", '{"state": [28, 0], "action": "E"}', auth),
            ("POST", f"/sessions/{sid}/positions", '{"positions": [[0.5, 0.5]]}', auth),
        ]
        routes = [(m, p, b, live.admin if a else {}) for m, p, b, a in BODIES] + session_routes
        for method, path, body, headers in routes:
            r = http.request(method, path, content=body, headers=headers | {"Content-Type": kind})
            detail = strict(r.content)["detail"]
            if kind == "text/plain" and method == "PUT":  # a map file's text goes there
                assert r.status_code == 422, (path, r.text)
                assert "this text/plain body is JSON" in detail
                assert "Content-Type: application/json" in detail
                continue
            assert r.status_code == 415, (path, r.text)
            assert "Content-Type: application/json" in detail
            if kind == "application/x-www-form-urlencoded":  # what curl -d sends
                assert "curl -d" in detail and "a form" in detail


def test_json_with_or_without_a_content_type_is_read_alike(live: Live) -> None:
    """Every body route reads JSON sent with ``application/json`` (parameters allowed) or with
    no Content-Type at all; none answers "Input should be a valid dictionary"."""
    with httpx.Client(base_url=live.url, timeout=30) as http:
        for kind in (None, "application/json", "application/json; charset=utf-8"):
            headers = {} if kind is None else {"Content-Type": kind}
            for method, path, body, admin in BODIES:
                r = http.request(method, path, content=body,
                                 headers=headers | (live.admin if admin else {}))  # fmt: skip
                assert r.status_code in (200, 201), (kind, path, r.text)


def test_numbers_of_thousands_of_digits_are_refused_saying_so(live: Live) -> None:
    big = "9" * 5000
    with httpx.Client(base_url=live.url, timeout=30) as http:
        r = http.post("/domains/default/sessions", content=f'{{"window": {big}}}')
        assert r.status_code == 422, r.text
        assert "more than 4300 digits" in strict(r.content)["detail"]
        created = http.post("/domains/default/sessions", json={}).json()
        auth = {"Authorization": f"Bearer {created['token']}"}
        r = http.post(f"/sessions/{created['session_id']}/events", headers=auth,
                      content=f'{{"state": [{big}, 0], "action": "E"}}')  # fmt: skip
        assert r.status_code == 422 and "number out of range" in strict(r.content)["detail"]


def test_the_openapi_document_states_the_enforced_limits(live: Live) -> None:
    doc = httpx.get(f"{live.url}/openapi.json").json()
    schemas = doc["components"]["schemas"]
    assert schemas["SessionCreate"]["properties"]["window"]["maximum"] == 10_000
    batch = [b for b in schemas["Events"]["anyOf"] if b.get("type") == "array"]
    assert batch[0]["maxItems"] == 5000
    map_doc = schemas["DomainPut"]["properties"]["map"]
    assert "250000 cells" in map_doc["description"] and map_doc["x-max-cells"] == 250_000
    assert "2097152" in map_doc["description"]
    assert "200000 steps" in schemas["TrajectoriesCreate"]["description"]
    assert "2097152 bytes" in doc["info"]["description"]
    r = httpx.post(f"{live.url}/domains/default/sessions", json={"window": 10_001})
    assert r.status_code == 422 and "10000" in r.json()["detail"]
    assert httpx.head(f"{live.url}/health").status_code == 200
