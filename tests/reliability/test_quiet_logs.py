"""Clients that hang up are not errors: a client that disconnects while its body arrives, or a
websocket client that vanishes before its answers, leaves no "Exception in ASGI application"
and no traceback in the server's log (the issue: both logged tracebacks)."""

from __future__ import annotations

import json
import socket
import struct
import time
from pathlib import Path

import httpx
from websockets.sync.client import connect

from tests.reliability.conftest import start, stop


def _reset(sock: socket.socket) -> None:
    """Close with a TCP reset (SO_LINGER 0): the client is gone at once (a socket the client
    library closed already, as it does when the server refuses a handshake, is gone too)."""
    if sock.fileno() < 0:
        return
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    sock.close()


def test_clients_hanging_up_leave_no_traceback(tmp_path: Path) -> None:
    live = start(tmp_path / "data", log_level="info")
    try:
        created = httpx.post(f"{live.url}/domains/default/sessions", json={}).json()
        sid, token = created["session_id"], created["token"]
        bearer = f"Authorization: Bearer {token}\r\n"
        admin = f"X-API-Key: {live.admin_key}\r\n"
        routes = [
            ("POST", f"/sessions/{sid}/events", bearer),
            ("POST", f"/sessions/{sid}/positions", bearer),
            ("POST", "/domains/default/trajectories", admin),
            ("POST", "/domains/default/sessions", ""),
            ("PUT", "/domains/gone", admin),
        ]
        for method, path, extra in routes:  # 10 of 100,000 promised bytes, then gone
            sock = socket.create_connection(("127.0.0.1", live.port))
            head = f"{method} {path} HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
            sock.sendall(f"{head}Content-Length: 100000\r\n{extra}\r\n".encode() + b"[" * 10)
            time.sleep(0.2)
            _reset(sock)
        events = json.dumps([{"state": [28, 0], "action": "E"}, {"state": [28, 1], "action": "W"}]
                            * 2500)  # fmt: skip
        url = live.url.replace("http", "ws") + f"/sessions/{sid}/stream"
        for frames in (0, 1, 20):  # gone at once, after one frame, with 20 answers pending
            ws = connect(url, additional_headers={"Authorization": f"Bearer {token}"},
                         max_size=None)  # fmt: skip
            for _ in range(frames):
                ws.send(events)
            _reset(ws.socket)
        bad = connect(f"{url}?token=wrong")  # refused: the server closes it; the client is gone
        _reset(bad.socket)
        time.sleep(1.0)
        assert httpx.get(f"{live.url}/health").status_code == 200
    finally:
        stop(live)
    log = live.log.read_text(errors="replace")
    assert "Exception in ASGI application" not in log
    assert "Traceback" not in log
