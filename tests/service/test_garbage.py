"""Garbage to every route, with every kind of credential: never a 5xx, always a JSON reason."""

from __future__ import annotations

import itertools
import re

from fastapi.testclient import TestClient

from app.service.state import ServiceState
from tests.service.conftest import open_session

BODIES = [
    b"", b"{", b"}", b"null", b"[]", b"{}", b'"x"', b"1e999", b"NaN", b"-Infinity",
    b"[" * 5000 + b"]" * 5000, b'{"a":' * 3000 + b"1" + b"}" * 3000, b"\xff\xfe\x00\x00",
    '{"map": ["S\u2603G"]}'.encode(), b'{"map": 5, "alpha0": "x"}', b'{"map": [], "alpha0": -1}',
    b'{"trajectories": "x"}', b'{"trajectories": [{"steps": [{"state": [1e308, -1]}]}]}',
    b'{"trajectories": [{"steps": [{"state": [99999999999999999999999, 0], "action": 7}]}]}',
    b'{"kappa": [], "window": {}, "start": "here"}', b'{"state": {"a": 1}, "action": null}',
    b'[{"state": [28, 0], "action": "E"}, 5, null]', b'{"state": [28, 0], "next_state": [28, 0]}',
    b"\x00" * 64, "\u202e\ufeff\U0001f600".encode(),
]  # fmt: skip
CONTRACT = {
    ("GET", "/health"), ("GET", "/health/live"), ("GET", "/health/ready"),
    ("GET", "/domains"), ("GET", "/domains/{name}"), ("PUT", "/domains/{name}"),
    ("DELETE", "/domains/{name}"), ("POST", "/domains/{name}/trajectories"),
    ("GET", "/domains/{name}/prior"), ("POST", "/domains/{name}/sessions"),
    ("POST", "/sessions/{session_id}/events"), ("POST", "/sessions/{session_id}/positions"),
    ("POST", "/sessions/{session_id}/mute"),
    ("GET", "/sessions/{session_id}"),
    ("DELETE", "/sessions/{session_id}"), ("GET", "/sessions"), ("GET", "/overview"),
    ("GET", "/viewer"),  # where the viser viewer runs (app/service/routes/viewer.py)
    ("GET", "/metrics"),  # Prometheus text (app/service/routes/metrics.py)
    ("GET", "/strategies"),  # the advising strategies (app/service/routes/strategies.py)
    ("GET", "/viewer/snapshot"),  # what the viewer process draws (operator key)
}  # fmt: skip
NAMES = ["default", "nowhere", "%E2%98%83", "a" * 100, "..", "%00"]


def _paths(template: str, session_id: str) -> list[str]:
    names = NAMES if "{name}" in template else ["default"]
    sids = [session_id, "0123456789abcdef", "x" * 80] if "{session_id}" in template else [""]
    return [
        template.replace("{name}", n).replace("{session_id}", s)
        for n, s in itertools.product(names, sids)
    ]


def test_garbage_to_every_route_never_gives_5xx(client: TestClient, service: ServiceState) -> None:
    sid, auth, _ = open_session(client)
    odd: dict[str, str | bytes] = {"Authorization": "Bearer n\u00f8pe".encode("latin-1")}
    credentials: list[dict[str, str | bytes]] = [
        {},
        {"X-API-Key": service.admin_key},
        {**auth},
        odd,
    ]
    routes = [
        (m.upper(), p)
        for p, ops in client.get("/openapi.json").json()["paths"].items()
        for m in ops
    ]
    assert len(routes) == len(CONTRACT)
    tried = 0
    for method, template in [*routes, ("GET", "/"), ("GET", "/walk")]:
        canonical, *others = _paths(template, sid)
        # every body on the live path (credentials in turn), then odd paths with each credential
        tries = [(canonical, body, credentials[i % 4]) for i, body in enumerate(BODIES)]
        tries += [(p, b"{}", c) for p in others for c in credentials]
        for path, body, headers in tries:
            r = client.request(method, path + "?limit=-1&agent_type=%00", content=body,
                               headers=headers | {"Content-Type": "application/json"})  # fmt: skip
            tried += 1
            assert r.status_code < 500, (method, path, body[:40], r.status_code, r.text[:200])
            if r.status_code >= 400:
                assert isinstance(r.json()["detail"], str) and r.json()["detail"]
    assert tried > 500


def test_unknown_routes_and_methods_are_json_4xx(client: TestClient) -> None:
    r = client.get("/no/such/route")
    assert r.status_code == 404 and r.json()["detail"]
    r = client.patch("/domains/default")
    assert r.status_code == 405 and r.json()["detail"]


def test_openapi_documents_every_route_of_the_contract(client: TestClient) -> None:
    schema = client.get("/openapi.json").json()
    documented = {(m.upper(), p) for p, ops in schema["paths"].items() for m in ops}
    assert documented == CONTRACT
    events = schema["paths"]["/sessions/{session_id}/events"]["post"]
    assert events["requestBody"]["content"]["application/json"]["schema"]["$ref"].endswith(
        "/Events"
    )
    assert {"Events", "EventIn", "TrajectoriesCreate", "StepIn"} <= set(
        schema["components"]["schemas"]
    )
    assert re.search(r"X-API-Key", str(schema["components"]["securitySchemes"]))
