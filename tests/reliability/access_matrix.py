"""The access matrix: every route of the service with every kind of credential, as the service
answers it. ``python -m tests.reliability.access_matrix --write docs/ACCESS.md`` writes it;
``tests/reliability/test_access.py`` checks that the service answers as the policy says and
that the document is up to date.

Every cell is one request to a fresh resource (a new session, a new domain name), so a cell
that deletes or ends something cannot change another cell's answer.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from fastapi.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

from app.service.config import REPO_ROOT
from app.service.main import create_app
from tests.service.conftest import TINY, make_settings

COLUMNS = {
    "none": "no credentials",
    "wrong": "a wrong key",
    "other": "another session's token",
    "admin": "admin key",
    "operator": "operator key",
    "own": "the session's own token",
}
E = {"state": [5, 1], "action": "E"}
TRAJECTORIES = {"trajectories": [{"steps": [E]}]}


@dataclass(frozen=True)
class Route:
    method: str
    path: str
    who: str  # a key of POLICY
    body: object = None


ROUTES = [
    Route("GET", "/health", "anyone"),
    Route("HEAD", "/health", "anyone"),
    Route("GET", "/health/live", "anyone"),
    Route("HEAD", "/health/live", "anyone"),
    Route("GET", "/health/ready", "anyone"),
    Route("HEAD", "/health/ready", "anyone"),
    Route("GET", "/domains", "anyone"),
    Route("GET", "/domains/{name}", "anyone"),
    Route("PUT", "/domains/{new}", "admin", {"map": TINY}),
    Route("DELETE", "/domains/{new}", "admin"),
    Route("POST", "/domains/{name}/trajectories", "admin", TRAJECTORIES),
    Route("GET", "/domains/{name}/prior", "anyone"),
    Route("POST", "/domains/{name}/sessions", "anyone", {}),
    Route("POST", "/sessions/{session_id}/events", "token", E),
    Route("POST", "/sessions/{session_id}/positions", "token", {"positions": [[2.5, 1.5]]}),
    Route("POST", "/sessions/{session_id}/mute", "token", {"muted": True}),
    Route("GET", "/sessions/{session_id}", "token or operator"),
    Route("DELETE", "/sessions/{session_id}", "token or admin"),
    Route("GET", "/sessions", "operator"),
    Route("WS", "/sessions/{session_id}/stream", "token"),
    Route("GET", "/overview", "anyone; sessions: operator"),
    Route("GET", "/viewer", "anyone"),
    Route("GET", "/metrics", "anyone"),
    Route("GET", "/strategies", "anyone"),
    Route("GET", "/viewer/snapshot", "operator"),
    Route("GET", "/", "anyone"),
    Route("GET", "/walk", "anyone"),
]
#: What each kind of route answers to each column ("ok": its success status).
POLICY = {
    "anyone": {"none": "ok", "wrong": "ok", "other": "ok", "admin": "ok", "operator": "ok",
               "own": "ok"},
    "admin": {"none": "401", "wrong": "403", "other": "401", "admin": "ok", "operator": "403",
              "own": "401"},
    "operator": {"none": "401", "wrong": "403", "other": "401", "admin": "ok", "operator": "ok",
                 "own": "401"},
    "token": {"none": "401", "wrong": "401", "other": "403", "admin": "401", "operator": "401",
              "own": "ok"},
    "token or admin": {"none": "401", "wrong": "403", "other": "403", "admin": "ok",
                       "operator": "403", "own": "ok"},
    "token or operator": {"none": "401", "wrong": "403", "other": "403", "admin": "ok",
                          "operator": "ok", "own": "ok"},
    # live sessions (where explorers are and were) for the admin and operator keys only
    "anyone; sessions: operator": {"none": "figures", "wrong": "403", "other": "figures",
                                   "admin": "sessions", "operator": "sessions",
                                   "own": "figures"},
}  # fmt: skip
#: A websocket refusal is a close code: 4400 + the HTTP status it stands for.
WS_CLOSE = {"401": "close 4401", "403": "close 4403"}


@dataclass
class Cell:
    """One measured answer: its status, and whether it is a success."""

    status: str
    ok: bool


class Service:
    """A fresh app (TestClient) on a temporary data directory, with helpers for fresh
    resources."""

    def __init__(self, client: TestClient):
        self.client = client
        self.admin_key: str = client.app.state.service.admin_key  # type: ignore[attr-defined]
        self.operator_key: str = client.app.state.service.operator_key  # type: ignore[attr-defined]
        self.counter = 0
        body = {"map": TINY, "resolution": 1.0}  # in metres too: positions are valid
        r = client.put("/domains/tiny", json=body, headers=self.admin)
        assert r.status_code == 201, r.text

    @property
    def admin(self) -> dict[str, str]:
        return {"X-API-Key": self.admin_key}

    def session(self) -> tuple[str, str]:
        r = self.client.post("/domains/tiny/sessions", json={})
        assert r.status_code == 201, r.text
        return r.json()["session_id"], r.json()["token"]

    def new_domain(self, create: bool) -> str:
        self.counter += 1
        name = f"fresh{self.counter}"
        if create:
            assert self.client.put(f"/domains/{name}", json={"map": TINY}, headers=self.admin)
        return name


@contextmanager
def service() -> Iterator[Service]:
    with tempfile.TemporaryDirectory() as tmp:
        settings = make_settings(Path(tmp) / "data", static_dir=REPO_ROOT / "static")
        with TestClient(create_app(settings)) as client:
            yield Service(client)


def headers(column: str, svc: Service, own: str, other: str) -> dict[str, str]:
    return {
        "none": {},
        "wrong": {"X-API-Key": "not-a-key-of-this-service"},
        "other": {"Authorization": f"Bearer {other}"},
        "admin": svc.admin,
        "operator": {"X-API-Key": svc.operator_key},
        "own": {"Authorization": f"Bearer {own}"},
    }[column]


def measure_cell(svc: Service, route: Route, column: str) -> Cell:
    sid, own = svc.session()
    _, other = svc.session()
    path = route.path.format(
        name="tiny", session_id=sid, new=svc.new_domain(create=route.method == "DELETE")
    )
    sent = headers(column, svc, own, other)
    if route.method == "WS":
        return _websocket(svc.client, path, sent)
    r = svc.client.request(
        route.method,
        path,
        content=None if route.body is None else json.dumps(route.body),
        headers=sent | ({"Content-Type": "application/json"} if route.body is not None else {}),
    )
    if r.is_success and route.path == "/overview":  # which view: live sessions or figures
        listed = r.json()["detail"] and r.json()["sessions"]
        return Cell("200 sessions" if listed else "200 figures", True)
    return Cell(str(r.status_code), r.is_success)


def _websocket(client: TestClient, path: str, sent: dict[str, str]) -> Cell:
    with client.websocket_connect(path, headers=sent) as ws:
        ws.send_text(json.dumps(E))
        try:
            answer = json.loads(ws.receive_text())
        except WebSocketDisconnect as closed:
            return Cell(f"close {closed.code}", False)
    assert answer["step"] == 1, answer
    return Cell("open", True)


Matrix = dict[tuple[str, str], dict[str, Cell]]


def measure() -> Matrix:
    with service() as svc:
        return {(r.method, r.path): {c: measure_cell(svc, r, c) for c in COLUMNS} for r in ROUTES}


def expected(route: Route, column: str) -> Callable[[Cell], bool]:
    """Whether a measured cell is what the policy says for ``route`` and ``column``."""
    want = POLICY[route.who][column]
    if want == "ok":
        return lambda cell: cell.ok
    if want in ("figures", "sessions"):
        return lambda cell: cell.status == f"200 {want}"
    if route.method == "WS":
        return lambda cell: cell.status == WS_CLOSE[want]
    return lambda cell: cell.status == want


RULES = [
    "## The rules",
    "",
    "**Keys.** Two keys go in the `X-API-Key` header: the admin key (everything) and the",
    "read-only operator key (reads of live sessions, no writes). Each comes from its setting",
    "(`ADVISOR_ADMIN_KEY`, `ADVISOR_OPERATOR_KEY`), else from `<data_dir>/admin_key` and",
    "`<data_dir>/operator_key`; if neither exists, one is generated and written there with mode",
    "0600, and the log says where it is kept, never the key. A key that is neither is refused",
    "(403), not taken as none. Session routes take",
    "the session's own token (`Authorization: Bearer`; on the websocket also the subprotocols",
    "`advisor`, `token.<token>`, as the `/walk` page sends it, or `?token=`, which logs keep:",
    "the service's own log writes `token=***`). Comparisons are constant-time.",
    "",
    "**Where explorers are is personal data.** Live positions, recent paths and where advice",
    "was given are shown to the admin and operator keys only: `GET /overview` lists sessions",
    "for them and gives anyone else figures per domain (sessions, steps, advice per 100",
    "decisions, how many look lost); `GET /sessions`, `GET /sessions/{id}` and the viewer's",
    "`GET /viewer/snapshot` are theirs (and a session's own token reads its own session). The",
    "dashboard asks for the operator key and keeps it in the tab's session storage. The cells",
    "an explorer was at are kept `ADVISOR_PATH_RETENTION_SECONDS` (600) at most: older ones are",
    "dropped from its recent path and advice log (answers never show them; the sweeper forgets",
    "them), and only its current cell stays while its session lives. With sessions in Redis, a",
    "session is written there without them, but one that stays still keeps them there until its",
    "next event or its expiry (each read drops them).",
    "",
    "**What the pages offer a key.** `GET /overview` says which key asked (`role`: `admin`,",
    "`operator`, or null without one). The dashboard offers only what that key may do: with the",
    "operator key its End buttons are shown disabled, their tooltip saying that this key can",
    "only read and that ending a session needs the admin key (rather than live buttons that the",
    "service refuses with 403). The 3D viewer holds the operator key and writes nothing: its",
    "controls change what it shows, not the service.",
    "",
    "**The viewer** (`python -m app viewer`, which `serve` starts in a process of its own) is",
    "an operator's tool: it reads the API with the operator key, and listens on loopback",
    "(`ADVISOR_VIEWER_HOST`, default 127.0.0.1) since it asks a browser for no key; it says so",
    "when it starts. It refuses websockets from pages of other origins than its own (403: its",
    "address's, the loopback names' when it listens on loopback or every interface, and those",
    "of `ADVISOR_VIEWER_ORIGINS`), messages over 4 MiB (closed), more than 8 browsers (503),",
    "and drops file uploads.",
    "",
    "**Quotas.** Sessions are free to open, so each client may hold at most",
    "`ADVISOR_CLIENT_MAX_SESSIONS` (1,000) live sessions reserving at most",
    "`ADVISOR_CLIENT_MAX_SESSION_MEMORY` (256 MiB) between them (429 beyond, saying which). A",
    "client is the key it sends as `X-API-Key` where the service knows it, from whatever",
    "address: the operator key is one client, and each key of `ADVISOR_CLIENT_KEYS` (JSON",
    '`{"name": "key"}`, e.g. for a building\'s positioning gateway) another, known by its name',
    "(the 429, Redis and the sessions hold the name, never the key; such a key gives no right",
    "but its own quota). Anyone else is its address, also when it sends a key the service does",
    "not know (an invented key makes no new client): the peer's address, or behind proxies the",
    "operator lists in `ADVISOR_TRUSTED_PROXIES` (addresses or CIDR networks), the last address",
    "of `X-Forwarded-For` that is not one of them (a forwarded address from anyone else is not",
    "believed). Sessions made with the admin key count against no client's quota. In all, at",
    "most `ADVISOR_MAX_SESSIONS` (20,000) sessions reserving `ADVISOR_MAX_SESSION_MEMORY`",
    "(1 GiB) live at once (503 beyond).",
    "",
    "**Connections.** One client may hold at most `ADVISOR_CLIENT_MAX_CONNECTIONS` (256) open",
    "connections, websockets included (429 beyond, and the connection closes); here a client is",
    "the peer's address, since nothing has been read yet, and trusted proxies are not capped",
    "(many clients share them). In all, at most `ADVISOR_MAX_CONNECTIONS` (1,000; fewer if the",
    "process's open-files limit less 64 is lower) are open at once (503 beyond).",
    "",
]


def render(matrix: Matrix) -> str:
    head = " | ".join(COLUMNS.values())
    lines = [
        "# Access matrix",
        "",
        "<!-- generated by `.venv/bin/python -m tests.reliability.access_matrix --write "
        "docs/ACCESS.md`; tests/reliability/test_access.py fails when it is out of date -->",
        "",
        "What the service answers to each route with each kind of credential, measured on a",
        "fresh service (each cell one request to a fresh session or domain). Keys (admin,",
        "operator, a wrong one): the `X-API-Key` header; session credentials: `Authorization:",
        'Bearer <token>` (the websocket also takes `?token=`). "Another session\'s token" is a',
        "valid token of a different live session; on routes without a session, \"the session's own",
        'token" is any valid session token. A websocket is accepted (`open`: it answers',
        "events) or closed with 4400 + the HTTP status it stands for (4401 missing, 4403",
        "wrong). Bodies are valid, so a refusal is about credentials alone.",
        "",
        f"| route | who | {head} |",
        "|---" * (len(COLUMNS) + 2) + "|",
    ]
    for route in ROUTES:
        cells = matrix[(route.method, route.path)]
        row = " | ".join(f"{cells[c].status}" for c in COLUMNS)
        lines.append(f"| `{route.method} {route.path}` | {route.who} | {row} |")
    lines += [
        "",
        "`{new}` is a domain name not yet in use (PUT creates it: 201) or one just created",
        "(DELETE removes it: 204). On `GET /overview`, `figures` is the answer without live",
        "sessions (figures per domain), `sessions` the one that lists them.",
        "",
        *RULES,
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", type=Path, help="write the markdown here (else: print it)")
    args = parser.parse_args(argv)
    text = render(measure())
    if args.write:
        args.write.write_text(text, encoding="utf-8")
    else:
        sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
