"""Redis failing under the service, each test with a ``redis-server`` of its own on a free port
(paused with SIGSTOP, killed, restarted with its data or without, filled to ``maxmemory``,
behind a password, behind TLS): every request that needs Redis answers 503 with
``Retry-After`` and a body naming Redis in time (a websocket closes with 1013, an MQTT message
gets its error), never a 500; while Redis is known to be down, requests do not wait for it;
sessions go on where they were when it comes back with its data, and answer 410 saying they
were lost when it comes back empty; nothing acknowledged is lost.

Most tests run the app in process (TestClient) with a command timeout of 0.3 s; the kill test
runs the real server (``python -m app serve``) and reads its log for tracebacks."""

from __future__ import annotations

import json
import logging
import subprocess
import threading
import time
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
import redis.asyncio as aioredis
from fastapi.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

from app.service.config import Settings
from app.service.live.lanes import Lane
from app.service.main import create_app
from app.service.state import ServiceState
from tests.reliability.conftest import server_errors, start, stop
from tests.reliability.redis_server import RedisServer, needs_redis_server
from tests.service.conftest import make_settings, open_session

pytestmark = needs_redis_server
TIMEOUT = 0.3  # ADVISOR_REDIS_TIMEOUT of these tests


def settings_for(tmp: Path, server: RedisServer, url: str | None = None, **more: Any) -> Settings:
    values: dict[str, Any] = {"redis_url": url or server.url, "redis_timeout": TIMEOUT}
    return make_settings(tmp / "data", database_url=f"sqlite:///{tmp / 'advisor.db'}",
                         **(values | more))  # fmt: skip


@pytest.fixture(autouse=True)
def no_traceback(caplog: pytest.LogCaptureFixture) -> Iterator[None]:
    """No test here logs an error or a traceback (the server's log is read in the kill test)."""
    with caplog.at_level(logging.WARNING):
        yield
    logged = [r for r in caplog.records if r.levelno >= logging.ERROR or r.exc_info]
    assert logged == [], [r.getMessage() for r in logged]


@pytest.fixture
def redis_server(tmp_path: Path) -> Iterator[RedisServer]:
    server = RedisServer(tmp_path / "redis").start()
    try:
        yield server
    finally:
        server.stop()


def event(step: int) -> dict[str, Any]:
    """Step ``step`` of a walk along the default domain's bottom corridor, back and forth."""
    return {"state": [28, (step - 1) % 2], "action": "E" if step % 2 else "W", "step": step}


def post(c: TestClient | httpx.Client, sid: str, auth: dict[str, str], step: int) -> Any:
    return c.post(f"/sessions/{sid}/events", json=event(step), headers=auth)


def assert_redis_503(r: httpx.Response) -> None:
    assert r.status_code == 503, r.text
    assert r.headers["retry-after"] == "1"
    assert "Redis" in r.json()["detail"], r.text


def service_of(c: TestClient) -> ServiceState:
    state: ServiceState = c.app.state.service  # type: ignore[attr-defined]
    return state


def wait_ready(c: TestClient | httpx.Client, within: float = 30.0) -> None:
    """Until readiness is 200 (Redis answered a probe): bounded, not timed."""
    deadline = time.monotonic() + within
    while c.get("/health/ready").status_code != 200:
        assert time.monotonic() < deadline, "not ready again after Redis came back"
        time.sleep(0.05)


class Calls:
    """Calls that reached Redis: through the lanes, and through redis-py's pool (the breaker's
    probes, ``GET <prefix>:gen``, left out)."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch, prefix: str):
        self.lanes = 0
        self.commands = 0
        lane_call, command = Lane.call, aioredis.Redis.execute_command

        async def counted_lane(lane: Lane, *args: Any) -> Any:
            self.lanes += 1
            return await lane_call(lane, *args)

        async def counted(client: aioredis.Redis, *args: Any, **options: Any) -> Any:
            if args[:2] != ("GET", f"{prefix}:gen"):
                self.commands += 1
            return await command(client, *args, **options)  # type: ignore[no-untyped-call]

        monkeypatch.setattr(Lane, "call", counted_lane)
        monkeypatch.setattr(aioredis.Redis, "execute_command", counted)


def test_a_paused_redis_is_503_in_time_and_at_once_while_down_then_the_retry_applies_once(
    tmp_path: Path, redis_server: RedisServer, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Redis stopped (SIGSTOP): the first request waits the command timeout and answers 503;
    from then on every request that needs Redis (events, reads, a new session, a domain, the
    websocket) is refused at once, none reaching Redis; liveness stays 200, readiness is 503
    naming Redis. Once Redis continues, the event sent again with its step is applied once."""
    with TestClient(create_app(settings_for(tmp_path, redis_server))) as c:
        sessions = service_of(c).sessions
        sid, auth, _ = open_session(c)
        token = auth["Authorization"].removeprefix("Bearer ")
        assert post(c, sid, auth, 1).status_code == 200
        redis_server.pause()
        try:
            assert_redis_503(post(c, sid, auth, 2))  # waited the timeout: Redis is down
            breaker = sessions.breaker  # type: ignore[attr-defined]
            assert not breaker.up
            calls = Calls(monkeypatch, sessions.prefix)  # type: ignore[attr-defined]
            refused = breaker.refused
            answers = [
                post(c, sid, auth, 2),
                c.get(f"/sessions/{sid}", headers=auth),
                c.post("/domains/default/sessions", json={}),
                c.get("/domains/default"),
                c.delete(f"/sessions/{sid}", headers=auth),
            ]
            for r in answers:
                assert_redis_503(r)
            with (
                c.websocket_connect(f"/sessions/{sid}/stream?token={token}") as ws,
                pytest.raises(WebSocketDisconnect) as closed,
            ):
                ws.receive_text()
            assert closed.value.code == 1013 and "Redis" in closed.value.reason
            assert c.get("/health/live").status_code == 200
            for path in ("/health", "/health/ready"):
                r = c.get(path)
                assert r.status_code == 503 and r.headers["retry-after"], r.text
                deps = r.json()["dependencies"]
                assert deps["redis"]["state"] == "down" and deps["database"]["state"] == "up"
                assert "Redis" in r.json()["detail"] or "redis" in r.json()["detail"]
            assert c.head("/health/ready").status_code == 503
            assert c.head("/health/live").status_code == 200
            # none of them reached Redis: each was refused by the breaker
            assert (calls.lanes, calls.commands) == (0, 0)
            assert breaker.refused >= refused + len(answers) + 1
            monkeypatch.undo()
        finally:
            redis_server.resume()
        wait_ready(c)
        r = post(c, sid, auth, 2)
        assert r.status_code == 200 and r.json()["step"] == 2, r.text
        assert c.get(f"/sessions/{sid}", headers=auth).json()["steps"] == 2
        r = post(c, sid, auth, 3)
        assert r.status_code == 200 and r.json()["step"] == 3


def test_a_websocket_frame_while_redis_is_paused_is_a_503_frame_and_is_applied_once_after(
    tmp_path: Path, redis_server: RedisServer
) -> None:
    """Mid-stream, Redis stopped: the frame's answer is an error frame (status 503,
    ``retry_after``, naming Redis) and the stream stays open; once Redis answers again the
    same frame is applied once."""
    with TestClient(create_app(settings_for(tmp_path, redis_server))) as c:
        sid, auth, _ = open_session(c)
        token = auth["Authorization"].removeprefix("Bearer ")
        with c.websocket_connect(f"/sessions/{sid}/stream?token={token}") as ws:
            ws.send_text(json.dumps([event(1), event(2)]))
            assert [d["step"] for d in json.loads(ws.receive_text())] == [1, 2]
            frame = json.dumps([event(3), event(4)])
            redis_server.pause()
            try:
                for _ in range(3):  # the first waits the timeout, the others are refused at once
                    ws.send_text(frame)
                    error = json.loads(ws.receive_text())
                    assert error["status"] == 503 and error["retry_after"] == 1, error
                    assert "Redis" in error["detail"]
            finally:
                redis_server.resume()
            wait_ready(c)
            ws.send_text(frame)
            assert [d["step"] for d in json.loads(ws.receive_text())] == [3, 4]
        assert c.get(f"/sessions/{sid}", headers=auth).json()["steps"] == 4


class Walker(threading.Thread):
    """An explorer on the real server: one event at a time with its step; 503: the same step
    again 50 ms later; anything else but 200 is kept as wrong."""

    def __init__(self, url: str, sid: str, token: str):
        super().__init__(daemon=True)
        self.url, self.sid = url, sid
        self.auth = {"Authorization": f"Bearer {token}"}
        self.step = 1  # the next step to send
        self.acked = 0  # the last step answered 200
        self.statuses: Counter[object] = Counter()
        self.wrong: list[str] = []
        self.halt = threading.Event()

    def run(self) -> None:
        with httpx.Client(base_url=self.url, timeout=10) as http:
            while not self.halt.is_set():
                try:
                    r = post(http, self.sid, self.auth, self.step)
                except httpx.HTTPError as exc:
                    self.wrong.append(f"no answer: {exc!r}")
                    return
                self.statuses[r.status_code] += 1
                if r.status_code == 200 and r.json()["step"] == self.step:
                    self.acked = self.step
                    self.step += 1
                elif r.status_code == 503 and r.headers.get("retry-after") == "1":
                    time.sleep(0.05)
                else:
                    self.wrong.append(f"{r.status_code} {r.headers} {r.text}")
                    return

    def walk(self, until: int) -> None:
        while self.acked < until and self.is_alive():
            time.sleep(0.01)


def test_a_killed_redis_restarted_from_its_append_only_file_loses_no_acknowledged_event(
    tmp_path: Path,
) -> None:
    """Four explorers stream one event at a time to the real server; Redis (append-only file,
    fsync at every write) is killed (SIGKILL) mid-stream, and restarted on the same files.
    Meanwhile every answer is 200 or 503 with Retry-After, never a 500, and the server logs
    no traceback. What the restarted Redis holds for each session is every step that was
    acknowledged (and at most the one in flight at the kill); the explorers then go on,
    sending their unanswered step again, and end with exactly the steps acknowledged."""
    server = RedisServer(tmp_path / "redis", aof=True).start()
    live = start(tmp_path / "data", ADVISOR_REDIS_URL=server.url,
                 ADVISOR_REDIS_TIMEOUT=str(TIMEOUT))  # fmt: skip
    try:
        made = [httpx.post(f"{live.url}/domains/default/sessions", json={}).json()
                for _ in range(4)]  # fmt: skip
        walkers = [Walker(live.url, m["session_id"], m["token"]) for m in made]
        for w in walkers:
            w.start()
        for w in walkers:
            w.walk(until=30)
        server.kill()
        deadline = time.monotonic() + 20
        while not all(w.statuses[503] for w in walkers):  # each met Redis gone
            assert time.monotonic() < deadline and all(w.is_alive() for w in walkers), [
                w.wrong for w in walkers
            ]
            time.sleep(0.02)
        for w in walkers:
            w.halt.set()
            w.join(30)
        assert [w.wrong for w in walkers] == [[]] * 4
        server.start()  # the same port and files: Redis reads its append-only file
        with httpx.Client(base_url=live.url, timeout=10) as http:
            wait_ready(http)
            for w in walkers:
                held = http.get(f"/sessions/{w.sid}", headers=w.auth).json()["steps"]
                assert w.acked <= held <= w.acked + 1, (w.acked, held)
        again = [Walker(live.url, w.sid, w.auth["Authorization"][7:]) for w in walkers]
        for old, new in zip(walkers, again, strict=True):
            new.step, new.acked = old.step, old.acked
            new.start()
        for w in again:
            w.walk(until=w.acked + 20)
            w.halt.set()
            w.join(30)
        assert [w.wrong for w in again] == [[]] * 4
        with httpx.Client(base_url=live.url, timeout=10) as http:
            for w in again:
                assert http.get(f"/sessions/{w.sid}", headers=w.auth).json()["steps"] == w.acked
        statuses = sum((w.statuses for w in walkers + again), Counter())
        assert set(statuses) <= {200, 503}, statuses
        print(f"\nkill and restart: {dict(statuses)} answers")
    finally:
        stop(live)
        server.stop()
    assert server_errors(live) == []
    assert "Traceback" not in live.log.read_text(errors="replace")


def test_redis_restarted_empty_answers_410_saying_the_session_was_lost(
    tmp_path: Path, redis_server: RedisServer
) -> None:
    """Redis killed and restarted without its data, two workers: the sessions a worker held
    answer 410 saying they were lost (events, reads, the websocket), from either worker, the
    one that never saw them too; an id that never was is 404; new sessions work."""
    a = TestClient(create_app(settings_for(tmp_path, redis_server)))
    b = TestClient(create_app(settings_for(tmp_path, redis_server)))
    with a, b:
        one, auth1, _ = open_session(a)
        two, auth2, _ = open_session(a)
        for step in (1, 2):
            assert post(a, one, auth1, step).status_code == 200
            assert post(a, two, auth2, step).status_code == 200
        redis_server.kill()
        redis_server.start(empty=True)
        r = post(a, one, auth1, 3)
        assert r.status_code == 410, r.text
        assert "lost" in r.json()["detail"] and "Redis" in r.json()["detail"]
        r = b.get(f"/sessions/{two}", headers=auth2)  # a worker that never held it
        assert r.status_code == 410 and "lost" in r.json()["detail"], r.text
        assert a.get(f"/sessions/{one}", headers=auth1).status_code == 410
        token = auth2["Authorization"].removeprefix("Bearer ")
        with (
            a.websocket_connect(f"/sessions/{two}/stream?token={token}") as ws,
            pytest.raises(WebSocketDisconnect) as closed,
        ):
            ws.receive_text()
        assert closed.value.code == 4410 and "lost" in closed.value.reason
        r = b.get("/sessions/never-was", headers=auth1)
        assert r.status_code == 404, r.text
        three, auth3, _ = open_session(b)
        for step in (1, 2, 3):
            assert post([a, b][step % 2], three, auth3, step).status_code == 200
        assert a.get(f"/sessions/{three}", headers=auth3).json()["steps"] == 3
        assert a.get("/health/ready").status_code == 200


def test_trajectories_stored_while_redis_fails_are_acknowledged_and_other_workers_learn_of_them(
    tmp_path: Path, redis_server: RedisServer, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Redis fails after an ingestion's transaction committed (telling it the domain's new
    data version): the trajectories are stored, so the answer is 201, not a 503 a client
    would send again (storing them twice); the other worker learns of them once Redis is told,
    at the next sweep."""
    from app.service.live.faults import RedisDown
    from app.service.live.shared import SharedSessions

    a = TestClient(create_app(settings_for(tmp_path, redis_server)))
    b = TestClient(create_app(settings_for(tmp_path, redis_server)))
    with a, b:
        admin = {"X-API-Key": service_of(a).admin_key}
        before = b.get("/domains/default").json()["trajectories"]
        run = SharedSessions._run

        async def failing(self: SharedSessions, cmd: str, *args: Any, lane: str = "") -> Any:
            if cmd == "version":
                raise RedisDown("Redis did not answer within 0.3 s")
            return await run(self, cmd, *args, lane=lane)

        steps = {"trajectories": [{"steps": [{"state": [28, c], "action": "E"} for c in range(4)]}]}
        with monkeypatch.context() as m:
            m.setattr(SharedSessions, "_run", failing)
            r = a.post("/domains/default/trajectories", json=steps, headers=admin)
        assert r.status_code == 201, r.text
        assert a.get("/domains/default").json()["trajectories"] == before + 1
        assert b.get("/domains/default").json()["trajectories"] == before  # not told yet
        assert a.portal is not None
        a.portal.call(service_of(a).sessions.sweep)
        assert b.get("/domains/default").json()["trajectories"] == before + 1


def test_a_full_redis_answers_503_for_writes_and_recovers_losing_nothing(
    tmp_path: Path,
) -> None:
    """Redis at its ``maxmemory`` (noeviction): events (the lanes) and new sessions (the
    pool) answer 503 saying Redis is out of memory, reads still answer, the breaker stays
    closed (Redis answers at once); with room again, the same events are applied once and
    every acknowledged step is there."""
    server = RedisServer(tmp_path / "redis", "--maxmemory-policy", "noeviction").start()
    try:
        with TestClient(create_app(settings_for(tmp_path, server))) as c:
            made = [open_session(c)[:2] for _ in range(3)]
            for sid, auth in made:
                for step in (1, 2, 3):
                    assert post(c, sid, auth, step).status_code == 200
            admin = server.client()
            memory: dict[str, Any] = admin.info("memory")  # type: ignore[assignment]
            used = int(memory["used_memory"])
            admin.config_set("maxmemory", max(1, used // 2))
            for sid, auth in made:
                r = post(c, sid, auth, 4)
                assert_redis_503(r)
                assert "out of memory" in r.json()["detail"]
                assert c.get(f"/sessions/{sid}", headers=auth).json()["steps"] == 3
            r = c.post("/domains/default/sessions", json={})
            assert_redis_503(r)
            assert "out of memory" in r.json()["detail"]
            assert service_of(c).sessions.breaker.up  # type: ignore[attr-defined]
            admin.config_set("maxmemory", 0)
            for sid, auth in made:
                r = post(c, sid, auth, 4)
                assert r.status_code == 200 and r.json()["step"] == 4
                assert c.get(f"/sessions/{sid}", headers=auth).json()["steps"] == 4
            assert c.post("/domains/default/sessions", json={}).status_code == 201
    finally:
        server.stop()


def test_redis_with_a_password_or_an_acl_user_works_and_a_wrong_one_stops_the_start(
    tmp_path: Path,
) -> None:
    """``redis://:password@`` (the default user) and ``redis://user:password@`` (an ACL
    user): sessions, events (the lanes authenticate) and the websocket work; a wrong password
    stops the start with a message naming Redis, never the password."""
    server = RedisServer(
        tmp_path / "redis", "--requirepass", "s3cret-pw",
        "--user", "alice", "on", ">wonder-land", "~*", "&*", "+@all",
    ).start()  # fmt: skip
    try:
        for url in (f"redis://:s3cret-pw@127.0.0.1:{server.port}/0",
                    f"redis://alice:wonder-land@127.0.0.1:{server.port}/0"):  # fmt: skip
            with TestClient(create_app(settings_for(tmp_path, server, url))) as c:
                sid, auth, _ = open_session(c)
                for step in (1, 2):
                    assert post(c, sid, auth, step).status_code == 200
                token = auth["Authorization"].removeprefix("Bearer ")
                with c.websocket_connect(f"/sessions/{sid}/stream?token={token}") as ws:
                    ws.send_text(json.dumps(event(3)))
                    assert json.loads(ws.receive_text())["step"] == 3
                assert c.get("/health/ready").status_code == 200
        wrong = f"redis://:not-it@127.0.0.1:{server.port}/0"
        with (
            pytest.raises(RuntimeError) as failed,
            TestClient(create_app(settings_for(tmp_path, server, wrong))),
        ):
            pass
        assert "ADVISOR_REDIS_URL" in str(failed.value) and "not-it" not in str(failed.value)
    finally:
        server.stop()


def _certificates(home: Path) -> Path:
    """A CA of the test's own and a certificate for 127.0.0.1 it signed (openssl)."""
    home.mkdir(parents=True, exist_ok=True)

    def run(*args: str) -> None:
        subprocess.run(["openssl", *args], cwd=home, check=True, capture_output=True)

    run("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", "ca.key", "-out", "ca.pem",
        "-days", "1", "-subj", "/CN=advisor test CA")  # fmt: skip
    run("req", "-newkey", "rsa:2048", "-nodes", "-keyout", "server.key", "-out", "server.csr",
        "-subj", "/CN=127.0.0.1")  # fmt: skip
    (home / "san.cnf").write_text("subjectAltName=IP:127.0.0.1\n")
    run("x509", "-req", "-in", "server.csr", "-CA", "ca.pem", "-CAkey", "ca.key",
        "-CAcreateserial", "-out", "server.pem", "-days", "1", "-extfile", "san.cnf")  # fmt: skip
    return home


def test_rediss_with_a_ca_of_its_own_works_and_an_unknown_ca_stops_the_start(
    tmp_path: Path,
) -> None:
    """Redis over TLS (``rediss://``, redis-server's own TLS port, a certificate signed by a
    CA made here): with ``?ssl_ca_certs=`` naming the CA, sessions, events (the lanes speak
    TLS) and reads (redis-py's pool) work; without it the certificate is refused and the
    start stops naming Redis."""
    import shutil

    if shutil.which("openssl") is None:
        pytest.skip("openssl is not installed: no certificates for the TLS test")
    certs = _certificates(tmp_path / "redis")
    server = RedisServer(
        tmp_path / "redis", "--tls-cert-file", str(certs / "server.pem"),
        "--tls-key-file", str(certs / "server.key"), "--tls-ca-cert-file",
        str(certs / "ca.pem"), "--tls-auth-clients", "no", tls=True,
    )  # fmt: skip
    try:
        server.start()
    except RuntimeError as exc:
        if "TLS" in str(exc) or "Bad directive" in str(exc):
            pytest.skip(f"this redis-server has no TLS: {str(exc)[-200:]}")
        raise
    try:
        url = f"{server.url}?ssl_ca_certs={certs / 'ca.pem'}"
        with TestClient(create_app(settings_for(tmp_path, server, url))) as c:
            sid, auth, _ = open_session(c)
            for step in (1, 2, 3):
                assert post(c, sid, auth, step).status_code == 200
            assert c.get(f"/sessions/{sid}", headers=auth).json()["steps"] == 3
            assert c.get("/health/ready").status_code == 200
        with (
            pytest.raises(RuntimeError) as failed,
            TestClient(create_app(settings_for(tmp_path, server, server.url))),
        ):
            pass
        assert "ADVISOR_REDIS_URL" in str(failed.value) and "certificate" in str(failed.value)
    finally:
        server.stop()


def test_the_mqtt_bridge_answers_503_on_the_errors_topic_while_redis_is_paused(
    tmp_path: Path, redis_server: RedisServer
) -> None:
    """An MQTT message whose events need a paused Redis: its explorer's errors topic gets
    ``{"detail": "...Redis...", "status": 503, "retry_after": 1}`` and nothing is applied;
    sent again once Redis answers, it is applied once. (The bridge's handling of a message,
    without a broker: what it would publish is what it queues.)"""
    from app.service.mqtt import Bridge, Explorer

    with TestClient(create_app(settings_for(tmp_path, redis_server))) as c:
        state = service_of(c)
        bridge = Bridge(state, "mqtt://127.0.0.1:1", lock_dir=tmp_path)
        topic = "advisor/default/robot-1/events"
        assert c.portal is not None
        c.portal.call(bridge.handle, topic, json.dumps(event(1)).encode())
        (kind, start), (_, decided) = bridge.pending  # the session's start, then the event
        assert kind.endswith("/decisions") and json.loads(start)["step"] == 0
        assert json.loads(decided)["step"] == 1
        bridge.pending.clear()
        redis_server.pause()
        try:
            for _ in range(2):
                c.portal.call(bridge.handle, topic, json.dumps(event(2)).encode())
                ((kind, error),) = bridge.pending
                bridge.pending.clear()
                refused = json.loads(error)
                assert kind == "advisor/default/robot-1/errors"
                assert refused["status"] == 503 and refused["retry_after"] == 1
                assert "Redis" in refused["detail"]
        finally:
            redis_server.resume()
        wait_ready(c)
        c.portal.call(bridge.handle, topic, json.dumps(event(2)).encode())
        ((kind, decided),) = bridge.pending
        assert kind.endswith("/decisions") and json.loads(decided)["step"] == 2
        sid = bridge.sessions[Explorer("robot-1", "default", "robot-1", short=True)].id
        admin = {"X-API-Key": state.admin_key}
        assert c.get(f"/sessions/{sid}", headers=admin).json()["steps"] == 2
