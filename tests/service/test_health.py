"""Liveness and readiness: ``/health/live`` asks nothing of anything; ``/health/ready`` (and
``/health``, as it always answered) lists every dependency and fails only for the database
and a configured Redis, never for the MQTT bridge or the viewer."""

from __future__ import annotations

import socket
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

from fastapi.testclient import TestClient

from app.service.main import create_app
from tests.client.conftest import free_port
from tests.service.conftest import make_settings


def test_liveness_touches_nothing_and_readiness_lists_every_dependency(
    client: TestClient,
) -> None:
    r = client.get("/health/live")
    assert r.status_code == 200 and set(r.json()) == {"status", "version", "uptime_seconds"}
    for path in ("/health", "/health/ready"):
        r = client.get(path)
        assert r.status_code == 200, r.text
        body = r.json()
        assert body["status"] == "ok" and body["database"] == "sqlite"  # as before
        assert {"version", "domains", "sessions", "uptime_seconds"} <= set(body)
        deps = body["dependencies"]
        assert deps["database"] == {"state": "up", "required": True, "detail": None}
        assert deps["redis"]["state"] == "not used" and not deps["redis"]["required"]
        assert deps["mqtt"]["state"] == "off" and deps["viewer"]["state"] == "off"
    for path in ("/health", "/health/ready", "/health/live"):
        r = client.head(path)
        assert r.status_code == 200 and r.content == b""


def test_a_bridge_without_its_broker_and_a_viewer_not_running_never_fail_readiness(
    tmp_path: Path,
) -> None:
    viewer_port, broker_port = free_port(), free_port()  # nothing listens at either
    settings = make_settings(
        tmp_path / "data", viewer_enabled=True, viewer_port=viewer_port,
        mqtt_url=f"mqtt://127.0.0.1:{broker_port}",
    )  # fmt: skip
    with TestClient(create_app(settings)) as c:
        r = c.get("/health/ready")
        assert r.status_code == 200, r.text
        deps = r.json()["dependencies"]
        assert deps["mqtt"]["state"] == "not connected" and not deps["mqtt"]["required"]
        assert deps["viewer"]["state"] == "not listening" and not deps["viewer"]["required"]
        with socket.create_server(("127.0.0.1", viewer_port)) as silent:  # accepts, says nothing
            r = c.get("/health/ready")
            assert r.json()["dependencies"]["viewer"]["state"] == "not listening"
            silent.close()
        with http_server(viewer_port) as requests:  # the viewer's port answers HTTP
            r = c.get("/health/ready")
            assert r.status_code == 200
            assert r.json()["dependencies"]["viewer"]["state"] == "listening"
        # a request, not a bare connection (which the viewer logs as a failed handshake)
        assert requests == ["GET / HTTP/1.1"]


@contextmanager
def http_server(port: int) -> Iterator[list[str]]:
    """An HTTP server at ``port`` answering 200 to anything; yields the request lines."""
    lines: list[str] = []

    class Answer(BaseHTTPRequestHandler):
        def do_GET(self) -> None:
            lines.append(self.requestline)
            self.send_response(200)
            self.end_headers()

        def log_message(self, *args: object) -> None:
            pass

    server = ThreadingHTTPServer(("127.0.0.1", port), Answer)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield lines
    finally:
        server.shutdown()
        server.server_close()
