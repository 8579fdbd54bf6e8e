"""The MQTT bridge: explorers report over a broker, decisions go back over it.

Off unless ``ADVISOR_MQTT_URL`` is set (``mqtt://[user:password@]host[:port]``, ``mqtts://``
for TLS). With ``P`` the prefix (``ADVISOR_MQTT_PREFIX``, ``advisor``), each explorer has its
topics under ``B``, in one of two forms:

* ``B = P/<device>/<domain>/<explorer>``: a device (a sensor, a positioning gateway: the
  broker's user name) reports for any number of explorers;
* ``B = P/<domain>/<explorer>``, the short form: the explorer is its own device (its id is the
  device's name).

The device is the MQTT client: its sessions count against the per-client quotas
(``ADVISOR_CLIENT_MAX_SESSIONS``, ``ADVISOR_CLIENT_MAX_SESSION_MEMORY``) as ``"mqtt
<device>"`` (HTTP clients are ``"address ..."`` or ``"key ..."``, so no name is shared), and
against the service's caps, exactly as sessions opened over HTTP. The bridge cannot see who
published a message, only its topic: the broker's ACL makes the device level the publisher's
own user name (``%u``: deploy/mosquitto/acl, README "MQTT"); without one, anyone may write
any device there.

* ``B/events``: one event or a list, the JSON of ``POST /sessions/{id}/events``. The first
  message of an explorer opens its session, starting at the cell of its first event, with the
  options of its retained ``B/config`` message (the JSON of ``POST /domains/{name}/sessions``)
  or the domain's defaults.
* ``B/decisions``: each decision, one message each, in order: the session's start decision
  (step 0) when it opens, then one per event, each the JSON the REST route answers. Events go
  through the routes' own functions (:mod:`app.service.ops`), so the decisions are the REST
  ones.
* ``B/errors``: ``{"detail", "status"}`` for a message refused (bad JSON, unknown domain, a
  wall, the device's quota...), as the websocket's error frames; nothing changed. When Redis or
  the database does not answer: status 503, a detail naming which, and ``retry_after``
  (seconds): send the message again then (events carrying ``step`` are applied once). A bug is
  answered there too (500) and logged.

Device, domain and explorer ids follow the rule of domain names (a message of another id is
answered on its ``errors`` topic and opens no session). QoS 1 both ways: the bridge handles
one message at a time, publishes its decisions, and acknowledges the message only once the
broker has acknowledged every one of them, so a message whose decisions did not all reach the
broker (the connection dropped, the process died) is sent again by the broker; decisions not
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

Memory is bounded whatever is published. The bridge connects with an MQTT v5 Maximum Packet
Size of ``ADVISOR_MAX_BODY_BYTES`` plus 64 KiB (for the topic and properties): the broker does
not send it a larger message (Mosquitto drops it for the bridge, and nobody is told), and were
a broker to send one anyway the bridge closes the connection having read its length only
(:meth:`Bridge._guard`), never the message; a message that fits but is larger than
``ADVISOR_MAX_BODY_BYTES`` is refused on its ``errors`` topic (413). The broker's own limit
(Mosquitto's ``message_size_limit``, deploy/mosquitto/mosquitto.conf) refuses larger messages
at the publisher, which an MQTT v5 publisher is told (its PUBACK's reason code). Each message
is acknowledged once its decisions are published, and the broker sends at most
``ADVISOR_MQTT_QUEUE`` unacknowledged ones (the connection's Receive Maximum), so what a fast
publisher sends with QoS 1 waits at the broker, not here (Mosquitto keeps up to its
``max_queued_messages`` per client, 1000 by default, and drops what comes beyond); QoS 0
messages are not held back by the broker, and those that find the bridge's queue full
are dropped (counted, and logged as below); the bridge keeps sessions and configs for
``ADVISOR_MQTT_MAX_EXPLORERS`` explorers at most (the least recently heard from go first,
their sessions ended).

The bridge's warnings, and those of aiomqtt and paho under it, are written at most once a
minute for each kind (logger, level and message template); the next line of a kind says how
many of it were left out (:class:`Throttle`).

Sessions live in one process's memory, so one bridge serves a data directory: with several
workers, the first to lock ``<data_dir>/mqtt-bridge.lock`` runs it and the others wait to take
over, so each message is handled once.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import fcntl
import hashlib
import logging
import re
import socket
import ssl
import threading
import time
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
from app.service.clients import device_client
from app.service.data.domains import DomainNotFound
from app.service.errors import (
    DATABASE_DOWN,
    DATABASE_DOWN_TEXT,
    DATABASE_RETRY_AFTER,
    STORE_DOWN,
    store_down_detail,
)
from app.service.live.faults import RETRY_AFTER
from app.service.live.registry import LiveSession, SessionNotFound
from app.service.metrics import MQTT_MESSAGES
from app.service.problems import BadInput, describe_errors
from app.service.public import decision_leads_to
from app.service.schemas import NAME_PATTERN, SessionCreate
from app.service.state import ServiceState
from app.service.wire.encode import decision_json

log = logging.getLogger("uvicorn.error")  # uvicorn's handler: the default format writes it too

LOCK_FILE = "mqtt-bridge.lock"
SESSION_EXPIRY = 60  # seconds the broker keeps the bridge's subscriptions and queue
#: bytes a packet may hold beyond its payload (``ADVISOR_MAX_BODY_BYTES``): its topic (at most
#: 65,535 bytes) and properties
PACKET_HEADROOM = 64 * 1024
LOG_EVERY = 60.0  # seconds: one line of a kind of warning per this many (Throttle)
NAME = re.compile(NAME_PATTERN)
KINDS = ("events", "config")  # what the bridge reads; it writes decisions and errors
#: what a refusal's detail says to do on REST, and over MQTT instead
REST_END = "(DELETE /sessions/{id})"
MQTT_END = "(an empty message on an explorer's config topic ends its session)"


@dataclass(frozen=True)
class Explorer:
    """An explorer as its topics name it: the device reporting it, its domain and its id;
    ``short``: its topics are ``P/<domain>/<explorer>/...`` (the explorer its own device)."""

    device: str
    domain: str
    explorer: str
    short: bool = False

    @property
    def client(self) -> str:
        """Whom its session's quota counts against."""
        return device_client(self.device)


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


def subscriptions(prefix: str) -> list[str]:
    """What the bridge subscribes to: configs, then events (so that the retained configs come
    before the events that waited for the bridge), in both forms of the topics."""
    return [f"{prefix}/{'+/' * levels}{kind}" for kind in ("config", "events") for levels in (2, 3)]


class Refused(Exception):
    def __init__(self, status: int, detail: str, retry_after: int | None = None):
        super().__init__(detail)
        self.status, self.detail, self.retry_after = status, detail, retry_after


#: what a message may be refused for: its own fault, or Redis or the database not answering
REFUSED: tuple[type[Exception], ...] = (Refused, *STORE_DOWN, *DATABASE_DOWN)


def unavailable(exc: Exception) -> Refused:
    """Redis or the database not answering, as a message's refusal: 503, naming which."""
    if isinstance(exc, DATABASE_DOWN):
        return Refused(503, DATABASE_DOWN_TEXT, DATABASE_RETRY_AFTER)
    return Refused(503, store_down_detail(exc), RETRY_AFTER)


class Throttle(logging.Filter):
    """Lets through one record of a kind (its logger, level and message template) per
    ``every`` seconds of ``clock``, warnings and above only; the next one let through after
    others were left out says how many. Kinds are templates, a few dozen at most; past 1,024
    the oldest are forgotten."""

    def __init__(self, every: float = LOG_EVERY, clock: Callable[[], float] = time.monotonic):
        super().__init__()
        self.every, self.clock = every, clock
        self.kinds: OrderedDict[tuple[str, int, str], list[float]] = OrderedDict()
        self._lock = threading.Lock()  # paho may log from a thread of its own

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno < logging.WARNING:
            return True
        kind = (record.name, record.levelno, str(record.msg))
        now = self.clock()
        with self._lock:
            seen = self.kinds.get(kind)
            if seen is not None and now - seen[0] < self.every:
                seen[1] += 1
                return False
            self.kinds[kind] = [now, 0]
            self.kinds.move_to_end(kind)
            while len(self.kinds) > 1024:
                self.kinds.popitem(last=False)
        if seen is not None and seen[1]:
            record.msg = (
                f"{record.msg} [{int(seen[1])} more like this in the last "
                f"{now - seen[0]:.0f} s not logged]"
            )
        return True


def throttled_logger(name: str, throttle: Throttle, parent: logging.Logger) -> logging.Logger:
    """A logger of its own (not in logging's registry, so each bridge has its own) whose
    records go through ``throttle``, then to ``parent``'s handlers as a child's would."""
    logger = logging.Logger(name)
    logger.parent = parent
    logger.addFilter(throttle)
    return logger


class Bridge:
    """One connection to the broker, its subscriptions and the explorers' sessions."""

    def __init__(
        self, state: ServiceState, url: str, lock_dir: Path | None = None,
        clock: Callable[[], float] = time.monotonic,
    ):  # fmt: skip
        settings = state.settings
        self.state = state
        self.broker = parse_url(url)
        self.prefix = settings.mqtt_prefix
        self.max_explorers = settings.mqtt_max_explorers
        self.queue = settings.mqtt_queue
        self.max_bytes = settings.max_body_bytes
        self.max_packet = settings.max_body_bytes + PACKET_HEADROOM
        self.lock_path = (lock_dir or settings.data_dir) / LOCK_FILE
        self.sessions: OrderedDict[Explorer, LiveSession] = OrderedDict()
        self.configs: OrderedDict[Explorer, SessionCreate] = OrderedDict()
        self.pending: list[tuple[str, bytes]] = []  # decisions not yet acknowledged
        # messages handled whose acknowledgement the broker has not had: packet id -> digest
        self.unacked: OrderedDict[int, bytes] = OrderedDict()
        self.connected = asyncio.Event()
        self.handled = 0  # messages handled (for tests and logs)
        self.dropped = 0  # QoS 0 messages dropped, the queue full
        self.oversized = 0  # packets over the Maximum Packet Size the broker sent anyway
        self.received = 0  # bytes read from the broker
        self.throttle = Throttle(clock=clock)
        self.log = throttled_logger(__name__, self.throttle, log)
        self.client_log = throttled_logger(f"{__name__}.client", self.throttle, log)
        # the same for every bridge of this data directory on this host, so that the one that
        # takes over (a new process, another worker) resumes the broker session and gets what
        # was not acknowledged
        place = hashlib.sha256(str(self.lock_path.resolve()).encode()).hexdigest()[:12]
        self.identifier = f"{self.prefix}-bridge-{socket.gethostname()}-{place}"
        self._lock: IO[str] | None = None

    # ---- topics ---------------------------------------------------------------------------
    def topic(self, who: Explorer, kind: str) -> str:
        if who.short:
            return f"{self.prefix}/{who.domain}/{who.explorer}/{kind}"
        return f"{self.prefix}/{who.device}/{who.domain}/{who.explorer}/{kind}"

    def _parse(self, topic: str) -> tuple[Explorer, str] | None:
        parts = topic.split("/")
        if parts[0] != self.prefix or parts[-1] not in KINDS:
            return None
        if len(parts) == 4:
            return Explorer(parts[2], parts[1], parts[2], short=True), parts[3]
        if len(parts) == 5:
            return Explorer(parts[1], parts[2], parts[3]), parts[4]
        return None

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
            self._watch_queue(connection)
            self._guard(connection)
            try:
                async with connection as client:
                    backoff = 0.5
                    await self._flush(client)
                    for topic in subscriptions(self.prefix):
                        await client.subscribe(topic, qos=1)
                    self.connected.set()
                    self.log.info(
                        "MQTT bridge connected to %s:%d", self.broker.host, self.broker.port
                    )
                    async for message in client.messages:
                        await self.take(client, message)
            except aiomqtt.MqttError as exc:
                self.connected.clear()
                self.log.warning("MQTT bridge: %s; reconnecting in %.1f s", exc, backoff)
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

    def _watch_queue(self, connection: aiomqtt.Client) -> None:
        """At most ``queue`` QoS 0 messages wait in aiomqtt's queue (unbounded itself): one
        that comes when ``queue`` messages wait is dropped here, counted and logged
        (throttled); the broker does not hold QoS 0 back. QoS 1 messages are never dropped
        here (one dropped unacknowledged would stay in flight at the broker, holding back the
        rest): the broker sends at most ``queue`` unacknowledged ones (Receive Maximum), so at
        most ``2 * queue`` messages wait."""
        paho = connection._client
        deliver = paho.on_message
        queue = connection._queue

        def on_message(client: Any, userdata: Any, message: Any) -> None:
            if not message.qos and queue.qsize() >= self.queue:
                self.dropped += 1
                MQTT_MESSAGES.labels("in", "dropped").inc()
                self.log.warning(
                    "MQTT bridge: %d messages wait already (ADVISOR_MQTT_QUEUE): a QoS 0 "
                    "message on %s was dropped; publish events with QoS 1, which the broker "
                    "holds back until the bridge takes them",
                    self.queue, message.topic,
                )  # fmt: skip
                return
            if deliver is not None:
                deliver(client, userdata, message)

        paho.on_message = on_message

    def _guard(self, connection: aiomqtt.Client) -> None:
        """Never read a packet larger than the Maximum Packet Size the bridge connects with:
        paho reads a packet's length, then asks the socket for that many bytes; asked for more
        than the limit, the connection is closed instead (MQTT v5: a client that gets a packet
        over its maximum disconnects), so not even a buffer of that size is made. A broker that
        honours the maximum (Mosquitto does) never sends one."""
        paho = connection._client
        recv = getattr(paho, "_sock_recv", None)
        if recv is None:  # another paho: the broker's honouring of the maximum is left
            self.log.warning("MQTT bridge: this paho-mqtt has no _sock_recv to guard")
            return

        def guarded(size: int) -> bytes:
            if size > self.max_packet:
                self.oversized += 1
                self.log.warning(
                    "MQTT bridge: the broker sent a packet of %d bytes, more than the "
                    "bridge's Maximum Packet Size of %d (ADVISOR_MAX_BODY_BYTES + %d); "
                    "the connection is closed without reading it",
                    size, self.max_packet, PACKET_HEADROOM,
                )  # fmt: skip
                raise OSError(errno.EMSGSIZE, "packet over the bridge's Maximum Packet Size")
            data: bytes = recv(size)
            self.received += len(data)
            return data

        paho._sock_recv = guarded  # type: ignore[method-assign,assignment]

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
        props.MaximumPacketSize = self.max_packet
        b = self.broker
        return aiomqtt.Client(
            b.host, b.port, username=b.username, password=b.password,
            identifier=self.identifier, protocol=aiomqtt.ProtocolVersion.V5,
            clean_start=False, properties=props,
            tls_context=ssl.create_default_context() if b.tls else None,
            max_queued_incoming_messages=0, max_inflight_messages=100,  # _watch_queue
            timeout=30.0, logger=self.client_log,
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
        who, kind = parsed
        MQTT_MESSAGES.labels("in", kind).inc()
        self.handled += 1
        try:
            try:
                if not all(NAME.match(n) for n in (who.device, who.domain, who.explorer)):
                    raise Refused(422, f"device, domain and explorer ids must match {NAME_PATTERN}")
                if kind == "config":
                    await self.configure(who, payload)
                    return
                decisions = await self.events(who, payload)
            except Refused:
                raise
            except REFUSED as failed:  # Redis or the database does not answer
                refused = unavailable(failed)
                self.log.warning("MQTT bridge: %s", refused.detail)
                raise refused from None
            except Exception:  # a bug: the device is told, the log gets the traceback
                self.log.exception("MQTT bridge: a message on %s failed", topic)
                raise Refused(
                    500, "the service failed on this message (its log says why); nothing is "
                    "known to have been applied: send it again, with steps to be safe",
                ) from None  # fmt: skip
        except Refused as exc:
            later = {} if exc.retry_after is None else {"retry_after": exc.retry_after}
            error = orjson.dumps({"detail": exc.detail, "status": exc.status, **later})
            self.pending.append((self.topic(who, "errors"), error))
            MQTT_MESSAGES.labels("out", "errors").inc()
        else:
            out = self.topic(who, "decisions")
            self.pending.extend((out, d) for d in decisions)
            MQTT_MESSAGES.labels("out", "decisions").inc(len(decisions))

    async def configure(self, who: Explorer, payload: bytes) -> None:
        """A retained config: the options of the explorer's next session (an empty payload
        clears it). A live session of the explorer ends, so the next event starts anew."""
        await self._end(who)
        if not payload:
            self.configs.pop(who, None)
            return
        try:
            body = SessionCreate.model_validate_json(payload)
        except ValidationError as exc:
            raise Refused(422, "config: " + describe_errors(exc.errors())) from None
        self.configs[who] = body
        self.configs.move_to_end(who)
        while len(self.configs) > self.max_explorers:
            self.configs.popitem(last=False)

    async def events(self, who: Explorer, payload: bytes) -> list[bytes]:
        """The decisions for one message of events (a new session's start decision first)."""
        if len(payload) > self.max_bytes:
            raise Refused(413, f"the message is larger than {self.max_bytes} bytes")
        state = self.state
        out: list[bytes] = []
        for _ in range(2):  # a second time if the session ended meanwhile
            session = self.sessions.get(who)
            try:
                if session is None:
                    session, first = await self._open(who, payload)
                    out.append(first)
                    answer = await self._first_answer(who, session, payload)
                else:
                    answer = await ops.answer_events(state, session, payload)
            except SessionNotFound:
                self.sessions.pop(who, None)
                out.clear()
                continue
            except BadInput as exc:
                raise Refused(exc.status, exc.detail) from None
            self.sessions.move_to_end(who)
            if answer.startswith(b"["):
                out += [orjson.dumps(d) for d in orjson.loads(answer)]
            else:
                out.append(answer)
            return out
        raise Refused(404, "the explorer's session ended twice while its message was handled")

    async def _open(self, who: Explorer, payload: bytes) -> tuple[LiveSession, bytes]:
        """A session for the explorer, counted against its device's quota (``mqtt
        <device>``) and the service's caps, as a REST client's."""
        try:
            domain = await self.state.sessions.domain(who.domain)
        except DomainNotFound:
            raise Refused(404, f"no domain named {who.domain!r}") from None
        body = self.configs.get(who) or SessionCreate()
        if body.start is None:
            body = body.model_copy(update={"start": _first_state(payload)})
        try:
            session, decision = await ops.open_session(self.state, domain, body, who.client)
        except BadInput as exc:  # 429: the device's quota; 503: the service's caps
            raise Refused(exc.status, exc.detail.replace(REST_END, MQTT_END)) from None
        self.sessions[who] = session
        while len(self.sessions) > self.max_explorers:
            await self._end(next(iter(self.sessions)))
        leads = decision_leads_to(session, decision)
        return session, decision_json(decision, domain.domain, leads)

    async def _first_answer(self, who: Explorer, session: LiveSession, payload: bytes) -> bytes:
        """The events of the message that opened ``session``: refused, or failing, they end
        it, so that nothing is left of the message (its start decision was not published) and
        the explorer's next message opens its session anew."""
        try:
            return await ops.answer_events(self.state, session, payload)
        except Exception:
            try:
                await self._end(who)
            except Exception as exc:  # Redis down: the session expires when idle
                self.log.warning("MQTT bridge: a session could not be ended: %s", exc)
            raise

    async def _end(self, who: Explorer) -> None:
        session = self.sessions.pop(who, None)
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
    if not (
        isinstance(state, list) and len(state) in (2, 3) and all(type(v) is int for v in state)
    ):
        raise Refused(
            422,
            "event 0: state must be a cell [row, col] ([floor, row, col] on a map of "
            "several floors)",
        )
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
