"""Hostile input against the real server (uvicorn's HTTP and websocket stack, default limits):
each is a 4xx whose detail names the problem, and nothing of it is stored.

What tests/service already covers is not repeated here: bad events one by one and over the
websocket (test_events.py, test_stream.py: walls, off-map cells, non-adjacent moves, bad
actions, ambiguous bumps), NaN/inf/negative kappa and bad windows (test_routes_sessions.py),
bad trajectories and the step limit (test_routes_domains.py), garbage to every route
(test_garbage.py: status < 500 only).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
from collections.abc import Iterator
from typing import Any
from urllib.parse import quote

import httpx
import pytest
import websockets

from app.service.data.domains import DomainCatalog
from app.service.data.store import Store
from tests.client.test_client import run_async
from tests.reliability.conftest import Live, server_errors
from tests.service.conftest import TINY

LIMIT = 2 * 1024 * 1024  # Settings.max_body_bytes
MAX_EVENTS = 5000  # Settings.max_batch_events
JSON = {"Content-Type": "application/json"}
PATTERN = "String should match pattern"
E = {"state": [5, 1], "action": "E"}


@pytest.fixture(scope="module")
def http(live: Live) -> Iterator[httpx.Client]:
    with httpx.Client(base_url=live.url, timeout=30) as client:
        r = client.put("/domains/tiny", json={"map": TINY, "alpha0": 0.5}, headers=live.admin)
        assert r.status_code in (200, 201), r.text
        yield client
    assert server_errors(live) == []


def session(http: httpx.Client, domain: str = "tiny") -> tuple[str, dict[str, str], str]:
    r = http.post(f"/domains/{domain}/sessions", json={})
    assert r.status_code == 201, r.text
    body = r.json()
    return body["session_id"], {"Authorization": f"Bearer {body['token']}"}, body["token"]


def refused(r: httpx.Response, status: int, *words: str) -> str:
    """Assert the status and that the detail says each of ``words``; the detail."""
    assert r.status_code == status, (r.status_code, r.text[:300])
    detail: str = r.json()["detail"]
    for word in words:
        assert word in detail, (word, detail)
    return detail


def body_routes(http: httpx.Client, live: Live) -> list[tuple[str, str, dict[str, str]]]:
    sid, auth, _ = session(http)
    return [
        ("PUT", "/domains/tiny", live.admin),
        ("POST", "/domains/tiny/trajectories", live.admin),
        ("POST", "/domains/tiny/sessions", {}),
        ("POST", f"/sessions/{sid}/events", auth),
    ]


def test_oversize_bodies_are_413_with_or_without_content_length(
    http: httpx.Client, live: Live
) -> None:
    big = b'{"map": ["' + b"." * (LIMIT + 10) + b'"]}'

    def chunked() -> Iterator[bytes]:  # no Content-Length: counted as it arrives
        for i in range(0, len(big), 256 * 1024):
            yield big[i : i + 256 * 1024]

    for method, path, headers in body_routes(http, live):
        for content in (big, chunked()):
            r = http.request(method, path, content=content, headers=headers | JSON)
            refused(r, 413, f"larger than {LIMIT} bytes")
    assert http.get("/domains/tiny").json()["map"] == TINY


def test_deeply_nested_json_is_refused_saying_so(http: httpx.Client, live: Live) -> None:
    deep = "[" * 50_000 + "]" * 50_000
    parsed_by_fastapi = {"/domains/tiny/sessions"}  # PUT reads its body itself (JSON or a file)
    for method, path, headers in body_routes(http, live):
        r = http.request(method, path, content=deep, headers=headers | JSON)
        if path in parsed_by_fastapi:
            refused(r, 400, "nested too deeply")
        else:  # parsed by pydantic-core, whose limit names itself
            refused(r, 422, "recursion limit exceeded")
    sid, _, token = session(http)

    async def frames() -> dict[str, Any]:
        async with websockets.connect(f"{ws_url(live)}/sessions/{sid}/stream?token={token}") as ws:
            await ws.send(deep)
            answer: dict[str, Any] = json.loads(await ws.recv())
            await ws.send(json.dumps(E))  # the stream stays usable
            assert json.loads(await ws.recv())["step"] == 1
            return answer

    error = run_async(frames())
    assert error["status"] == 422 and "recursion limit exceeded" in error["detail"]


def test_not_utf8_bodies_are_refused_saying_so(http: httpx.Client, live: Live) -> None:
    r = http.put("/domains/tiny", content=b'{"map": ["S\xff.G"]}', headers=live.admin | JSON)
    refused(r, 422, "invalid unicode code point")
    sid, auth, _ = session(http)
    r = http.post(f"/sessions/{sid}/events", content=b'{"state": "\xff"}', headers=auth | JSON)
    refused(r, 422, "invalid unicode code point")


def ws_url(live: Live) -> str:
    return live.url.replace("http://", "ws://")


def test_giant_batches_are_413_and_change_nothing(http: httpx.Client, live: Live) -> None:
    sid, auth, token = session(http)
    batch = [E, {"state": [5, 2], "action": "W"}] * (MAX_EVENTS // 2) + [E]
    r = http.post(f"/sessions/{sid}/events", json=batch, headers=auth)
    refused(r, 413, f"too many events: {MAX_EVENTS + 1} in one batch, at most {MAX_EVENTS}")
    # a trajectory batch over the byte limit (the step limit is further than that at defaults)
    steps = [{"state": [5, 1], "action": "E"}, {"state": [5, 2], "action": "W"}] * 40_000
    r = http.post(
        "/domains/tiny/trajectories",
        json={"trajectories": [{"steps": steps}]},
        headers=live.admin,
    )
    refused(r, 413, f"larger than {LIMIT} bytes")
    assert http.get("/domains/tiny").json()["trajectories"] == 0

    async def frames() -> tuple[dict[str, Any], str]:
        url = f"{ws_url(live)}/sessions/{sid}/stream?token={token}"
        ws = await websockets.connect(url, max_size=None)
        try:
            await ws.send(json.dumps(batch))
            too_many: dict[str, Any] = json.loads(await ws.recv())
            # far over the frame limit: uvicorn closes the connection (1009, message too big)
            # as soon as it reads the frame's length, without reading the rest, so the close
            # frame may be overtaken by a reset while this end is still sending
            try:
                await ws.send(" " * (LIMIT + 64 * 1024))
                answer = await asyncio.wait_for(ws.recv(), 10)
            except websockets.ConnectionClosed as closed:
                code = closed.rcvd.code if closed.rcvd else "no close frame"
                return too_many, f"closed {code}"
            except OSError as exc:
                return too_many, f"reset ({type(exc).__name__})"
            return too_many, f"answered {str(answer)[:100]}"
        finally:
            with contextlib.suppress(Exception):
                await ws.close()

    too_many, outcome = run_async(frames())
    assert too_many["status"] == 413 and f"at most {MAX_EVENTS}" in too_many["detail"]
    assert outcome in ("closed 1009", "closed no close frame") or outcome.startswith("reset")
    assert http.get(f"/sessions/{sid}", headers=auth).json()["steps"] == 0


@pytest.mark.parametrize(
    ("raw", "words"),
    [
        ("1e308", ["alpha0", "less than or equal to 1000000"]),  # was: 500, and a poisoned db
        ("9.4e307", ["alpha0", "less than or equal to 1000000"]),
        ("1e7", ["alpha0", "less than or equal to 1000000"]),
        ("5e-324", ["alpha0", "greater than or equal to 0.000001"]),  # theta underflows to 0
        ("1e-7", ["alpha0", "greater than or equal to 0.000001"]),
        ("0", ["alpha0", "greater than or equal to 0.000001"]),
        ("-1", ["alpha0", "greater than or equal to 0.000001"]),
        ("NaN", ["alpha0", "finite number"]),
        ("-Infinity", ["alpha0", "finite number"]),
        ("true", ["alpha0", "valid number"]),
        ('"1"', ["alpha0", "valid number"]),
        ("null", ["alpha0", "valid number"]),
    ],
)
def test_alpha0_out_of_range_is_refused_and_never_stored(
    http: httpx.Client, live: Live, raw: str, words: list[str]
) -> None:
    body = f'{{"map": {json.dumps(TINY)}, "alpha0": {raw}}}'
    for name in ("tiny", "fresh"):  # replacing a domain, and creating one
        r = http.put(f"/domains/{name}", content=body, headers=live.admin | JSON)
        refused(r, 422, *words)
    assert http.get("/domains/tiny").json()["alpha0"] == 0.5
    assert http.get("/domains/fresh").status_code == 404
    # what a restart would load: every stored domain builds (a bad alpha0 used to stop it)
    store = Store(f"sqlite:///{live.data_dir / 'advisor.db'}")
    try:
        catalog = DomainCatalog(store, 250_000)
        catalog.load()
        assert catalog.get("tiny").view.alpha0 == 0.5
    finally:
        store.close()


@pytest.mark.parametrize(
    ("raw", "words"),
    [
        ('{"kappa": null}', ["kappa", "valid number"]),
        ('{"kappa": []}', ["kappa", "valid number"]),
        ('{"kappa": true}', ["kappa", "valid number"]),
        ('{"kappa": -1e308}', ["kappa", "greater than or equal to 0"]),
        ('{"window": 1000000000000000000000000000000}', ["window", "larger than this service"]),
        ('{"window": -9223372036854775809}', ["window", "greater than or equal to 1"]),
        ('{"window": 1.5e3}', ["window", "valid integer"]),
        ('{"window": null}', ["window", "valid integer"]),
        ('{"window": "300"}', ["window", "valid integer"]),
    ],
)
def test_odd_kappa_and_window_values_are_refused(
    http: httpx.Client, raw: str, words: list[str]
) -> None:
    refused(http.post("/domains/tiny/sessions", content=raw, headers=JSON), 422, *words)


ODD = [
    "d\u0435fault",  # Cyrillic e: looks like "default"
    "\uff44efault",  # fullwidth d
    "\u202eevil",  # right-to-left override
    "x\u200by",  # zero-width space
    "caf\u00e9",
    "\U0001f600",
    "a\x00b",
    "a b",
    ".hidden",
    "a" * 65,
]


@pytest.mark.parametrize("name", ODD)
def test_odd_unicode_in_names_is_422_naming_the_field(
    http: httpx.Client, live: Live, name: str
) -> None:
    quoted = "/domains/" + quote(name, safe="")
    before = [d["name"] for d in http.get("/domains").json()]
    for method, suffix, headers in [
        ("GET", "", {}),
        ("PUT", "", live.admin),
        ("DELETE", "", live.admin),
        ("POST", "/sessions", {}),
        ("GET", "/prior", {}),
    ]:
        body = {"map": TINY} if method == "PUT" else None
        r = http.request(method, quoted + suffix, json=body, headers=headers)
        refused(r, 422, "name", PATTERN)
    _, auth, _ = session(http)
    refused(http.get("/domains/tiny/prior", params={"agent_type": name}), 422, "agent_type")
    refused(http.post("/domains/tiny/sessions", json={"agent_type": name}), 422, "agent_type")
    traj = {"trajectories": [{"agent_type": name, "steps": [E]}]}
    r = http.post("/domains/tiny/trajectories", json=traj, headers=live.admin)
    refused(r, 422, "trajectories[0].agent_type", PATTERN)
    r = http.post(f"/sessions/{quoted.rsplit('/', 1)[1]}/events", json=E, headers=auth)
    refused(r, 422, "session_id", PATTERN)
    assert [d["name"] for d in http.get("/domains").json()] == before
    assert http.get("/domains/tiny").json()["agent_types"] == []


def test_an_unknown_but_valid_agent_type_is_served_the_pooled_prior(http: httpx.Client) -> None:
    """Not an error, by design: a type without data of its own uses the pooled prior."""
    r = http.get("/domains/tiny/prior", params={"agent_type": "martian"})
    assert r.status_code == 200 and r.json()["table"] == "*"
    r = http.post("/domains/tiny/sessions", json={"agent_type": "martian"})
    assert r.status_code == 201 and r.json()["prior_table"] == "*"


@pytest.mark.parametrize(
    ("row", "words"),
    [
        ("#S\u2603G#", ["line 2, column 3", "unknown character"]),
        ("#S\u200bG#", ["line 2, column 3", "unknown character", "\\u200b"]),
        ("#S\x00G#", ["line 2, column 3", "unknown character", "\\x00"]),
        ("#S\u202eG#", ["line 2, column 3", "unknown character"]),
        ("#S\u00a0G#", ["line 2, column 3", "unknown character"]),  # no-break space
    ],
)
def test_odd_unicode_in_maps_is_422_naming_line_and_column(
    http: httpx.Client, live: Live, row: str, words: list[str]
) -> None:
    r = http.put("/domains/odd", json={"map": ["#####", row, "#####"]}, headers=live.admin)
    refused(r, 422, "map:", *words)
    assert http.get("/domains/odd").status_code == 404
