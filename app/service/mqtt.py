"""The MQTT bridge: explorers report over a broker, decisions go back over it.

Off unless ``ADVISOR_MQTT_URL`` is set (``mqtt://[user:password@]host[:port]``, ``mqtts://``
for TLS). With ``P`` the prefix (``ADVISOR_MQTT_PREFIX``, ``advisor``):

* ``P/<domain>/<explorer>/events``: one event or a list, the JSON of ``POST
  /sessions/{id}/events``. The first message of an explorer opens its session, starting at
  the cell of its first event, with the options of its retained ``P/<domain>/<explorer>/config``
  message (the JSON of ``POST /domains/{name}/sessions``) or the domain's defaults.
* ``P/<domain>/<explorer>/decisions``: each decision, one message each, in order: the session's
  start decision (step 0) when it opens, then one per event, each the JSON the REST route
  answers. Events go through the routes' own functions (:mod:`app.service.ops`), so the
  decisions are the REST ones.
* ``P/<domain>/<explorer>/errors``: ``{"detail", "status"}`` for a message refused (bad JSON,
  unknown domain, a wall...), as the websocket's error frames; nothing changed.

Explorer ids follow the rule of domain names (a message of another id is answered on its
``errors`` topic and opens no session). QoS 1 both ways: the bridge handles one message at a
time, publishes its decisions, and acknowledges the message only once the broker has
acknowledged every one of them, so a message whose decisions did not all reach the broker
(the connection dropped, the process died) is sent again by the broker; decisions not
acknowledged when the connection drops are published again after it reconnects (at least
once, as QoS 1 is). It reconnects with a backoff of up to 10 s, under the same client id (made
of the host and the data directory), and keeps its broker session for a minute (MQTT v5
session expiry) so that what was published meanwhile waits for it, for this bridge or the one
that takes over.

Sent again, a message is not applied twice when it can be told apart: one this bridge handled
but had not acknowledged (the same packet id, topic and payload, while the broker kept the
bridge's session) is acknowledged without being handled again; events that carry ``step`` are
answered again, not applied twice, as on REST. A message whose acknowledgement was lost with
the connection cannot be told from a new one: without steps, its events are applied again. A
bridge that takes over from a process that died gets the messages it had not acknowledged, but
not its explorers' sessions (they lived in that process): their events open new sessions.

Memory is bounded whatever is published: a message larger than ``ADVISOR_MAX_BODY_BYTES`` is
refused; each message is acknowledged once its decisions are published, and the broker sends
at most ``ADVISOR_MQTT_QUEUE`` unacknowledged ones (the connection's Receive Maximum), so what a
fast publisher sends waits at the broker, not here (Mosquitto keeps up to its
``max_queued_messages`` per client, 1000 by default, and drops what comes beyond); the bridge
keeps sessions and configs for ``ADVISOR_MQTT_MAX_EXPLORERS`` explorers at most (the least
recently heard from go first, their sessions ended).

Sessions live in one process's memory, so one bridge serves a data directory: with several
workers, the first to lock ``<data_dir>/mqtt-bridge.lock`` runs it and the others wait to take
over, so each message is handled once. Who may publish or read which topics is the broker's
business (an ACL file: README, "MQTT").
"""

from __future__ import annotations

import asyncio
import contextlib
import fcntl
import hashlib
import logging
import re
import socket
import ssl
from collections import OrderedDict
from collections.abc import AsyncIterator, Awaitable, Callable
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any
from urllib.parse import unquote, urlsplit

import aiomqtt
import orjson
from fastapi import FastAPI
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties
from pydantic import ValidationError

from app.service import ops
from app.service.data.domains import DomainNotFound
from app.service.live.registry import LiveSession, SessionNotFound
from app.service.metrics import MQTT_MESSAGES
from app.service.problems import BadInput, describe_errors
from app.service.schemas import NAME_PATTERN, SessionCreate
from app.service.state import ServiceState
from app.service.wire.encode import decision_json

log = logging.getLogger("uvicorn.error")  # uvicorn's handler: the default format writes it too

LOCK_FILE = "mqtt-bridge.lock"
SESSION_EXPIRY = 60  # seconds the broker keeps the bridge's subscriptions and queue
NAME = re.compile(NAME_PATTERN)
Key = tuple[str, str]


@dataclass(frozen=True)
class Broker:
    host: str
    port: int
    tls: bool
    username: str | None
    password: str | None


def parse_url(url: str) -> Broker:
    """``mqtt://[user:password@]host[:port]`` (1883; ``mqtts://``: TLS, 8883)."""
    parts = urlsplit(url)
    if parts.scheme not in ("mqtt", "mqtts") or not parts.hostname:
        raise ValueError(f"ADVISOR_MQTT_URL: {url!r} is not mqtt://host[:port] or mqtts://...")
    tls = parts.scheme == "mqtts"
    return Broker(
        parts.hostname, parts.port or (8883 if tls else 1883), tls,
        unquote(parts.username) if parts.username else None,
        unquote(parts.password) if parts.password else None,
    )  # fmt: skip


class Refused(Exception):
    def __init__(self, status: int, detail: str):
        super().__init__(detail)
        self.status, self.detail = status, detail


class Bridge:
    """One connection to the broker, its subscriptions and the explorers' sessions."""

    def __init__(self, state: ServiceState, url: str, lock_dir: Path | None = None):
        settings = state.settings
        self.state = state
        self.broker = parse_url(url)
        self.prefix = settings.mqtt_prefix
        self.max_explorers = settings.mqtt_max_explorers
        self.queue = settings.mqtt_queue
        self.max_bytes = settings.max_body_bytes
        self.lock_path = (lock_dir or settings.data_dir) / LOCK_FILE
        self.sessions: OrderedDict[Key, LiveSession] = OrderedDict()
        self.configs: OrderedDict[Key, SessionCreate] = OrderedDict()
        self.pending: list[tuple[str, bytes]] = []  # decisions not yet acknowledged
        # messages handled whose acknowledgement the broker has not had: packet id -> digest
        self.unacked: OrderedDict[int, bytes] = OrderedDict()
        self.connected = asyncio.Event()
        self.handled = 0  # messages handled (for tests and logs)
        # the same for every bridge of this data directory on this host, so that the one that
        # takes over (a new process, another worker) resumes the broker session and gets what
        # was not acknowledged
        place = hashlib.sha256(str(self.lock_path.resolve()).encode()).hexdigest()[:12]
        self.identifier = f"{self.prefix}-bridge-{socket.gethostname()}-{place}"
        self._lock: IO[str] | None = None

    # ---- topics ---------------------------------------------------------------------------
    def topic(self, domain: str, explorer: str, kind: str) -> str:
        return f"{self.prefix}/{domain}/{explorer}/{kind}"

    def _parse(self, topic: str) -> tuple[str, str, str] | None:
        parts = topic.split("/")
        if len(parts) != 4 or parts[0] != self.prefix:
            return None
        return parts[1], parts[2], parts[3]

    # ---- running --------------------------------------------------------------------------
    async def run(self) -> None:
        """Wait for the lock, then connect, and reconnect after every failure, forever."""
        while not self._take_lock():
            await asyncio.sleep(2.0)
        backoff = 0.5
        while True:
            connection = self._client()
            # acknowledged once its decisions are published: the broker sends at most ``queue``
            # unacknowledged messages (the connection's Receive Maximum), so none waits beyond
            # that here
            connection._client.manual_ack_set(True)
            self._watch_session(connection)
            try:
                async with connection as client:
                    backoff = 0.5
                    await self._flush(client)
                    await client.subscribe(self.topic("+", "+", "config"), qos=1)
                    await client.subscribe(self.topic("+", "+", "events"), qos=1)
                    self.connected.set()
                    log.info("MQTT bridge connected to %s:%d", self.broker.host, self.broker.port)
                    async for message in client.messages:
                        await self.take(client, message)
            except aiomqtt.MqttError as exc:
                self.connected.clear()
                log.warning("MQTT bridge: %s; reconnecting in %.1f s", exc, backoff)
                await asyncio.sleep(backoff)
                backoff = min(backoff * 2, 10.0)

    async def take(self, client: aiomqtt.Client, message: aiomqtt.Message) -> None:
        """One message: handled (unless it is one handled already, sent again), its decisions
        published and acknowledged by the broker, then the message acknowledged. A dropped
        connection (:class:`aiomqtt.MqttError`) leaves it unacknowledged: the broker sends it
        again."""
        topic, payload = str(message.topic), _bytes(message.payload)
        digest = hashlib.sha256(topic.encode() + b"\0" + payload).digest()
        if not (message.qos and self.unacked.get(message.mid) == digest):
            await self.handle(topic, payload)
            if message.qos:
                self.unacked[message.mid] = digest
                while len(self.unacked) > self.queue:
                    self.unacked.popitem(last=False)
        await self._flush(client)
        if message.qos:
            client._client.ack(message.mid, message.qos)
            self.unacked.pop(message.mid, None)

    def _watch_session(self, connection: aiomqtt.Client) -> None:
        """Forget the messages handled but not acknowledged when the broker kept no session
        for the bridge (it will not send them again, and their packet ids are reused)."""
        paho = connection._client
        on_connect = paho.on_connect

        def connected(client: Any, userdata: Any, flags: Any, *rest: Any) -> None:
            if not getattr(flags, "session_present", False):
                self.unacked.clear()
            if on_connect is not None:
                on_connect(client, userdata, flags, *rest)

        paho.on_connect = connected

    def _take_lock(self) -> bool:
        if self._lock is not None:
            return True
        self.lock_path.parent.mkdir(parents=True, exist_ok=True)
        handle = self.lock_path.open("a")
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            handle.close()
            return False
        self._lock = handle
        return True

    def release(self) -> None:
        if self._lock is not None:
            self._lock.close()  # closing the file drops the lock
            self._lock = None

    def _client(self) -> aiomqtt.Client:
        props = Properties(PacketTypes.CONNECT)  # type: ignore[no-untyped-call]
        props.SessionExpiryInterval = SESSION_EXPIRY
        props.ReceiveMaximum = min(self.queue, 65_535)
        b = self.broker
        return aiomqtt.Client(
            b.host, b.port, username=b.username, password=b.password,
            identifier=self.identifier, protocol=aiomqtt.ProtocolVersion.V5,
            clean_start=False, properties=props,
            tls_context=ssl.create_default_context() if b.tls else None,
            max_queued_incoming_messages=self.queue, max_inflight_messages=100,
            timeout=30.0,
        )  # fmt: skip

    async def _flush(self, client: aiomqtt.Client) -> None:
        """Publish every decision not yet acknowledged (QoS 1), keeping the ones that fail."""
        if not self.pending:
            return
        todo, self.pending = self.pending, []
        tasks = [asyncio.ensure_future(client.publish(t, p, qos=1)) for t, p in todo]
        everything = asyncio.gather(*tasks, return_exceptions=True)
        # aiomqtt's publish waits for the broker's acknowledgement up to its timeout even when
        # the connection has dropped: stop waiting then (aiomqtt's future of the disconnection)
        gone = getattr(client, "_disconnected", None)
        try:
            if gone is not None:
                await asyncio.wait([everything, gone], return_when=asyncio.FIRST_COMPLETED)
                for task in tasks:
                    task.cancel()  # those the broker has not acknowledged: kept below
            results = await everything
        except asyncio.CancelledError:  # the bridge stops
            for task in tasks:
                task.cancel()
            raise
        self.pending = [m for m, r in zip(todo, results, strict=True) if r is not None]
        failed = next((r for r in results if isinstance(r, BaseException)), None)
        if failed is not None:
            if isinstance(failed, aiomqtt.MqttError):
                raise failed
            raise aiomqtt.MqttError(f"publishing failed: {failed}")

    # ---- one message ----------------------------------------------------------------------
    async def handle(self, topic: str, payload: bytes) -> None:
        """One message: its decisions (or its error) join :attr:`pending`, to be published."""
        parsed = self._parse(topic)
        if parsed is None:
            return
        domain, explorer, kind = parsed
        MQTT_MESSAGES.labels("in", kind).inc()
        self.handled += 1
        try:
            if not (NAME.match(domain) and NAME.match(explorer)):
                raise Refused(422, f"domain and explorer ids must match {NAME_PATTERN}")
            if kind == "config":
                await self.configure((domain, explorer), payload)
                return
            decisions = await self.events((domain, explorer), payload)
        except Refused as exc:
            error = orjson.dumps({"detail": exc.detail, "status": exc.status})
            self.pending.append((self.topic(domain, explorer, "errors"), error))
            MQTT_MESSAGES.labels("out", "errors").inc()
        else:
            out = self.topic(domain, explorer, "decisions")
            self.pending.extend((out, d) for d in decisions)
            MQTT_MESSAGES.labels("out", "decisions").inc(len(decisions))

    async def configure(self, key: Key, payload: bytes) -> None:
        """A retained config: the options of the explorer's next session (an empty payload
        clears it). A live session of the explorer ends, so the next event starts anew."""
        await self._end(key)
        if not payload:
            self.configs.pop(key, None)
            return
        try:
            body = SessionCreate.model_validate_json(payload)
        except ValidationError as exc:
            raise Refused(422, "config: " + describe_errors(exc.errors())) from None
        self.configs[key] = body
        self.configs.move_to_end(key)
        while len(self.configs) > self.max_explorers:
            self.configs.popitem(last=False)

    async def events(self, key: Key, payload: bytes) -> list[bytes]:
        """The decisions for one message of events (a new session's start decision first)."""
        if len(payload) > self.max_bytes:
            raise Refused(413, f"the message is larger than {self.max_bytes} bytes")
        state = self.state
        out: list[bytes] = []
        for _ in range(2):  # a second time if the session ended meanwhile
            session = self.sessions.get(key)
            try:
                if session is None:
                    session, first = await self._open(key, payload)
                    out.append(first)
                answer = await ops.answer_events(state, session, payload)
            except SessionNotFound:
                self.sessions.pop(key, None)
                out.clear()
                continue
            except BadInput as exc:
                raise Refused(exc.status, exc.detail) from None
            self.sessions.move_to_end(key)
            if answer.startswith(b"["):
                out += [orjson.dumps(d) for d in orjson.loads(answer)]
            else:
                out.append(answer)
            return out
        raise Refused(404, "the explorer's session ended twice while its message was handled")

    async def _open(self, key: Key, payload: bytes) -> tuple[LiveSession, bytes]:
        domain_name, _ = key
        try:
            domain = await self.state.sessions.domain(domain_name)
        except DomainNotFound:
            raise Refused(404, f"no domain named {domain_name!r}") from None
        body = self.configs.get(key) or SessionCreate()
        if body.start is None:
            body = body.model_copy(update={"start": _first_state(payload)})
        try:
            session, decision = await ops.open_session(self.state, domain, body)
        except BadInput as exc:
            raise Refused(exc.status, exc.detail) from None
        self.sessions[key] = session
        while len(self.sessions) > self.max_explorers:
            await self._end(next(iter(self.sessions)))
        return session, decision_json(decision, domain.domain)

    async def _end(self, key: Key) -> None:
        session = self.sessions.pop(key, None)
        if session is not None:
            with contextlib.suppress(SessionNotFound):
                await self.state.sessions.end(session)


def _bytes(payload: Any) -> bytes:
    if isinstance(payload, bytes | bytearray):
        return bytes(payload)
    if isinstance(payload, str):
        return payload.encode()
    return b"" if payload is None else str(payload).encode()


def _first_state(payload: bytes) -> list[int]:
    """The cell of the first event: where a new session starts."""
    try:
        body = orjson.loads(payload)
    except orjson.JSONDecodeError as exc:
        raise Refused(422, f"the message is not JSON: {exc}") from None
    first = body[0] if isinstance(body, list) and body else body
    state = first.get("state") if isinstance(first, dict) else None
    if not (isinstance(state, list) and len(state) == 2 and all(type(v) is int for v in state)):
        raise Refused(422, "event 0: state must be a cell [row, col]")
    return state


@contextlib.asynccontextmanager
async def running(bridge: Bridge) -> AsyncIterator[asyncio.Task[None]]:
    task = asyncio.create_task(bridge.run(), name="mqtt-bridge")
    try:
        yield task
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
        bridge.release()


async def start_bridge(app: FastAPI) -> Callable[[], Awaitable[None]]:
    """Start the bridge beside the API (the lifespan's background hook); returns its stop."""
    state: ServiceState = app.state.service
    assert state.settings.mqtt_url is not None
    bridge = Bridge(state, state.settings.mqtt_url)
    context = running(bridge)
    await context.__aenter__()
    app.state.bridge = bridge

    async def stop() -> None:
        app.state.bridge = None
        await context.__aexit__(None, None, None)

    return stop
