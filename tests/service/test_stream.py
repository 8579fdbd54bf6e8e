"""The websocket stream: decisions in order, error frames that keep it usable, close codes."""

from __future__ import annotations

import json

import pytest
from fastapi.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

from app.service.state import ServiceState
from tests.service.conftest import open_session

E = {"state": [28, 0], "action": "E"}
W = {"state": [28, 1], "action": "W"}


def test_stream_answers_each_frame_in_order(client: TestClient) -> None:
    sid, auth, created = open_session(client)
    token = created["token"]
    with client.websocket_connect(f"/sessions/{sid}/stream?token={token}") as ws:
        ws.send_text(json.dumps(E))
        one = json.loads(ws.receive_text())
        assert one["step"] == 1 and one["state"] == [28, 1]
        ws.send_text(json.dumps([W, E] * 50))
        many = json.loads(ws.receive_text())
        assert [d["step"] for d in many] == list(range(2, 102))
    r = client.post(f"/sessions/{sid}/events", json=W, headers=auth)
    assert r.json()["step"] == 102  # REST and websocket advance the same session


def test_stream_accepts_the_bearer_header(client: TestClient) -> None:
    sid, auth, _ = open_session(client)
    with client.websocket_connect(f"/sessions/{sid}/stream", headers=auth) as ws:
        ws.send_text(json.dumps(E))
        assert json.loads(ws.receive_text())["step"] == 1


def test_stream_bad_frames_get_error_frames_and_the_stream_stays_usable(
    client: TestClient, service: ServiceState
) -> None:
    service.settings.max_batch_events = 5
    sid, _, created = open_session(client)
    with client.websocket_connect(f"/sessions/{sid}/stream?token={created['token']}") as ws:
        for frame, status, message in [
            ("not json", 422, "send JSON"),
            ('{"state": [28, 0], "action": "Q"}', 422, "event.action: an action is"),
            ('{"state": [27, 0], "action": "N"}', 422, "event 0: state [27, 0] is a wall"),
            ('{"state": [28, 0], "next_state": [26, 0]}', 422, "is not one move"),
            (json.dumps([E] * 6), 413, "at most 5"),
        ]:
            ws.send_text(frame)
            error = json.loads(ws.receive_text())
            assert error == {"detail": error["detail"], "status": status}
            assert message in error["detail"]
        ws.send_bytes(b"\x00\x01")
        assert "text frames" in json.loads(ws.receive_text())["detail"]
        ws.send_text(json.dumps(E))
        assert json.loads(ws.receive_text())["step"] == 1  # nothing refused was applied


def test_stream_refuses_oversize_messages(client: TestClient, service: ServiceState) -> None:
    sid, _, created = open_session(client)
    with client.websocket_connect(f"/sessions/{sid}/stream?token={created['token']}") as ws:
        ws.send_text(" " * (service.settings.max_body_bytes + 1))
        assert json.loads(ws.receive_text())["status"] == 413


@pytest.mark.parametrize(("query", "code"), [("", 4401), ("?token=wrong", 4403)])
def test_stream_without_the_right_token_is_closed_with_a_reason(
    client: TestClient, query: str, code: int
) -> None:
    sid, _, _ = open_session(client)
    with (
        client.websocket_connect(f"/sessions/{sid}/stream{query}") as ws,
        pytest.raises(WebSocketDisconnect) as closed,
    ):
        ws.receive_text()
    assert closed.value.code == code and closed.value.reason


def test_stream_with_another_sessions_token_is_4403(client: TestClient) -> None:
    sid, _, _ = open_session(client)
    _, _, other = open_session(client)
    with (
        client.websocket_connect(f"/sessions/{sid}/stream?token={other['token']}") as ws,
        pytest.raises(WebSocketDisconnect) as closed,
    ):
        ws.receive_text()
    assert closed.value.code == 4403


def test_stream_of_an_unknown_session_is_4404(client: TestClient) -> None:
    with (
        client.websocket_connect("/sessions/0123456789abcdef/stream?token=x") as ws,
        pytest.raises(WebSocketDisconnect) as closed,
    ):
        ws.receive_text()
    assert closed.value.code == 4404


def test_stream_closes_when_its_session_ends(client: TestClient) -> None:
    sid, auth, created = open_session(client)
    with client.websocket_connect(f"/sessions/{sid}/stream?token={created['token']}") as ws:
        ws.send_text(json.dumps(E))
        ws.receive_text()
        assert client.delete(f"/sessions/{sid}", headers=auth).status_code == 200
        ws.send_text(json.dumps(W))
        with pytest.raises(WebSocketDisconnect) as closed:
            ws.receive_text()
    assert closed.value.code == 4404
