"""The MQTT bridge against real Mosquitto brokers: the machine's (127.0.0.1:1883) and, for a
restart, one of the test's own on a free port. Each test uses topics of its own."""

from __future__ import annotations

import getpass
import secrets
import shutil
import socket
import subprocess
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import aiomqtt
import numpy as np
import orjson
import paho.mqtt.client as paho
import pytest
from fastapi.testclient import TestClient
from paho.mqtt.enums import CallbackAPIVersion
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties

from app.domain.building import Domain
from app.domain.grid import GridDomain
from app.service.main import create_app
from app.service.mqtt import Bridge, parse_url
from tests.client.test_client import run_async
from tests.service.conftest import make_settings, put_tiny
from tests.service.test_strategies import put_tower

MOSQUITTO = "/usr/sbin/mosquitto"
HOST, PORT = "127.0.0.1", 1883


def reachable(host: str, port: int) -> bool:
    try:
        with socket.create_connection((host, port), timeout=1.0):
            return True
    except OSError:
        return False


needs_broker = pytest.mark.skipif(
    not reachable(HOST, PORT), reason=f"no MQTT broker (Mosquitto) at {HOST}:{PORT}"
)
needs_mosquitto = pytest.mark.skipif(
    shutil.which(MOSQUITTO) is None, reason=f"{MOSQUITTO} is not installed (apt-get mosquitto)"
)


def free_port() -> int:
    with socket.socket() as s:
        s.bind((HOST, 0))
        port: int = s.getsockname()[1]
        return port


def wait_until(condition: Callable[[], object], timeout: float = 30.0, what: str = "") -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout}s waiting for {what}")
        time.sleep(0.02)


class Peer:
    """A test's own MQTT client (paho, its network thread): publishes, and keeps every message
    of ``prefix/#`` (subscribed again at each reconnection). ``expiry``: seconds the broker
    keeps its session (and the messages for it) while it is away."""

    def __init__(self, port: int, prefix: str, expiry: int = 0):
        self.prefix = prefix
        self.messages: list[tuple[str, bytes]] = []
        self.lock = threading.Lock()
        self.client = paho.Client(
            CallbackAPIVersion.VERSION2, f"test-{secrets.token_hex(4)}", protocol=paho.MQTTv5
        )
        self.subscribed = threading.Event()
        self.client.on_connect = lambda c, *_: c.subscribe(f"{prefix}/#", qos=1)
        self.client.on_subscribe = lambda *_: self.subscribed.set()
        self.client.on_message = self._message
        self.client.reconnect_delay_set(1, 1)
        props = None
        if expiry:  # a new client id: no session to start clean from (Mosquitto 2.0.11 does
            # not keep over a restart the session of a client that connected with clean start)
            props = Properties(PacketTypes.CONNECT)  # type: ignore[no-untyped-call]
            props.SessionExpiryInterval = expiry
        self.client.connect(HOST, port, clean_start=not expiry, properties=props)
        self.client.loop_start()
        # subscribed before it publishes: else the first answers may come before it listens
        wait_until(self.subscribed.is_set, 10.0, f"the test client to subscribe to {prefix}/#")

    def _message(self, _c: Any, _u: Any, message: paho.MQTTMessage) -> None:
        with self.lock:
            self.messages.append((message.topic, bytes(message.payload)))

    def publish(self, topic: str, payload: Any, retain: bool = False) -> None:
        data = payload if isinstance(payload, bytes) else orjson.dumps(payload)
        self.client.publish(f"{self.prefix}/{topic}", data, qos=1, retain=retain).wait_for_publish(
            10
        )

    def got(self, topic: str) -> list[Any]:
        with self.lock:
            return [orjson.loads(p) for t, p in self.messages if t == f"{self.prefix}/{topic}"]

    def wait(self, topic: str, n: int) -> list[Any]:
        wait_until(lambda: len(self.got(topic)) >= n, what=f"{n} messages on {topic}")
        return self.got(topic)

    def close(self) -> None:
        self.client.loop_stop()
        self.client.disconnect()


@contextmanager
def service(tmp: Path, port: int, prefix: str, **settings: Any) -> Iterator[TestClient]:
    app = create_app(
        make_settings(tmp, mqtt_url=f"mqtt://{HOST}:{port}", mqtt_prefix=prefix, **settings)
    )
    with TestClient(app) as client:
        yield client


def connected(client: TestClient) -> bool:
    bridge = client.app.state.bridge  # type: ignore[attr-defined]
    return bridge is not None and bridge.connected.is_set()


def walk(n: int, seed: int, grid: Domain | None = None) -> list[dict[str, Any]]:
    """``n`` random moves from the start of ``grid`` (the shipped maze by default)."""
    if grid is None:
        grid = GridDomain.from_file(Path(__file__).parents[2] / "app/domain/maps/default.txt")
    rng = np.random.default_rng(seed)
    s, out = grid.start, []
    for a in rng.integers(0, grid.n_actions, n).tolist():
        out.append({"state": list(grid.cell(s)), "action": grid.actions[a]})
        s = int(grid.next_state[s, a])
    return out


@pytest.fixture
def prefix() -> str:
    return f"t{secrets.token_hex(5)}"


@needs_broker
@pytest.mark.parametrize("domain", ["default", "tower"])
def test_bridge_decisions_equal_the_rest_answers(tmp_path: Path, prefix: str, domain: str) -> None:
    """On the shipped maze and on a building of two floors."""
    with service(tmp_path, PORT, prefix) as client:
        events = walk(41, seed=3)
        if domain == "tower":
            admin = {"X-API-Key": client.app.state.service.admin_key}  # type: ignore[attr-defined]
            events = walk(41, seed=3, grid=put_tower(client, admin))
        wait_until(lambda: connected(client), what="the bridge to connect")
        peer = Peer(PORT, prefix)
        try:
            peer.publish(f"{domain}/e1/events", events[:40])  # a list: one message per decision
            peer.publish(f"{domain}/e1/events", events[40])  # one event
            got = peer.wait(f"{domain}/e1/decisions", 42)
        finally:
            peer.close()
        created = client.post(
            f"/domains/{domain}/sessions", json={"start": events[0]["state"]}
        ).json()
        auth = {"Authorization": f"Bearer {created['token']}"}
        sid = created["session_id"]
        rest = [created["decision"]]
        rest += client.post(f"/sessions/{sid}/events", json=events[:40], headers=auth).json()
        rest.append(client.post(f"/sessions/{sid}/events", json=events[40], headers=auth).json())
    assert [d["step"] for d in got] == list(range(42))
    assert got == rest


@needs_broker
def test_bridge_opens_sessions_with_the_retained_config(tmp_path: Path, prefix: str) -> None:
    peer = Peer(PORT, prefix)
    try:
        config = {"kappa": 0.0, "strategy": "always", "window": 20}
        peer.publish("default/walker-1/config", config, retain=True)  # before the bridge runs
        with service(tmp_path, PORT, prefix) as client:
            wait_until(lambda: connected(client), what="the bridge to connect")
            peer.publish("default/walker-1/events", walk(5, seed=1))
            got = peer.wait("default/walker-1/decisions", 6)
            assert all(d["advise"] for d in got)
            operator = {"X-API-Key": client.app.state.service.operator_key}  # type: ignore[attr-defined]
            listed = client.get("/overview", headers=operator).json()["sessions"]
            assert [(s["strategy"], s["kappa"]) for s in listed] == [("always", 0.0)]
        peer.publish("default/walker-1/config", b"", retain=True)  # clears the retained one
    finally:
        peer.close()


@needs_broker
def test_bridge_answers_a_refused_message_on_the_errors_topic(tmp_path: Path, prefix: str) -> None:
    with service(tmp_path, PORT, prefix, max_body_bytes=4096) as client:
        wait_until(lambda: connected(client), what="the bridge to connect")
        peer = Peer(PORT, prefix)
        try:
            peer.publish("nowhere/e1/events", {"state": [28, 0], "action": "E"})
            peer.publish("default/e1/events", b"{not json")
            peer.publish("default/e1/events", {"state": [27, 0], "action": "N"})  # a wall
            peer.publish("default/e1/events", [{"state": [28, 0], "action": "E"}] * 300)
            peer.publish("default/e1/config", {"kappa": -1})
            errors = peer.wait("default/e1/errors", 4) + peer.wait("nowhere/e1/errors", 1)
            # the explorer can go on: its session opens at its first good event
            peer.publish("default/e1/events", {"state": [28, 0], "action": "E"})
            decisions = peer.wait("default/e1/decisions", 2)
        finally:
            peer.close()
    statuses = sorted(e["status"] for e in errors)
    assert statuses == [404, 413, 422, 422, 422], errors
    assert any("is a wall" in e["detail"] for e in errors)
    assert any(e["detail"].startswith("config: kappa") for e in errors)
    assert [d["state"] for d in decisions] == [[28, 0], [28, 1]]


@needs_broker
def test_bridge_keeps_at_most_its_explorers(tmp_path: Path, prefix: str) -> None:
    with service(tmp_path, PORT, prefix, mqtt_max_explorers=2) as client:
        wait_until(lambda: connected(client), what="the bridge to connect")
        admin = {"X-API-Key": client.app.state.service.admin_key}  # type: ignore[attr-defined]
        put_tiny(client, admin, "tiny")
        peer = Peer(PORT, prefix)
        try:
            for k in range(3):
                peer.publish(f"tiny/e{k}/events", {"state": [5, 1], "action": "E"})
                peer.wait(f"tiny/e{k}/decisions", 2)
        finally:
            peer.close()
        bridge = client.app.state.bridge  # type: ignore[attr-defined]
        assert [k.explorer for k in bridge.sessions] == ["e1", "e2"]
        assert client.get("/overview").json()["total_sessions"] == 2


def own_broker(port: int, workdir: Path) -> subprocess.Popen[bytes]:
    conf = workdir / "mosquitto.conf"
    conf.write_text(
        f"listener {port} {HOST}\nallow_anonymous true\npersistence true\n"
        f"persistence_location {workdir}/\n"
        # started as root, Mosquitto runs as the user "mosquitto", who may not write here (its
        # sessions would not outlive a restart); as anyone else, this changes nothing
        f"user {getpass.getuser()}\n"
    )
    proc = subprocess.Popen([MOSQUITTO, "-c", str(conf)], stderr=subprocess.DEVNULL)
    wait_until(lambda: reachable(HOST, port), 10.0, "mosquitto to listen")
    return proc


@needs_mosquitto
def test_decisions_of_events_sent_before_the_broker_stops_arrive_after_it_restarts(
    tmp_path: Path, prefix: str
) -> None:
    """Events acknowledged by the broker just before it stops (handled by the bridge, being
    handled, or still queued for it): after the restart every one has its decision, and each
    event was applied once. The events carry their steps: a message sent again after its
    acknowledgement was lost with the connection is answered again, not applied twice (so a
    decision may come twice, the same one: QoS 1 is at least once)."""
    port = free_port()
    broker = own_broker(port, tmp_path)
    try:
        with service(tmp_path / "data", port, prefix) as client:
            wait_until(lambda: connected(client), what="the bridge to connect")
            peer = Peer(port, prefix, expiry=300)  # its decisions wait for it at the broker
            try:
                events = [e | {"step": k + 1} for k, e in enumerate(walk(41, seed=5))]
                peer.publish("default/e1/events", events[0])
                assert len(peer.wait("default/e1/decisions", 2)) == 2  # the session is open
                for event in events[1:40]:  # one message each, each acknowledged
                    peer.publish("default/e1/events", event)
                broker.terminate()
                broker.wait(10)
                before = len(peer.got("default/e1/decisions"))
                broker = own_broker(port, tmp_path)
                wait_until(lambda: peer.client.is_connected(), what="the test client to reconnect")
                peer.publish("default/e1/events", events[40])  # its decision comes last

                def steps() -> set[int]:
                    return {d["step"] for d in peer.got("default/e1/decisions")}

                wait_until(lambda: steps() >= set(range(42)), what="every event's decision")
                got = peer.got("default/e1/decisions")
            finally:
                peer.close()
            operator = {"X-API-Key": client.app.state.service.operator_key}  # type: ignore[attr-defined]
            (session,) = client.get("/overview", headers=operator).json()["sessions"]
        print(f"\n{before} of 42 decisions before the broker stopped; {len(got)} in all")
        assert session["steps"] == 41  # each event applied once
        by_step: dict[int, Any] = {}
        for d in got:  # a decision sent again is the same decision
            assert by_step.setdefault(d["step"], d) == d
        assert sorted(by_step) == list(range(42))  # none lost
        # each decision is at the cell its event moved to: the next event's cell
        assert [by_step[k]["state"] for k in range(41)] == [e["state"] for e in events]
    finally:
        broker.terminate()
        broker.wait(10)


def test_a_message_sent_again_after_its_decisions_went_out_is_not_handled_twice() -> None:
    """The connection drops after a message was handled, before its decisions were all
    acknowledged: the message is not acknowledged; the broker sends it again (same packet id)
    and the bridge publishes what was left and acknowledges it, without handling it again."""

    class Client:
        def __init__(self) -> None:
            self.sent: list[str] = []
            self.acked: list[int] = []
            self.fail = True
            self._client = self

        async def publish(self, topic: str, payload: bytes, qos: int) -> None:
            if self.fail:
                raise aiomqtt.MqttError("connection lost")
            self.sent.append(topic)

        def ack(self, mid: int, qos: int) -> None:
            self.acked.append(mid)

    bridge = Bridge.__new__(Bridge)
    bridge.pending, bridge.queue = [], 10
    bridge.unacked = OrderedDict()
    handled: list[str] = []

    async def handle(topic: str, payload: bytes) -> None:
        handled.append(topic)
        bridge.pending.append((topic + "/decision", payload))

    bridge.handle = handle  # type: ignore[method-assign]
    message = aiomqtt.Message("p/default/e1/events", b"[1]", 1, False, 7, None)
    client = Client()
    with pytest.raises(aiomqtt.MqttError):
        run_async(bridge.take(client, message))  # type: ignore[arg-type]
    assert handled == ["p/default/e1/events"] and client.acked == []  # not acknowledged
    client.fail = False
    run_async(bridge.take(client, message))  # type: ignore[arg-type]  # sent again
    assert handled == ["p/default/e1/events"]  # not handled twice
    assert client.sent == ["p/default/e1/events/decision"] and client.acked == [7]
    other = aiomqtt.Message("p/default/e1/events", b"[2]", 1, False, 7, None)  # id reused
    run_async(bridge.take(client, other))  # type: ignore[arg-type]
    assert len(handled) == 2 and client.acked == [7, 7] and not bridge.unacked


@needs_broker
def test_an_explorer_id_off_the_rule_is_refused_on_its_errors_topic(
    tmp_path: Path, prefix: str
) -> None:
    with service(tmp_path, PORT, prefix) as client:
        wait_until(lambda: connected(client), what="the bridge to connect")
        peer = Peer(PORT, prefix)
        try:
            peer.publish("default/-robot/events", {"state": [28, 0], "action": "E"})
            (error,) = peer.wait("default/-robot/errors", 1)
            peer.publish("default/robot/events", {"state": [28, 0], "action": "E"})
            peer.wait("default/robot/decisions", 2)  # handled after the refused one
        finally:
            peer.close()
        assert error["status"] == 422 and "must match" in error["detail"]
        assert peer.got("default/-robot/decisions") == []
        bridge = client.app.state.bridge  # type: ignore[attr-defined]
        assert [k.explorer for k in bridge.sessions] == ["robot"]
        assert client.get("/overview").json()["total_sessions"] == 1


@needs_broker
def test_one_bridge_per_data_directory_handles_each_message_once(
    tmp_path: Path, prefix: str
) -> None:
    """Two workers of one service: one bridge runs, the other takes over when it stops."""
    with service(tmp_path, PORT, prefix) as first:
        wait_until(lambda: connected(first), what="the first bridge to connect")
        peer = Peer(PORT, prefix)
        try:
            with service(tmp_path, PORT, prefix) as second:
                time.sleep(0.5)
                assert not connected(second)  # waiting for the lock
                peer.publish("default/e1/events", walk(5, seed=2))
                peer.wait("default/e1/decisions", 6)
                time.sleep(0.5)  # a second bridge would have answered by now
                assert len(peer.got("default/e1/decisions")) == 6
                first.__exit__(None, None, None)
                wait_until(lambda: connected(second), what="the second bridge to take over")
                peer.publish("default/e2/events", walk(3, seed=2))
                assert len(peer.wait("default/e2/decisions", 4)) == 4
        finally:
            peer.close()


def test_decisions_not_acknowledged_are_published_again() -> None:
    """A publish that fails (the connection dropped) keeps its decision for the next
    connection; the ones acknowledged are not sent twice."""

    class Flaky:
        def __init__(self, fail: set[str]):
            self.fail, self.sent = fail, []  # type: ignore[var-annotated]

        async def publish(self, topic: str, payload: bytes, qos: int) -> None:
            if topic in self.fail:
                raise aiomqtt.MqttError("connection lost")
            self.sent.append(topic)

    bridge = Bridge.__new__(Bridge)
    bridge.pending = [("a", b"1"), ("b", b"2"), ("c", b"3")]
    first = Flaky({"b", "c"})
    with pytest.raises(aiomqtt.MqttError):
        run_async(bridge._flush(first))  # type: ignore[arg-type]
    assert first.sent == ["a"] and [t for t, _ in bridge.pending] == ["b", "c"]
    second = Flaky(set())
    run_async(bridge._flush(second))  # type: ignore[arg-type]
    assert second.sent == ["b", "c"] and bridge.pending == []


def test_broker_urls() -> None:
    b = parse_url("mqtts://user:p%40ss@broker.example:8884")
    assert (b.host, b.port, b.tls, b.username, b.password) == (
        "broker.example", 8884, True, "user", "p@ss",
    )  # fmt: skip
    assert parse_url("mqtt://127.0.0.1").port == 1883
    with pytest.raises(ValueError, match="not mqtt://"):
        parse_url("http://127.0.0.1:1883")
