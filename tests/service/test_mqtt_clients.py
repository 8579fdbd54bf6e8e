"""The MQTT bridge's clients: devices under the broker's ACL, their quotas, message sizes and
the log under a flood. Brokers: one of the test's own started from deploy/mosquitto/ (its
password file and ACL), one of the test's own with no limits, a fake one that ignores the
bridge's Maximum Packet Size, and the machine's (127.0.0.1:1883, topics of each test's own)."""

from __future__ import annotations

import asyncio
import json
import logging
import socket
import threading
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import aiomqtt
import pytest
import redis
from fastapi.testclient import TestClient

from app.service import ops
from app.service.live.sessions import StoreUnavailable
from app.service.main import create_app
from app.service.mqtt import MQTT_END, PACKET_HEADROOM, Bridge
from tests.client.test_client import run_async
from tests.service.conftest import (
    REDIS_URL,
    drop_redis_keys,
    make_settings,
    redis_prefix,
    redis_problem,
)
from tests.service.test_mqtt import (
    HOST,
    PORT,
    Peer,
    connected,
    free_port,
    needs_broker,
    needs_mosquitto,
    own_broker,
    prefix,
    service,
    wait_until,
)
from tests.test_compose import Device, deploy_broker
from tests.test_compose import needs_mosquitto as needs_mosquitto_passwd

__all__ = ["prefix"]  # the fixture, shared with test_mqtt.py

EVENT = {"state": [28, 0], "action": "E"}  # default's start, one step east


def bridge_of(client: TestClient) -> Bridge:
    bridge: Bridge = client.app.state.bridge  # type: ignore[attr-defined]
    return bridge


# ---- devices under the ACL ---------------------------------------------------------------------
def test_through_the_acl_each_device_is_the_client_of_its_own_explorers_only(
    tmp_path: Path,
) -> None:
    """deploy/mosquitto/ (its mosquitto.conf and ACL, a password file): the service's user
    reads every device's events; a device's events under another device's name never reach
    the bridge, and it reads only its own decisions; each session counts against the device
    that published it (``mqtt <device>``), in both forms of the topics."""
    needs_mosquitto_passwd()
    users = {"advisor": "service-pw", "robot-7": "seven-pw", "robot-8": "eight-pw"}
    (tmp_path / "broker").mkdir()
    broker, port = deploy_broker(tmp_path / "broker", users)
    try:
        url = f"mqtt://advisor:{users['advisor']}@{HOST}:{port}"
        with TestClient(create_app(make_settings(tmp_path / "data", mqtt_url=url))) as client:
            wait_until(lambda: connected(client), what="the bridge to connect")
            seven = Device(port, "robot-7", users["robot-7"])
            eight = Device(port, "robot-8", users["robot-8"])
            try:
                seven.subscribe("advisor/#")
                eight.subscribe("advisor/#")
                event = json.dumps(EVENT)
                seven.publish("advisor/robot-7/default/e1/events", event)
                seven.publish("advisor/robot-8/default/e2/events", event)  # as another device
                seven.publish("advisor/default/robot-8/events", event)  # as another, short form
                seven.publish("advisor/default/robot-7/events", event)  # its own, short form
                eight.publish("advisor/robot-8/default/e1/events", event)
                wait_until(lambda: len(seven.received()) == 4, what="robot-7's decisions")
                wait_until(lambda: len(eight.received()) == 2, what="robot-8's decisions")
            finally:
                seven.close()
                eight.close()
            bridge = bridge_of(client)
            assert bridge.handled == 3  # the forged ones never reached it
            assert {t for t, _ in seven.received()} == {
                "advisor/robot-7/default/e1/decisions", "advisor/default/robot-7/decisions"
            }  # fmt: skip
            assert {t for t, _ in eight.received()} == {"advisor/robot-8/default/e1/decisions"}
            clients = {(k.device, k.explorer): s.client for k, s in bridge.sessions.items()}
            assert clients == {
                ("robot-7", "e1"): "mqtt robot-7",
                ("robot-7", "robot-7"): "mqtt robot-7",
                ("robot-8", "e1"): "mqtt robot-8",
            }
            registry = client.app.state.service.sessions.registry  # type: ignore[attr-defined]
            assert registry.client_usage("mqtt robot-7")[0] == 2
            assert registry.client_usage("mqtt robot-8")[0] == 1
    finally:
        broker.terminate()
        broker.wait(10)


# ---- quotas ------------------------------------------------------------------------------------
@needs_broker
@pytest.mark.parametrize("store", ["local", "redis"])
def test_sessions_over_mqtt_count_against_the_devices_quota_and_the_services_caps(
    tmp_path: Path, prefix: str, store: str
) -> None:
    """ADVISOR_CLIENT_MAX_SESSIONS 2 and ADVISOR_MAX_SESSIONS 5: a device's third explorer is
    refused on its errors topic (429, naming the device and the setting), in either form of
    the topics, while another device and a REST client still open sessions; at five in all,
    devices get 503 on their errors topic as REST clients get 503. The same with the sessions
    in Redis, where the device's quota is Redis's hash of the client ``mqtt <device>``."""
    extra: dict[str, Any] = {}
    keys = ""
    if store == "redis":
        problem = redis_problem()
        if problem:
            pytest.skip(f"Redis at {REDIS_URL}: {problem}")
        keys = redis_prefix()
        extra = {"redis_url": REDIS_URL, "redis_prefix": keys}
    try:
        with service(tmp_path, PORT, prefix, client_max_sessions=2, max_sessions=5, **extra) as c:
            wait_until(lambda: connected(c), what="the bridge to connect")
            peer = Peer(PORT, prefix)
            try:
                for explorer in ("e1", "e2"):
                    peer.publish(f"dev-a/default/{explorer}/events", EVENT)
                    peer.wait(f"dev-a/default/{explorer}/decisions", 2)
                peer.publish("dev-a/default/e3/events", EVENT)
                (quota,) = peer.wait("dev-a/default/e3/errors", 1)
                peer.publish("default/dev-a/events", EVENT)  # the short form: dev-a too
                (short,) = peer.wait("default/dev-a/errors", 1)
                peer.publish("dev-b/default/e1/events", EVENT)  # another device
                assert len(peer.wait("dev-b/default/e1/decisions", 2)) == 2
                for _ in range(2):  # a REST client: its own quota
                    assert c.post("/domains/default/sessions", json={}).status_code == 201
                peer.publish("dev-b/default/e2/events", EVENT)  # the sixth in all
                (full,) = peer.wait("dev-b/default/e2/errors", 1)
                admin = {"X-API-Key": c.app.state.service.admin_key}  # type: ignore[attr-defined]
                rest = c.post("/domains/default/sessions", json={}, headers=admin)
                assert c.get("/health").json()["sessions"] == 5
            finally:
                peer.close()
            assert peer.got("dev-a/default/e3/decisions") == []
            assert peer.got("dev-b/default/e2/decisions") == []
            for refused in (quota, short):
                assert refused["status"] == 429, refused
                assert refused["detail"].startswith(
                    "this client (mqtt dev-a) holds 2 live sessions"
                )
                assert "ADVISOR_CLIENT_MAX_SESSIONS" in refused["detail"]
                assert MQTT_END in refused["detail"]
            assert full["status"] == 503 and "maximum of 5 live sessions" in full["detail"]
            assert rest.status_code == 503 and "maximum of 5 live sessions" in rest.text
            if store == "redis":
                held = redis.Redis.from_url(REDIS_URL, decode_responses=True)
                assert held.hget(f"{keys}:c:mqtt dev-a", "n") == "2"
                assert held.hget(f"{keys}:c:mqtt dev-b", "n") == "1"
                assert held.hget(f"{keys}:c:address testclient", "n") == "2"
                held.close()
            else:
                registry = c.app.state.service.sessions.registry  # type: ignore[attr-defined]
                assert registry.client_usage("mqtt dev-a")[0] == 2
                assert registry.client_usage("address testclient")[0] == 2
    finally:
        if keys:
            drop_redis_keys(keys)


# ---- message sizes -----------------------------------------------------------------------------
@needs_mosquitto
def test_a_message_over_the_bridges_maximum_packet_size_is_not_read_by_it(
    tmp_path: Path, prefix: str
) -> None:
    """A broker with no size limit of its own (it takes 20 MB): the bridge's Maximum Packet
    Size (ADVISOR_MAX_BODY_BYTES + 64 KiB) makes it drop a 20 MB message for the bridge, which
    receives none of its bytes; a message that fits the packet but not ADVISOR_MAX_BODY_BYTES
    is refused on its errors topic (413); the next message is answered."""
    port = free_port()
    broker = own_broker(port, tmp_path)
    try:
        limit = 64 * 1024
        with service(tmp_path / "data", port, prefix, max_body_bytes=limit) as client:
            wait_until(lambda: connected(client), what="the bridge to connect")
            bridge = bridge_of(client)
            assert bridge.max_packet == limit + PACKET_HEADROOM
            before = bridge.received
            peer = Peer(port, prefix)
            try:
                peer.publish("dev/default/e1/events", b" " * 20_000_000)
                peer.publish("dev/default/e1/events", b" " * (limit + 1))
                peer.publish("dev/default/e1/events", EVENT)
                decisions = peer.wait("dev/default/e1/decisions", 2)
                errors = peer.got("dev/default/e1/errors")
            finally:
                peer.close()
            read = bridge.received - before
        assert [e["status"] for e in errors] == [413], errors
        assert [d["step"] for d in decisions] == [0, 1]
        assert bridge.handled == 2 and bridge.oversized == 0
        # the 64 KiB message and the event, and acknowledgements: not the 20 MB
        assert limit < read < limit + 16 * 1024, read
    finally:
        broker.terminate()
        broker.wait(10)


def _packet(kind: int, body: bytes) -> bytes:
    """An MQTT packet: its type and flags, its remaining length, its body."""
    return bytes([kind]) + _varint(len(body)) + body


def _varint(n: int) -> bytes:
    out = bytearray()
    while True:
        n, digit = divmod(n, 128)
        out.append(digit | (128 if n else 0))
        if not n:
            return bytes(out)


class CarelessBroker:
    """Just enough of an MQTT v5 broker to let the bridge connect and subscribe, which then
    sends it a PUBLISH of ``size`` bytes whatever the Maximum Packet Size it connected with;
    counts the bytes the bridge took before closing the connection, and its connections."""

    def __init__(self, size: int):
        self.size = size
        self.server = socket.create_server((HOST, 0))
        self.server.settimeout(30)
        self.port: int = self.server.getsockname()[1]
        self.sent = 0
        self.connections = 0
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _read(self, conn: socket.socket) -> tuple[int, bytes]:
        kind = conn.recv(1)[0]
        length, shift = 0, 0
        while True:
            byte = conn.recv(1)[0]
            length += (byte & 127) << shift
            shift += 7
            if not byte & 128:
                break
        body = b""
        while len(body) < length:
            body += conn.recv(length - len(body))
        return kind, body

    def _serve(self) -> None:
        conn, _ = self.server.accept()
        self.connections += 1
        conn.settimeout(30)
        with conn:
            kind, _ = self._read(conn)
            assert kind == 0x10  # CONNECT
            conn.sendall(_packet(0x20, b"\x00\x00\x00"))  # CONNACK: success, no properties
            for _ in range(4):  # the bridge's subscriptions, one a packet
                kind, body = self._read(conn)
                assert kind == 0x82  # SUBSCRIBE
                conn.sendall(_packet(0x90, body[:2] + b"\x00\x01"))  # SUBACK: QoS 1 granted
            topic = b"careless/dev/default/e1/events"
            head = len(topic).to_bytes(2, "big") + topic + b"\x00"  # no properties
            conn.sendall(bytes([0x30]) + _varint(len(head) + self.size) + head)  # QoS 0
            chunk = b" " * 65536
            try:
                while self.sent < self.size:
                    self.sent += conn.send(chunk[: self.size - self.sent])
            except OSError:  # the bridge closed the connection
                pass
        conn, _ = self.server.accept()  # the bridge connecting again
        self.connections += 1
        conn.close()

    def close(self) -> None:
        self.server.close()


def test_a_broker_that_sends_more_than_the_maximum_packet_size_gets_its_connection_closed(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A broker that ignores the bridge's Maximum Packet Size and sends it 64 MiB: the bridge
    reads the packet's length, closes the connection without reading the rest (nor making a
    buffer for it), says so in the log, and connects again."""
    careless = CarelessBroker(64 * 1024 * 1024)
    try:
        with service(tmp_path, careless.port, "careless") as client:
            bridge = bridge_of(client)
            wait_until(lambda: careless.connections == 2, what="the bridge to connect again")
            careless.thread.join(10)
            assert bridge.oversized == 1 and bridge.handled == 0
            assert bridge.received < 1024 * 1024  # a CONNACK, SUBACKs, a packet's head
    finally:
        careless.close()
    assert careless.sent < careless.size  # the connection closed before all was sent
    (line,) = [r.getMessage() for r in caplog.records if "the broker sent" in r.getMessage()]
    assert f"{bridge.max_packet} (ADVISOR_MAX_BODY_BYTES + {PACKET_HEADROOM})" in line
    assert "without reading it" in line


# ---- the log under a flood ---------------------------------------------------------------------
def test_repeated_warnings_are_one_line_a_minute_for_each_kind(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """The bridge's loggers (its own, and the one aiomqtt and paho write to) let one warning
    of a kind (logger, level, message template) through a minute; the next line of the kind
    says how many were left out; other kinds and lines below warnings are not held back. The
    clock is the test's."""
    now = [0.0]
    state = SimpleNamespace(settings=make_settings(tmp_path))
    bridge = Bridge(state, "mqtt://127.0.0.1:1", clock=lambda: now[0])  # type: ignore[arg-type]

    async def make() -> aiomqtt.Client:  # aiomqtt takes the running loop
        return bridge._client()

    connection = run_async(make())  # off the browser tests' loop
    aiomqtt_log = connection._logger
    assert aiomqtt_log is bridge.client_log
    assert connection._client._logger is bridge.client_log  # paho's too
    # the bridge's loggers write through uvicorn's error logger (its handler: the default format)
    with caplog.at_level(logging.INFO, logger="uvicorn.error"):
        for k in range(10_000):  # a QoS 0 flood, as aiomqtt logs one
            now[0] = k * 0.005  # 50 s in all
            aiomqtt_log.warning("Message queue is full. Discarding message.")
            if k % 1000 == 0:
                bridge.log.warning("MQTT bridge: %s; reconnecting in %.1f s", "lost", 0.5)
        bridge.log.info("MQTT bridge connected to %s:%d", "broker", 1883)
        now[0] = 60.0
        aiomqtt_log.warning("Message queue is full. Discarding message.")
        now[0] = 60.5
        aiomqtt_log.warning("Message queue is full. Discarding message.")
    assert [r.getMessage() for r in caplog.records] == [
        "Message queue is full. Discarding message.",
        "MQTT bridge: lost; reconnecting in 0.5 s",
        "MQTT bridge connected to broker:1883",
        "Message queue is full. Discarding message. [9999 more like this in the last 60 s "
        "not logged]",
    ]


@needs_broker
def test_a_qos0_flood_past_the_queue_is_dropped_counted_and_logged_once(
    tmp_path: Path, prefix: str, caplog: pytest.LogCaptureFixture
) -> None:
    """ADVISOR_MQTT_QUEUE 1 and the bridge held on its first message: of 1,000 QoS 0 messages
    one waits in the queue and the others are dropped (the broker does not hold QoS 0 back),
    counted, and written in one line (the throttle's clock stopped: no time passes for it);
    aiomqtt's line per message is not written. A QoS 1 message that comes meanwhile is not
    dropped: it is answered once the bridge goes on."""
    with (
        caplog.at_level(logging.INFO, logger="app.service.mqtt"),
        service(tmp_path, PORT, prefix, mqtt_queue=1) as client,
    ):
        wait_until(lambda: connected(client), what="the bridge to connect")
        bridge = bridge_of(client)
        bridge.throttle.clock = lambda: 0.0
        gate = threading.Event()
        handle = bridge.handle

        async def held(topic: str, payload: bytes) -> None:
            while not gate.is_set():
                await asyncio.sleep(0.01)
            await handle(topic, payload)

        bridge.handle = held  # type: ignore[method-assign]
        peer = Peer(PORT, prefix)
        try:
            payload = json.dumps(EVENT).encode()
            for _ in range(1000):
                sent = peer.client.publish(f"{prefix}/dev/default/e1/events", payload, qos=0)
            sent.wait_for_publish(10)
            # one is being handled, one waits in the queue and the others find it full: 998
            # dropped, unless the broker dropped some itself (its max_queued_messages)
            wait_until(lambda: bridge.dropped >= 900, what="the flood to arrive")
            peer.publish("dev/default/e2/events", EVENT)  # QoS 1: waits, the queue full or not
            gate.set()
            peer.wait("dev/default/e2/decisions", 2)
        finally:
            peer.close()
    lines = [m for m in caplog.messages if "queue" in m.lower() or "dropped" in m]
    assert len(lines) == 1, lines
    assert "ADVISOR_MQTT_QUEUE" in lines[0] and "QoS 0 message" in lines[0]


# ---- the service's own failures ----------------------------------------------------------------
@needs_broker
def test_a_failure_of_the_service_is_an_error_message_and_the_bridge_goes_on(
    tmp_path: Path, prefix: str, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """Redis not answering and a bug, on an explorer's first message: 503 and 500 on its errors
    topic (no traceback there; the bug's is in the log), the session opened for it ended; the
    next message opens it anew, its start decision first."""
    answer = ops.answer_events
    failures: list[Exception] = [StoreUnavailable("connection refused"), RuntimeError("a bug")]

    async def failing(*args: Any, **kwargs: Any) -> bytes:
        if failures:
            raise failures.pop(0)
        return await answer(*args, **kwargs)

    monkeypatch.setattr(ops, "answer_events", failing)
    with service(tmp_path, PORT, prefix) as client:
        wait_until(lambda: connected(client), what="the bridge to connect")
        peer = Peer(PORT, prefix)
        try:
            peer.publish("dev/default/e1/events", EVENT)
            peer.publish("dev/default/e1/events", EVENT)
            errors = peer.wait("dev/default/e1/errors", 2)
            peer.publish("dev/default/e1/events", EVENT)
            decisions = peer.wait("dev/default/e1/decisions", 2)
        finally:
            peer.close()
        assert client.get("/health").json()["sessions"] == 1
    assert [e["status"] for e in errors] == [503, 500]
    assert "Redis, which does not answer now" in errors[0]["detail"]
    assert "its log says why" in errors[1]["detail"]
    assert all("Traceback" not in e["detail"] for e in errors)
    assert [d["step"] for d in decisions] == [0, 1]
    (failed,) = [r for r in caplog.records if r.exc_info]
    assert "RuntimeError: a bug" in caplog.text and "failed" in failed.getMessage()
