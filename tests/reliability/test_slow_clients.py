"""Headers and slow clients over the real server (the issue: a 48 MB header was accepted and
other clients waited 5.8 s; a 64 KiB header got 200; 300 sockets trickling a header byte every
5 s stayed open, and under a lower descriptor limit new clients were refused).

Each refusal is a JSON answer and the connection closes: 431 for headers over 16 KiB, 408 for
headers or a body that do not arrive in time, 503 beyond the connection cap, 400 for what is
not HTTP. Waits are bounded reads, never assertions on time."""

from __future__ import annotations

import contextlib
import json
import socket
import threading
import time
from collections.abc import Iterator

import httpx
import pytest

from tests.reliability.conftest import Live, start, stop
from tests.reliability.soak import rss_mib

CAP = 40


@pytest.fixture(scope="module")
def guarded(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    server = start(
        tmp_path_factory.mktemp("guard") / "data",
        log_level="info",
        ADVISOR_HEADER_TIMEOUT="1",
        ADVISOR_BODY_TIMEOUT="1",
        ADVISOR_MAX_CONNECTIONS=str(CAP),
    )
    yield server
    stop(server)
    log = server.log.read_text(errors="replace")
    assert "Traceback" not in log and "Exception in ASGI application" not in log


def answer(sock: socket.socket, limit: float = 20.0) -> tuple[int, dict[str, object]]:
    """The status and JSON body the server answered before closing (read until it closes)."""
    sock.settimeout(limit)
    data = b""
    try:
        while chunk := sock.recv(65536):
            data += chunk
    except (ConnectionResetError, TimeoutError):
        pass
    sock.close()
    head, _, body = data.partition(b"\r\n\r\n")
    status = int(head.split(b" ", 2)[1])
    return status, json.loads(body)


def connect(live: Live) -> socket.socket:
    return socket.create_connection(("127.0.0.1", live.port))


def header_request(size: int) -> bytes:
    return b"GET /health HTTP/1.1\r\nHost: x\r\nX-Pad: " + b"a" * size + b"\r\n\r\n"


def test_headers_over_16_kib_are_431_and_under_it_answered(guarded: Live) -> None:
    for size in (16_400, 65_536):  # in one piece
        sock = connect(guarded)
        sock.sendall(header_request(size))
        status, body = answer(sock)
        assert status == 431 and "larger than 16384 bytes" in str(body["detail"])
    sock = connect(guarded)
    sock.sendall(header_request(15_000))
    assert sock.recv(12).startswith(b"HTTP/1.1 200")
    sock.close()


def test_a_48_mb_header_is_refused_without_holding_it_or_others(guarded: Live) -> None:
    before = rss_mib(guarded.pid())
    sock = connect(guarded)
    sent = 0
    others: list[int] = []

    def other_client() -> None:
        others.append(httpx.get(f"{guarded.url}/health", timeout=30).status_code)

    other = threading.Thread(target=other_client)
    try:
        sock.sendall(b"GET /health HTTP/1.1\r\nHost: x\r\nX-Big: ")
        other.start()
        while sent < 48 * 1024 * 1024:
            sock.sendall(b"a" * 65536)
            sent += 65536
    except (BrokenPipeError, ConnectionResetError):
        pass  # the server refused and closed: the rest is never read
    status, body = answer(sock)
    other.join()
    grown = rss_mib(guarded.pid()) - before
    print(f"\n48 MB header: refused after {sent} bytes sent; RSS +{grown:.1f} MiB")
    assert status == 431, body
    assert sent < 48 * 1024 * 1024
    assert grown < 8.0
    assert others == [200]


def test_slow_headers_and_bodies_are_408_and_the_connection_cap_holds(guarded: Live) -> None:
    slow = [connect(guarded) for _ in range(CAP + 10)]  # more than the cap
    stop_trickle = threading.Event()

    def trickle() -> None:  # one header byte every 0.2 s on every socket, as a slow loris
        for byte in b"GET /health HTTP/1.1\r\nHost: x\r\nX-Slow: " + b"a" * 1000:
            for sock in slow:
                with contextlib.suppress(OSError):
                    sock.send(bytes([byte]))
            if stop_trickle.wait(0.2):
                return

    thread = threading.Thread(target=trickle)
    thread.start()
    try:
        answers = [answer(sock) for sock in slow]
    finally:
        stop_trickle.set()
        thread.join()
    statuses = sorted(status for status, _ in answers)
    assert set(statuses) == {408, 503}
    assert statuses.count(503) >= 10  # at least those beyond the cap
    timed_out = next(body for status, body in answers if status == 408)
    assert "headers did not arrive within 1 s" in str(timed_out["detail"])
    # the slow ones are gone: a new client is served
    assert httpx.get(f"{guarded.url}/health", timeout=30).status_code == 200
    # a body that trickles: 408 too
    sock = connect(guarded)
    sock.sendall(
        b"POST /domains/default/sessions HTTP/1.1\r\nHost: x\r\nContent-Type: application/json"
        b"\r\nContent-Length: 100\r\n\r\n{"
    )
    status, body = answer(sock)
    assert status == 408 and "body did not arrive" in str(body["detail"])


def test_what_is_not_http_gets_a_json_400(guarded: Live) -> None:
    for garbage in (b"GARBAGE\r\n\r\n", b"GET / HTTP/1.1\r\nHost: x\r\nBad Header\r\n\r\n",
                    b"\x16\x03\x01\x02\x00\x01\x00\x01\xfc\x03\x03"):  # fmt: skip
        sock = connect(guarded)
        sock.sendall(garbage)
        status, body = answer(sock)
        assert status == 400 and "not valid HTTP/1.1" in str(body["detail"])
    time.sleep(0.1)
