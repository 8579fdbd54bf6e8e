"""GET /metrics (Prometheus text), the request ids of JSON logs, and the quiet event routes."""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import httpx
import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from prometheus_client import REGISTRY
from prometheus_client.parser import text_string_to_metric_families

from app.service.logs import JsonFormatter, SkipEventRoutes
from app.service.main import create_app
from tests.client.test_client import run_async
from tests.service.conftest import make_settings, open_session, put_tiny

EVENTS = "/sessions/{session_id}/events"


def sample(name: str, **labels: str) -> float:
    return REGISTRY.get_sample_value(name, labels) or 0.0


def test_metrics_are_prometheus_text_named_advisor(client: TestClient) -> None:
    r = client.get("/metrics")
    assert r.status_code == 200
    assert r.headers["content-type"].startswith("text/plain")
    names = {f.name for f in text_string_to_metric_families(r.text)}
    ours = {n for n in names if n.startswith("advisor_")}
    assert {
        "advisor_http_requests",
        "advisor_http_request_duration_seconds",
        "advisor_live_sessions",
        "advisor_decisions",
        "advisor_advice",
        "advisor_trajectories_ingested",
        "advisor_viewer_tick_seconds",
    } <= ours


def test_metrics_count_requests_by_route_template_not_path(client: TestClient) -> None:
    before = sample("advisor_http_requests_total", method="POST", route=EVENTS, status="200")
    hist = sample("advisor_http_request_duration_seconds_count", method="POST", route=EVENTS)
    for _ in range(2):  # two sessions: two paths, one series
        sid, auth, _ = open_session(client)
        assert client.post(f"/sessions/{sid}/events", json=E, headers=auth).status_code == 200
    after = sample("advisor_http_requests_total", method="POST", route=EVENTS, status="200")
    assert after - before == 2
    assert sample("advisor_http_request_duration_seconds_count", method="POST", route=EVENTS) == (
        hist + 2
    )
    text = client.get("/metrics").text
    assert sid not in text  # no raw path becomes a label
    unmatched = sample(
        "advisor_http_requests_total", method="GET", route="<unmatched>", status="404"
    )
    assert client.get(f"/no/such/{sid}").status_code == 404
    assert (
        sample("advisor_http_requests_total", method="GET", route="<unmatched>", status="404")
        == unmatched + 1
    )


E = {"state": [28, 0], "action": "E"}


def series(name: str) -> dict[tuple[tuple[str, str], ...], float]:
    """The samples of ``name`` in the registry: label sets and values."""
    return {
        tuple(sorted(s.labels.items())): s.value
        for family in REGISTRY.collect()
        for s in family.samples
        if s.name == name
    }


#: methods llhttp (uvicorn's parser) knows, and some it does not
METHODS = [
    *("GET", "HEAD", "POST", "PUT", "DELETE", "CONNECT", "OPTIONS", "TRACE", "PATCH", "COPY"),
    *("LOCK", "MKCOL", "MOVE", "PROPFIND", "PROPPATCH", "SEARCH", "UNLOCK", "BIND", "REBIND"),
    *("UNBIND", "ACL", "REPORT", "MKACTIVITY", "CHECKOUT", "MERGE", "M-SEARCH", "NOTIFY"),
    *("SUBSCRIBE", "UNSUBSCRIBE", "PURGE", "MKCALENDAR", "LINK", "UNLINK", "SOURCE", "QUERY"),
    *("DESCRIBE", "ANNOUNCE", "SETUP", "PLAY", "PAUSE", "TEARDOWN", "GET_PARAMETER"),
    *("SET_PARAMETER", "REDIRECT", "RECORD", "FLUSH", "FOO", "BAR", "X-EVIL", "ZZZZ"),
]


def test_no_metrics_label_takes_a_value_the_client_chose(client: TestClient) -> None:
    """50 methods x 20 paths: the series they add name only the routes' own methods (any
    other is OTHER) and route templates (any other path is <unmatched>)."""
    from app.service.routes import ROUTERS
    from app.service.routes import metrics as metrics_route

    assert len(METHODS) == 50
    sid, auth, _ = open_session(client)
    paths = [
        f"/sessions/{sid}/events", f"/sessions/{sid}", f"/sessions/{sid}/positions",
        "/sessions", "/domains", "/domains/default", "/domains/default/sessions",
        "/domains/default/prior", "/health", "/metrics", "/overview", "/docs", "/openapi.json",
        "/static/app.js", f"/no/such/{sid}", "/%00", "/" + "x" * 300, "/sessions/a/b/c",
        "/domains/no-such", "/viewer",
    ]  # fmt: skip
    assert len(paths) == 20
    names = ("advisor_http_requests_total", "advisor_http_request_duration_seconds_count")
    before = {n: series(n) for n in names}
    for method in METHODS:
        for path in paths:
            client.request(method, path, headers=auth)
    app: FastAPI = client.app  # type: ignore[assignment]
    routers = (app.router, *ROUTERS, metrics_route.router)
    routes = [r for router in routers for r in router.routes]
    own: dict[str, set[str]] = {}  # each route template's methods
    for r in routes:
        if hasattr(r, "path"):
            own.setdefault(r.path, set()).update(getattr(r, "methods", None) or ())
    anywhere = set().union(*own.values())
    assert anywhere == {"GET", "HEAD", "POST", "PUT", "DELETE"}
    own |= {p: anywhere for p in ("<unmatched>", "/static/{path}", "/static-offline-docs/{path}")}
    for name in names:
        after = series(name)
        assert sum(after.values()) - sum(before[name].values()) == 50 * 20  # each counted
        added = [dict(x) for x in after.keys() - before[name].keys()]
        assert {x["method"] for x in added} <= anywhere | {"OTHER"}
        for x in added:  # a route's own methods, or OTHER
            assert x["method"] in own[x["route"]] | {"OTHER"}, x
        assert len({x["route"] for x in added}) <= len(paths)
        assert {dict(x)["method"] for x in after} <= anywhere | {"OTHER", "WS"}


def test_metrics_count_decisions_and_advice_per_domain_and_strategy(
    client: TestClient, admin: dict[str, str]
) -> None:
    put_tiny(client, admin, "metrics-tiny")
    labels = {"domain": "metrics-tiny", "strategy": "always"}
    sid, auth, _ = open_session(client, "metrics-tiny", strategy="always")
    moves = [{"state": [5, 1], "action": "E"}, {"state": [5, 2], "action": "W"}]
    assert client.post(f"/sessions/{sid}/events", json=moves, headers=auth).status_code == 200
    assert client.post(f"/sessions/{sid}/events", json=moves[0], headers=auth).status_code == 200
    # the start decision, a batch of two, one event: four decisions, each advised ("always")
    assert sample("advisor_decisions_total", **labels) == 4
    assert sample("advisor_advice_total", **labels) == 4
    client.get("/metrics")
    assert sample("advisor_live_sessions", domain="metrics-tiny") == 1
    steps = [{"state": [5, 1], "action": "E"}, {"state": [5, 2], "action": "E"}]
    r = client.post(
        "/domains/metrics-tiny/trajectories",
        json={"trajectories": [{"steps": steps}]},
        headers=admin,
    )
    assert r.status_code == 201
    assert sample("advisor_trajectories_ingested_total", domain="metrics-tiny") == 1
    assert sample("advisor_trajectory_pairs_ingested_total", domain="metrics-tiny") == 2
    # a deleted domain's series go with it
    assert client.delete("/domains/metrics-tiny", headers=admin).status_code == 204
    text = client.get("/metrics").text
    assert "metrics-tiny" not in text


def test_metrics_can_be_turned_off(tmp_path: Path) -> None:
    with TestClient(create_app(make_settings(tmp_path, metrics_enabled=False))) as c:
        assert c.get("/metrics").status_code == 404


def test_json_logs_carry_the_request_id_which_the_answer_echoes(tmp_path: Path) -> None:
    settings = make_settings(tmp_path, log_format="json")
    with TestClient(create_app(settings)) as c:
        given = c.get("/health", headers={"X-Request-ID": "abc-123"})
        assert given.headers["x-request-id"] == "abc-123"
        made = c.get("/health").headers["x-request-id"]
        assert len(made) == 16 and made != "abc-123"
    record = logging.LogRecord(
        "uvicorn.access", logging.INFO, "", 0, '%s - "%s %s HTTP/%s" %d',
        ("127.0.0.1:5", "GET", "/health", "1.1", 200), None,
    )  # fmt: skip
    from app.service.logs import REQUEST_ID

    token = REQUEST_ID.set("r1")
    try:
        line = json.loads(JsonFormatter().format(record))
    finally:
        REQUEST_ID.reset(token)
    assert line["request_id"] == "r1" and line["status"] == 200 and line["path"] == "/health"
    assert line["level"] == "INFO" and line["logger"] == "uvicorn.access"


def test_event_routes_are_left_out_of_the_access_log_others_are_kept() -> None:
    keep = SkipEventRoutes()

    def access(path: str) -> logging.LogRecord:
        args = ("127.0.0.1:5", "POST", path, "1.1", 200)
        return logging.LogRecord(
            "uvicorn.access", logging.INFO, "", 0, "%s %s %s %s %d", args, None
        )

    assert not keep.filter(access("/sessions/ab12/events"))
    assert keep.filter(access("/sessions/ab12"))
    assert keep.filter(access("/domains/default/sessions"))
    ws = logging.LogRecord(
        "uvicorn.error", logging.INFO, "", 0, '%s - "WebSocket %s" [accepted]',
        ("127.0.0.1:5", "/sessions/ab12/stream?token=***"), None,
    )  # fmt: skip
    assert not keep.filter(ws)
    other = logging.LogRecord("uvicorn.error", logging.INFO, "", 0, "Started server", None, None)
    assert keep.filter(other)


def test_a_live_server_counts_event_routes_instead_of_logging_them(tmp_path: Path) -> None:
    from websockets.sync.client import connect

    from tests.reliability.conftest import start, stop

    live = start(tmp_path / "data", log_level="info")
    try:
        with httpx.Client(base_url=live.url, timeout=10) as http:
            created = http.post("/domains/default/sessions", json={}).json()
            sid, token = created["session_id"], created["token"]
            auth = {"Authorization": f"Bearer {token}"}
            assert http.post(f"/sessions/{sid}/events", json=E, headers=auth).status_code == 200
            with connect(live.url.replace("http", "ws") + f"/sessions/{sid}/stream?token={token}"):
                pass
            assert http.get(f"/sessions/{sid}", headers=auth).status_code == 200
            counted = http.get("/metrics").text
    finally:
        stop(live)
    log = live.log.read_text(errors="replace")
    assert f'"GET /sessions/{sid} HTTP/1.1" 200' in log  # other routes keep their line
    assert f"/sessions/{sid}/events" not in log and f"/sessions/{sid}/stream" not in log
    assert 'route="/sessions/{session_id}/events",status="200"} 1.0' in counted
    assert 'method="WS",route="/sessions/{session_id}/stream",status="101"} 1.0' in counted


def _access_lines(quiet: bool) -> tuple[list[bool], list[str]]:
    """Two requests (an event, another route) through the service's HTTP protocol over an
    in-memory transport, uvicorn's access logger at INFO, the event lines dropped (``quiet``)
    or not: whether the protocol meant to log each, and the lines that reached a handler."""
    import asyncio
    from unittest import mock

    from uvicorn.config import Config
    from uvicorn.server import ServerState

    from app.service.guard import guarded_http
    from app.service.logs import quiet_event_routes

    async def app(scope: Any, receive: Any, send: Any) -> None:
        await send({"type": "http.response.start", "status": 200, "headers": []})
        await send({"type": "http.response.body", "body": b"{}"})

    lines: list[str] = []
    handler = logging.Handler()
    handler.emit = lambda record: lines.append(record.getMessage())  # type: ignore[method-assign]
    logger = logging.getLogger("uvicorn.access")
    kept = logger.filters[:]
    transport = mock.Mock(is_closing=lambda: False, get_extra_info=lambda *a: None)
    logged: list[bool] = []

    async def run() -> None:
        config = Config(app, log_config=None, proxy_headers=False)
        config.load()
        protocol = guarded_http(16384, 5.0, 5.0, 10, 10, [])(config, ServerState(), {})
        protocol.connection_made(transport)
        for path in (b"/sessions/ab12/events", b"/sessions/ab12"):
            protocol.data_received(b"POST " + path + b" HTTP/1.1\r\nHost: x\r\n\r\n")
            logged.append(protocol.cycle.access_log)
            await asyncio.sleep(0)  # the application task answers
        protocol.connection_lost(None)

    logger.addHandler(handler)
    level = logger.level
    logger.setLevel(logging.INFO)
    try:
        for f in [f for f in logger.filters if isinstance(f, SkipEventRoutes)]:
            logger.removeFilter(f)
        if quiet:
            quiet_event_routes()
        run_async(run())  # off the browser tests' loop
    finally:
        logger.removeHandler(handler)
        logger.setLevel(level)
        logger.filters[:] = kept
    return logged, lines


def test_the_protocol_makes_no_access_line_the_log_would_drop() -> None:
    logged, lines = _access_lines(quiet=True)  # the default: event routes counted, not logged
    assert logged == [False, True]
    assert len(lines) == 1 and "/sessions/ab12 " in lines[0]
    logged, lines = _access_lines(quiet=False)  # ADVISOR_ACCESS_LOG_EVENTS=true
    assert logged == [True, True]
    assert len(lines) == 2 and "/sessions/ab12/events" in lines[0]


def test_metrics_add_up_the_workers_in_prometheus_multiprocess_mode(tmp_path: Path) -> None:
    """Three worker processes count; a fourth answers /metrics with their sums (the live
    sessions, which every worker counts whole when they share them: the value set last by a
    worker that has not died)."""
    import os
    import subprocess
    import sys

    env = os.environ | {"PROMETHEUS_MULTIPROC_DIR": str(tmp_path)}
    work = (
        "from app.service.metrics import METRICS, SESSIONS\n"
        "METRICS.request('GET', '/health', 200, 0.002)\n"
        "METRICS.decisions('default', 'paper', 3, 1)\n"
        "import os, sys; SESSIONS.labels('default').set(int(sys.argv[1]))\n"
        "print(os.getpid())\n"
    )
    pids = [
        subprocess.run(
            [sys.executable, "-c", work, str(live)], env=env, check=True, timeout=120,
            capture_output=True,
        ).stdout.split()[-1]
        for live in (5, 3, 1)
    ]  # fmt: skip
    # the first worker has exited (as a process manager reports to prometheus-client)
    show = (
        "from prometheus_client import multiprocess\n"
        f"multiprocess.mark_process_dead({int(pids[0])})\n"
        "from app.service.metrics import exposition; print(exposition().decode())"
    )
    out = subprocess.run(
        [sys.executable, "-c", show], env=env, check=True, capture_output=True, text=True
    ).stdout
    samples = {
        (s.name, tuple(sorted(s.labels.items()))): s.value
        for f in text_string_to_metric_families(out)
        for s in f.samples
    }
    health = (("method", "GET"), ("route", "/health"), ("status", "200"))
    assert samples[("advisor_http_requests_total", health)] == 3
    paper = (("domain", "default"), ("strategy", "paper"))
    assert samples[("advisor_decisions_total", paper)] == 9
    assert samples[("advisor_advice_total", paper)] == 3
    # live sessions: the value set last (1), not the largest (3) nor the sum (4)
    assert samples[("advisor_live_sessions", (("domain", "default"),))] == 1


def test_metrics_read_past_a_file_a_starting_worker_has_not_sized_yet(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A worker's metric file is created empty and then sized; /metrics read in between (a
    worker starting in a killed one's place) raised and answered 500. The empty file holds
    no value yet and is passed over; the other workers' values are there."""
    import os
    import subprocess
    import sys

    env = os.environ | {"PROMETHEUS_MULTIPROC_DIR": str(tmp_path)}
    work = (
        "from app.service.metrics import METRICS\nMETRICS.request('GET', '/health', 200, 0.002)\n"
    )
    subprocess.run([sys.executable, "-c", work], env=env, check=True, timeout=120)
    for name in ("counter_999999.db", "gauge_liveall_999998.db", "histogram_999999.db"):
        (tmp_path / name).touch()  # created, not yet sized
    monkeypatch.setenv("PROMETHEUS_MULTIPROC_DIR", str(tmp_path))
    from app.service.metrics import exposition

    samples = {
        (s.name, tuple(sorted(s.labels.items()))): s.value
        for f in text_string_to_metric_families(exposition().decode())
        for s in f.samples
    }
    health = (("method", "GET"), ("route", "/health"), ("status", "200"))
    assert samples[("advisor_http_requests_total", health)] == 1


def live_sessions(url: str) -> float:
    r = httpx.get(f"{url}/metrics", timeout=10)
    assert r.status_code == 200, r.text
    for family in text_string_to_metric_families(r.text):
        for s in family.samples:
            if s.name == "advisor_live_sessions" and s.labels == {"domain": "default"}:
                return s.value
    raise AssertionError("no advisor_live_sessions{domain='default'} in /metrics")


def gauge_of(directory: Path, pid: int) -> float | None:
    """The live-sessions value worker ``pid`` last wrote in its file (None: no file)."""
    from prometheus_client.multiprocess import MultiProcessCollector

    files = [str(f) for f in directory.glob(f"gauge_live*_{pid}.db")]
    for metric in MultiProcessCollector.merge(files):  # type: ignore[no-untyped-call]
        for s in metric.samples:
            if s.name == "advisor_live_sessions" and s.labels == {"domain": "default"}:
                return float(s.value)
    return None


def test_the_live_sessions_gauge_is_right_after_a_worker_is_killed(tmp_path: Path) -> None:
    """``serve --workers 2`` with Redis: three sessions, each worker's gauge saying 3; one
    worker killed (SIGKILL), the sessions ended: /metrics says 0 at once, from the worker left,
    and the worker uvicorn starts in the killed one's place removes its gauge file."""
    import os
    import signal
    import time

    import pytest

    from tests.reliability.conftest import start, stop
    from tests.reliability.test_workers import workers_of
    from tests.service.conftest import REDIS_URL, drop_redis_keys, redis_prefix, redis_problem

    problem = redis_problem()
    if problem is not None:
        pytest.skip(f"Redis at {REDIS_URL}: {problem}")

    def wait_until(condition: object, what: str, timeout: float = 60.0) -> None:
        deadline = time.monotonic() + timeout
        while not condition():  # type: ignore[operator]
            assert time.monotonic() < deadline, f"timed out waiting for {what}"
            time.sleep(0.05)

    prefix = redis_prefix()
    files = tmp_path / "metrics"
    files.mkdir()
    env: dict[str, Any] = {
        "ADVISOR_WORKERS": "2", "ADVISOR_REDIS_URL": REDIS_URL, "ADVISOR_REDIS_PREFIX": prefix,
        "PROMETHEUS_MULTIPROC_DIR": str(files),
    }  # fmt: skip
    live = start(tmp_path / "data", **env)
    try:
        pids = workers_of(live)
        assert len(pids) == 2, pids
        # a connection per request: a kept-alive one may be the killed worker's
        made = [httpx.post(f"{live.url}/domains/default/sessions", json={}).json() for _ in "abc"]
        # each worker sets its gauge from Redis' count every few seconds
        wait_until(lambda: all(gauge_of(files, p) == 3 for p in pids), "both gauges at 3")
        killed = pids[0]
        os.kill(killed, signal.SIGKILL)
        for m in made:
            auth = {"Authorization": f"Bearer {m['token']}"}
            ended = httpx.delete(f"{live.url}/sessions/{m['session_id']}", headers=auth)
            assert ended.status_code == 200, ended.text
        assert gauge_of(files, killed) == 3  # the dead worker's last value, still there
        assert live_sessions(live.url) == 0
        wait_until(lambda: len(workers_of(live)) == 2, "a worker in the killed one's place")
        wait_until(lambda: gauge_of(files, killed) is None, "the dead worker's file to go")
        assert live_sessions(live.url) == 0
    finally:
        stop(live)
        drop_redis_keys(prefix)


def json_lines(text: str) -> list[dict[str, Any]]:
    """Every line of a log as a JSON object (fails, showing the line, on any other)."""
    out = []
    for line in text.splitlines():
        if not line.strip():
            continue
        try:
            record = json.loads(line)
        except ValueError:
            raise AssertionError(f"a log line that is not JSON: {line!r}") from None
        assert isinstance(record, dict), line
        assert {"time", "level", "logger", "message"} <= record.keys(), line
        out.append(record)
    return out


def test_json_logs_are_json_from_the_first_start_to_the_last_line(tmp_path: Path) -> None:
    """``ADVISOR_LOG_FORMAT=json``, a first start (keys made, the default domain created) with
    the viewer, requests, a graceful stop keeping a session: every line of stdout and stderr
    (the server's and its viewer's) is a JSON object."""
    import time

    from tests.client.conftest import free_port
    from tests.reliability.conftest import start, stop

    viewer_port = free_port()
    live = start(tmp_path / "data", log_level="info", viewer_port=viewer_port,
                 ADVISOR_LOG_FORMAT="json")  # fmt: skip
    try:
        with httpx.Client(base_url=live.url, timeout=10) as http:
            assert http.get("/domains/nowhere").status_code == 404
            assert http.post("/domains/default/sessions", json={}).status_code == 201
        deadline = time.monotonic() + 60
        while "viewer on http" not in live.log.read_text(errors="replace"):
            assert time.monotonic() < deadline, live.log.read_text(errors="replace")
            time.sleep(0.05)
    finally:
        stop(live)
    records = json_lines(live.log.read_text(errors="replace"))
    messages = [r["message"] for r in records]
    assert any(m.startswith("Generated the admin key") for m in messages)
    assert any(m.startswith("Generated the read-only operator key") for m in messages)
    assert any(m.startswith("Created domain 'default'") for m in messages)
    assert any(m.startswith("viewer on http://127.0.0.1:") for m in messages)
    assert any(r["logger"] == "uvicorn.access" and r.get("status") == 404 for r in records)
    assert "Kept 1 live sessions for the next start" in messages
