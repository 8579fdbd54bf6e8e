"""No secret reaches the log: uvicorn's access log writes every URL, and a websocket carries
its session token in the URL (``?token=...``); the token is written as ``***``."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import httpx
import pytest
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect
from websockets.typing import Subprotocol

from app.service.security import RedactTokens, redact
from tests.reliability.conftest import start, stop


def test_redact_hides_token_values_and_keeps_the_rest() -> None:
    assert redact("/sessions/ab/stream?token=s3cr3t&format=binary") == (
        "/sessions/ab/stream?token=***&format=binary"
    )
    assert redact("/x?a=1&TOKEN=zz") == "/x?a=1&TOKEN=***"
    assert redact("/x?api_key=k#frag") == "/x?api_key=***#frag"
    assert redact("/sessions/ab/events") == "/sessions/ab/events"


def test_the_filter_rewrites_uvicorn_s_access_record() -> None:
    record = logging.LogRecord(
        "uvicorn.access", logging.INFO, __file__, 1, '%s - "%s %s HTTP/%s" %d',
        ("127.0.0.1:5", "GET", "/sessions/a/stream?token=abc", "1.1", 101), None,
    )  # fmt: skip
    assert RedactTokens().filter(record)
    assert "abc" not in record.getMessage() and "token=***" in record.getMessage()


def test_a_live_server_logs_no_session_token_nor_admin_key(tmp_path: Path) -> None:
    # a configured admin key (a generated one: the next test)
    key = "configured-admin-key-for-this-test"
    # event routes logged too (by default they are counted, not logged)
    live = start(
        tmp_path / "data", log_level="info", ADVISOR_ADMIN_KEY=key, ADVISOR_ACCESS_LOG_EVENTS="true"
    )
    try:
        with httpx.Client(base_url=live.url, timeout=10) as http:
            created = http.post("/domains/default/sessions", json={}).json()
            sid, token = created["session_id"], created["token"]
            ws_url = live.url.replace("http", "ws") + f"/sessions/{sid}/stream?token={token}"
            with connect(ws_url) as ws:
                ws.send(json.dumps({"state": created["decision"]["state"], "action": "E"}))
                assert json.loads(ws.recv())["step"] == 1
            # as the /walk page connects: the token as a subprotocol, the server answering
            # "advisor" (a browser needs one of its offers back), never the token
            plain = live.url.replace("http", "ws") + f"/sessions/{sid}/stream"
            offer = [Subprotocol("advisor"), Subprotocol(f"token.{token}")]
            with connect(plain, subprotocols=offer) as ws:
                assert ws.subprotocol == "advisor"
                ws.send(json.dumps({"state": [28, 1], "action": "W"}))
                assert json.loads(ws.recv())["step"] == 2
            with connect(plain, subprotocols=[Subprotocol("advisor")]) as ws:  # no token
                with pytest.raises(ConnectionClosed) as closed:
                    ws.send("{}")
                    ws.recv()
                assert closed.value.rcvd is not None and closed.value.rcvd.code == 4401
            r = http.get(f"/sessions/{sid}", headers={"Authorization": f"Bearer {token}"})
            assert r.status_code == 200
            assert http.get("/domains", headers=live.admin).status_code == 200
    finally:
        stop(live)
    text = live.log.read_text(errors="replace")
    assert f"/sessions/{sid}/stream?token=***" in text  # the access log was written
    assert text.count(f"/sessions/{sid}/stream") >= 3
    assert token not in text
    assert key not in text


def test_generated_keys_are_never_logged_only_where_they_are_kept(tmp_path: Path) -> None:
    """At first start the service generates the admin and operator keys; its log (uvicorn's,
    at info, and what ``serve`` writes itself) says where each is kept, not the key."""
    live = start(tmp_path / "data", log_level="info")
    try:
        with httpx.Client(base_url=live.url, timeout=10) as http:
            assert http.get("/domains", headers=live.admin).status_code == 200
    finally:
        stop(live)
    text = live.log.read_text(errors="replace")
    for name in ("admin_key", "operator_key"):
        path = live.data_dir / name
        assert f"kept in {path} (mode 0600" in text, text[-2000:]
        assert path.read_text().strip() not in text
