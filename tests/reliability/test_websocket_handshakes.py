"""Websocket handshakes that fail, over the real server: every refusal is a JSON 4xx that says
what was wrong (uvicorn's websockets answered 400 text/plain "Failed to open a WebSocket
connection: ..." to a malformed handshake, and 403 with an empty body to a websocket at a path
with no websocket route). Sent as raw bytes over a socket; each answer is read until the server
closes the connection."""

from __future__ import annotations

import json
import socket

import httpx
import pytest

from tests.reliability.conftest import Live, server_errors

KEY = "dGhlIHNhbXBsZSBub25jZQ=="  # RFC 6455's sample key: 16 bytes in base64


def handshake(live: Live, path: str, headers: dict[str, str]) -> tuple[int, dict[str, str], bytes]:
    """Send an upgrade request for ``path`` with ``headers`` (after Host, Connection and
    Upgrade); the status, headers (lower-case names) and body of the answer."""
    lines = [f"GET {path} HTTP/1.1", "Host: 127.0.0.1", "Connection: Upgrade", "Upgrade: websocket"]
    lines += [f"{name}: {value}" for name, value in headers.items()]
    with socket.create_connection(("127.0.0.1", live.port)) as sock:
        sock.sendall(("\r\n".join(lines) + "\r\n\r\n").encode())
        sock.settimeout(20)
        data = b""  # a refusal: read until the server closes; 101: until the headers are in
        while b"\r\n\r\n" not in data or not data.startswith(b"HTTP/1.1 101"):
            chunk = sock.recv(65536)
            if not chunk:
                break
            data += chunk
    head, _, body = data.partition(b"\r\n\r\n")
    status_line, *header_lines = head.decode("latin-1").split("\r\n")
    fields = dict(line.split(": ", 1) for line in header_lines)
    return int(status_line.split(" ")[1]), {k.lower(): v for k, v in fields.items()}, body


@pytest.fixture(scope="module")
def session(live: Live) -> dict[str, str]:
    r = httpx.post(f"{live.url}/domains/default/sessions", json={}, timeout=30)
    assert r.status_code == 201, r.text
    made: dict[str, str] = r.json()
    return made


def stream(session: dict[str, str]) -> tuple[str, dict[str, str]]:
    """The session's websocket path and a valid handshake with its token."""
    path = f"/sessions/{session['session_id']}/stream"
    return path, {"Sec-WebSocket-Key": KEY, "Sec-WebSocket-Version": "13",
                  "Authorization": f"Bearer {session['token']}"}  # fmt: skip


def test_a_valid_handshake_still_opens_the_stream(live: Live, session: dict[str, str]) -> None:
    path, headers = stream(session)
    status, fields, _ = handshake(live, path, headers)
    assert status == 101
    assert fields["sec-websocket-accept"] == "s3pPLMBiTxaQ9kYGzzhZRbK+xOo="  # RFC 6455's


@pytest.mark.parametrize(
    ("change", "status", "words"),
    [
        ({"Sec-WebSocket-Key": None}, 400, "missing Sec-WebSocket-Key header"),
        ({"Sec-WebSocket-Key": "abc"}, 400, "invalid Sec-WebSocket-Key header: abc"),
        ({"Sec-WebSocket-Key": "c2hvcnQ="}, 400, "invalid Sec-WebSocket-Key header: c2hvcnQ="),
        ({"Sec-WebSocket-Version": "8"}, 400, "invalid Sec-WebSocket-Version header: 8"),
        ({"Sec-WebSocket-Version": None}, 400, "missing Sec-WebSocket-Version header"),
        ({"X-Long": "a" * 9000}, 431, "headers are too large (line too long)"),
    ],
)
def test_a_malformed_handshake_is_a_json_4xx_that_names_the_problem(
    live: Live, session: dict[str, str], change: dict[str, str | None], status: int, words: str
) -> None:
    path, headers = stream(session)
    for name, value in change.items():
        if value is None:
            del headers[name]
        else:
            headers[name] = value
    got, fields, body = handshake(live, path, headers)
    assert got == status, body
    assert fields["content-type"] == "application/json"
    detail = json.loads(body)["detail"]
    assert words in detail
    if status == 400:
        assert detail.startswith("the websocket handshake is invalid: ")


@pytest.mark.parametrize("path", ["/x", "/health", "/static/walk.js", "/sessions/abc/stream/x"])
def test_a_websocket_where_no_websocket_route_is_a_json_404(live: Live, path: str) -> None:
    status, fields, body = handshake(
        live, path, {"Sec-WebSocket-Key": KEY, "Sec-WebSocket-Version": "13"}
    )
    assert status == 404, body
    assert fields["content-type"] == "application/json"
    assert json.loads(body) == {"detail": f"no websocket route at {path}"}


def test_refused_handshakes_are_counted_and_log_no_error(live: Live) -> None:
    handshake(live, "/nowhere", {"Sec-WebSocket-Key": KEY, "Sec-WebSocket-Version": "13"})
    metrics = httpx.get(f"{live.url}/metrics", timeout=30).text
    assert any(
        line.startswith("advisor_http_requests_total{") and 'method="WS"' in line
        and 'status="404"' in line
        for line in metrics.splitlines()
    )  # fmt: skip
    assert server_errors(live) == []
