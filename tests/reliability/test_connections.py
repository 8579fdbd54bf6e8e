"""Caps on open connections, over the real server: the cap in all follows the process's
open-files limit, and one client (one address) may hold only its share, so that one slow client
cannot take every place (a slow loris from one address filled the whole cap, and every other
client got 503 until the header timeout).

Connections are raw sockets, bound to a loopback address of their own where a test plays
several clients (Linux's loopback answers all of 127.0.0.0/8). Waits are for conditions with
deadlines, never fixed sleeps."""

from __future__ import annotations

import contextlib
import json
import resource
import select
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from websockets.sync.client import connect as ws_connect

from tests.reliability.conftest import Live, server_errors, start, stop

FILES = 96  # the open-files limit of the first test's server: its cap is this less 64
CLIENT_CAP = 4  # connections one client may hold, in the other tests' server
HEALTH = b"GET /health HTTP/1.1\r\nHost: x\r\n\r\n"


def connect_from(live: Live, address: str = "127.0.0.1") -> socket.socket:
    """A connection to the server from ``address`` (bound before it connects)."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.bind((address, 0))
    sock.connect(("127.0.0.1", live.port))
    return sock


def answered(socks: list[socket.socket], n: int, limit: float = 20.0) -> list[socket.socket]:
    """The first ``n`` of ``socks`` the server answered (or closed), waiting at most ``limit``."""
    deadline = time.monotonic() + limit
    ready: list[socket.socket] = []
    while len(ready) < n and time.monotonic() < deadline:
        waiting = [s for s in socks if s not in ready]
        ready += select.select(waiting, [], [], max(0.0, deadline - time.monotonic()))[0]
    return ready


def refusal(sock: socket.socket) -> tuple[int, str]:
    """The status and detail the server answered before closing (read until it closes)."""
    sock.settimeout(20)
    data = b""
    with contextlib.suppress(ConnectionResetError):
        while chunk := sock.recv(65536):
            data += chunk
    sock.close()
    head, _, body = data.partition(b"\r\n\r\n")
    assert b"content-type: application/json" in head.lower(), head
    return int(head.split(b" ", 2)[1]), str(json.loads(body)["detail"])


def status_of(sock: socket.socket) -> int:
    """Ask /health over ``sock`` (kept alive): the status."""
    sock.sendall(HEALTH)
    sock.settimeout(20)
    data = b""
    while b"\r\n\r\n" not in data:
        chunk = sock.recv(65536)
        assert chunk, f"closed after {data!r}"
        data += chunk
    return int(data.split(b" ", 2)[1])


def served_again(live: Live, address: str = "127.0.0.1", limit: float = 20.0) -> bool:
    """Whether a new connection from ``address`` gets 200 from /health within ``limit`` (the
    server lets a closed connection go when it reads its end)."""
    deadline = time.monotonic() + limit
    transport = httpx.HTTPTransport(local_address=address)
    with httpx.Client(base_url=live.url, timeout=10, transport=transport) as http:
        while time.monotonic() < deadline:
            with contextlib.suppress(httpx.TransportError):
                if http.get("/health", headers={"Connection": "close"}).status_code == 200:
                    return True
            time.sleep(0.05)
    return False


def few_files() -> None:
    """In the server's process before it starts: at most ``FILES`` open files."""
    _, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (FILES, hard))


def test_the_connection_cap_is_lowered_to_the_open_files_limit(tmp_path: Path) -> None:
    cap, extra = FILES - 64, 4
    live = start(tmp_path / "data", preexec_fn=few_files, ADVISOR_HEADER_TIMEOUT="60")
    socks: list[socket.socket] = []
    try:
        assert f"max_connections 1000 lowered to {cap} (open files limit {FILES})" in (
            live.log.read_text()
        )
        socks = [connect_from(live) for _ in range(cap + extra)]
        refused = answered(socks, extra)
        assert len(refused) == extra
        for sock in refused:
            status, detail = refusal(sock)
            assert status == 503
            assert detail == f"the service holds its maximum of {cap} connections"
        held = [s for s in socks if s not in refused]
        assert [status_of(s) for s in held] == [200] * cap  # every one within the cap served
        for sock in held:
            sock.close()
        assert served_again(live)  # the server still answers once they close
    finally:
        for sock in socks:
            sock.close()
        stop(live)
    assert server_errors(live) == []


@pytest.fixture(scope="module")
def capped(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    """A server whose clients may hold ``CLIENT_CAP`` connections each; 127.0.0.3 is a
    trusted proxy."""
    server = start(
        tmp_path_factory.mktemp("capped") / "data",
        ADVISOR_CLIENT_MAX_CONNECTIONS=str(CLIENT_CAP),
        ADVISOR_HEADER_TIMEOUT="60",
        ADVISOR_TRUSTED_PROXIES='["127.0.0.3"]',
    )
    yield server
    stop(server)
    assert server_errors(server) == []


def test_a_slow_client_holds_its_own_share_and_others_are_served(capped: Live) -> None:
    slow = [connect_from(capped) for _ in range(CLIENT_CAP)]
    stop_trickle = threading.Event()

    def trickle() -> None:  # a slow loris: one header byte on each socket every 0.5 s
        for byte in b"GET /health HTTP/1.1\r\nHost: x\r\nX-Slow: " + b"a" * 200:
            for sock in slow:
                with contextlib.suppress(OSError):
                    sock.send(bytes([byte]))
            if stop_trickle.wait(0.5):
                return

    thread = threading.Thread(target=trickle)
    thread.start()
    try:
        extra = [connect_from(capped) for _ in range(3)]
        for sock in extra:  # beyond its share: refused at once, saying which limit
            status, detail = refusal(sock)
            assert status == 429
            assert detail.startswith(
                f"this client (address 127.0.0.1) holds {CLIENT_CAP} open connections"
            )
            assert "ADVISOR_CLIENT_MAX_CONNECTIONS" in detail
        assert select.select(slow, [], [], 0)[0] == []  # the slow ones are still open
        # another client is served meanwhile
        other = httpx.HTTPTransport(local_address="127.0.0.2")
        with httpx.Client(base_url=capped.url, timeout=30, transport=other) as http:
            assert http.get("/health").status_code == 200
        # a trusted proxy speaks for many clients: not capped
        proxy = [connect_from(capped, "127.0.0.3") for _ in range(CLIENT_CAP + 2)]
        assert [status_of(s) for s in proxy] == [200] * (CLIENT_CAP + 2)
        for sock in proxy:
            sock.close()
    finally:
        stop_trickle.set()
        thread.join()
        for sock in slow:
            sock.close()
    assert served_again(capped)  # its places come back when it lets go


def test_websockets_take_their_clients_places_and_give_them_back(capped: Live) -> None:
    made = httpx.post(f"{capped.url}/domains/default/sessions", json={}, timeout=30)
    assert made.status_code == 201, made.text
    session = made.json()
    url = f"ws://127.0.0.1:{capped.port}/sessions/{session['session_id']}/stream"
    auth = {"Authorization": f"Bearer {session['token']}"}
    # refused handshakes give their place back: twice the share, one after another
    for _ in range(2 * CLIENT_CAP):
        sock = connect_from(capped)
        sock.sendall(b"GET /x HTTP/1.1\r\nHost: x\r\nConnection: Upgrade\r\nUpgrade: websocket"
                     b"\r\nSec-WebSocket-Version: 13\r\n\r\n")  # fmt: skip
        assert refusal(sock) == (400, "the websocket handshake is invalid: missing "
                                 "Sec-WebSocket-Key header")  # fmt: skip
    with contextlib.ExitStack() as stack:
        streams = [stack.enter_context(ws_connect(url, additional_headers=auth))
                   for _ in range(CLIENT_CAP)]  # fmt: skip
        event = {"state": session["decision"]["state"], "action": "E"}
        streams[0].send(json.dumps(event))
        assert json.loads(streams[0].recv(timeout=30))["step"] == 1
        status, detail = refusal(connect_from(capped))  # its share is taken by websockets
        assert status == 429 and "ADVISOR_CLIENT_MAX_CONNECTIONS" in detail
    assert served_again(capped)  # closed websockets give their places back
