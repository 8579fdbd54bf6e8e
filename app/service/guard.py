"""The HTTP connection guard: uvicorn's httptools protocol with the bounds it lacks.

uvicorn with httptools reads request headers of any size (a 48 MB header was accepted) and
without a deadline (sockets trickling a byte every few seconds stay open for ever), and it
accepts every connection. :func:`guarded_http` makes its protocol class with:

* a bound on the request's headers (``max_header_bytes``, 16 KiB): the bytes received while a
  request's headers are incomplete, counted as they arrive, so the parser never holds more than
  that and one network read, and the request line and headers once parsed; over it: 431, and
  the connection closes;
* deadlines: the headers within ``header_timeout`` seconds of the connection (or of the
  request's first byte, on a kept-alive connection), the body within ``body_timeout`` seconds
  of the headers: 408, and the connection closes;
* a cap on open connections (``max_connections``, websockets included): a connection beyond it
  is answered 503 and closed at once;
* a cap on one client's open connections (``client_max_connections``, by the peer's address;
  addresses of trusted proxies are not capped): beyond it 429 and closed at once, so that one
  slow client cannot take every place;
* malformed HTTP answered as every other client error is: a JSON body ``{"detail": ...}``;
  so are websocket handshakes that are not valid (:class:`JsonWebSocket`, uvicorn's ``ws``).

It also leaves out the access-log line of an event request when the service drops those lines
anyway (:func:`app.service.logs.event_lines_dropped`): uvicorn would make it, arguments and
record, only for the service's filter to drop it.

httptools stays the parser (uvicorn's h11 bounds headers too, but parses several times slower
in pure Python; docs/PERFORMANCE.md). ``make run`` still needs only Python.
"""

from __future__ import annotations

import asyncio
import email.utils
import http
import json
import logging
from collections import Counter
from collections.abc import Callable
from typing import Any, ClassVar

import httptools
from uvicorn.config import Config
from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol
from uvicorn.protocols.websockets.websockets_sansio_impl import WebSocketsSansIOProtocol
from uvicorn.server import ServerState
from websockets.datastructures import Headers
from websockets.exceptions import SecurityError
from websockets.http11 import MAX_LINE_LENGTH, MAX_NUM_HEADERS, Response
from websockets.server import ServerProtocol
from websockets.typing import StatusLike

from app.service.clients import Network, networks, trusted
from app.service.config import Settings
from app.service.logs import EVENT_RAW_PATH, event_lines_dropped

log = logging.getLogger("uvicorn.error")


class _Refused(Exception):
    """Raised in a parser callback once the request was refused: the parser stops there."""


class GuardedHttpTools(HttpToolsProtocol):
    """:class:`HttpToolsProtocol` with bounded headers, read deadlines and caps on connections,
    in all and per client (the class attributes; :func:`guarded_http` sets them from the
    service's settings)."""

    max_header_bytes = 16 * 1024
    header_timeout = 10.0
    body_timeout = 30.0
    max_connections = 1000
    client_max_connections = 256
    trusted_proxies: tuple[Network, ...] = ()
    per_client: ClassVar[Counter[str]] = Counter()  # open connections by address (uncapped ones
    # not counted); :func:`guarded_http` gives each server its own

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._in_headers = True
        self._header_bytes = 0
        self._timer: asyncio.TimerHandle | None = None
        self._refused = False
        self._counted: str | None = None  # the address this connection counts against
        self._no_event_lines = event_lines_dropped()
        if len(self.connections) > self.max_connections:
            self.refuse(503, f"the service holds its maximum of {self.max_connections} connections")
            return
        host = self.client[0] if self.client else None
        if host is not None and not trusted(host, self.trusted_proxies):
            if self.per_client[host] >= self.client_max_connections:
                self.refuse(
                    429,
                    f"this client (address {host}) holds {self.client_max_connections} open "
                    "connections, the most one client may (ADVISOR_CLIENT_MAX_CONNECTIONS): "
                    "close one, or send more requests over each",
                )
                return
            self.per_client[host] += 1
            self._counted = host
        self._arm_headers()

    def connection_lost(self, exc: Exception | None) -> None:
        self._disarm()
        self.release()
        super().connection_lost(exc)

    def release(self) -> None:
        """This connection no longer counts against its client's cap (once)."""
        host, self._counted = self._counted, None
        if host is not None:
            left = self.per_client[host] - 1
            if left > 0:
                self.per_client[host] = left
            else:
                del self.per_client[host]

    def data_received(self, data: bytes) -> None:
        if self._refused:
            return
        self._unset_keepalive_if_required()
        try:
            self.parser.feed_data(data)
        except httptools.HttpParserUpgrade:
            if self._should_upgrade():
                self.handle_websocket_upgrade()
            else:
                self._unsupported_upgrade_warning()
            return
        except httptools.HttpParserError as exc:
            self.refuse(400, f"the request is not valid HTTP/1.1 ({exc})")
            return
        if self._in_headers:  # every byte of this read belongs to headers not yet complete
            self._header_bytes += len(data)
            if self._header_bytes > self.max_header_bytes:
                self._too_large()

    # ---- parser callbacks ----------------------------------------------------------------
    def on_message_begin(self) -> None:
        super().on_message_begin()
        self._in_headers = True
        self._header_bytes = 0
        if self._timer is None:  # a new request on a kept-alive connection
            self._arm_headers()

    def on_headers_complete(self) -> None:
        self._in_headers = False
        self._header_bytes = 0
        self._disarm()
        size = len(self.url) + sum(len(name) + len(value) + 4 for name, value in self.headers)
        if size > self.max_header_bytes:  # headers that arrived whole in one read
            self._too_large()
            raise _Refused  # stops the parser: no application task for this request
        super().on_headers_complete()
        cycle = self.cycle
        if cycle is not None and cycle.scope is self.scope:  # not an upgrade
            if self._no_event_lines and EVENT_RAW_PATH.match(self.scope["raw_path"]):
                cycle.access_log = False  # its line would be dropped: not made
            self._arm(self.body_timeout, "body")

    def on_message_complete(self) -> None:
        self._disarm()
        super().on_message_complete()

    def handle_websocket_upgrade(self) -> None:
        self._disarm()
        super().handle_websocket_upgrade()
        # the transport's protocol is the websocket's now: it is the one told when the
        # connection ends, so it releases the client's place
        protocol = self.transport.get_protocol()
        if isinstance(protocol, JsonWebSocket) and not protocol.disconnected:
            protocol.release = self.release
        else:
            self.release()

    def send_400_response(self, msg: str) -> None:
        self.refuse(400, msg)

    # ---- deadlines and refusals ----------------------------------------------------------
    def _too_large(self) -> None:
        self.refuse(431, f"the request's headers are larger than {self.max_header_bytes} bytes")

    def _arm_headers(self) -> None:
        self._arm(self.header_timeout, "headers")

    def _arm(self, seconds: float, what: str) -> None:
        self._disarm()
        self._timer = self.loop.call_later(seconds, self._expired, what, seconds)

    def _disarm(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def _expired(self, what: str, seconds: float) -> None:
        self._timer = None
        if self.transport.is_closing():
            return
        if (
            self.cycle is not None
            and self.cycle.scope is self.scope
            and self.cycle.response_started
        ):
            self.transport.close()  # answered already (a refusal before the body was read)
            return
        self.refuse(408, f"the request's {what} did not arrive within {seconds:g} s")

    def refuse(self, status: int, detail: str) -> None:
        """Answer ``status`` with ``{"detail": detail}`` and close the connection."""
        self._refused = True
        self._disarm()
        if self.transport.is_closing():
            return
        log.info("%s: %d %s", self._peer(), status, detail)
        body = json.dumps({"detail": detail}).encode()
        head = [f"HTTP/1.1 {status} {http.HTTPStatus(status).phrase}".encode()]
        head += [name + b": " + value for name, value in self.server_state.default_headers]
        head += [
            b"content-type: application/json",
            b"content-length: " + str(len(body)).encode(),
            b"connection: close",
        ]
        self.transport.write(b"\r\n".join(head) + b"\r\n\r\n" + body)
        self.transport.close()
        if self.cycle is not None and not self.cycle.response_complete:
            self.cycle.disconnected = True  # the application's answer, if any, goes nowhere
            self.cycle.message_event.set()

    def _peer(self) -> str:
        return f"{self.client[0]}:{self.client[1]}" if self.client else "a client"


def guarded_http(
    max_header_bytes: int,
    header_timeout: float,
    body_timeout: float,
    max_connections: int,
    client_max_connections: int,
    trusted_proxies: list[str],
) -> type[GuardedHttpTools]:
    """The protocol class with these bounds (uvicorn's ``http`` option), with a count of open
    connections by client of its own."""
    attrs: dict[str, Any] = {
        "max_header_bytes": max_header_bytes,
        "header_timeout": header_timeout,
        "body_timeout": body_timeout,
        "max_connections": max_connections,
        "client_max_connections": client_max_connections,
        "trusted_proxies": networks(trusted_proxies),
        "per_client": Counter(),
    }
    return type("GuardedHttp", (GuardedHttpTools,), attrs)


def guarded_http_of(settings: Settings) -> type[GuardedHttpTools]:
    """:func:`guarded_http` with the service's settings (the connection cap as
    :func:`connection_cap` lowers it)."""
    return guarded_http(
        settings.max_header_bytes, settings.header_timeout, settings.body_timeout,
        connection_cap(settings.max_connections, settings.log_format),
        settings.client_max_connections,
        settings.trusted_proxies,
    )  # fmt: skip


# ---- websocket handshakes ----------------------------------------------------------------------
class _JsonRefusals(ServerProtocol):
    """websockets' server side of the handshake, refusing with a JSON body ``{"detail": ...}``
    that says what was wrong (websockets writes text/plain "Failed to open a WebSocket
    connection: ...")."""

    def reject(self, status: StatusLike, text: str) -> Response:
        status = http.HTTPStatus(status)
        body = json.dumps({"detail": self.refusal(status)}).encode()
        headers = Headers(
            [
                ("Date", email.utils.formatdate(usegmt=True)),
                ("Connection", "close"),
                ("Content-Length", str(len(body))),
                ("Content-Type", "application/json"),
            ]
        )
        return Response(status.value, status.phrase, headers, body)

    def refusal(self, status: http.HTTPStatus) -> str:
        exc: BaseException | None = self.handshake_exc
        if exc is None:  # the application closed before accepting, or failed
            if status == http.HTTPStatus.FORBIDDEN:
                return "the service refused the websocket before opening it"
            return "the service could not open the websocket"
        if isinstance(exc.__cause__, SecurityError):  # websockets' bounds on what it reads
            return (
                f"the websocket handshake's headers are too large ({exc.__cause__}): at most "
                f"{MAX_NUM_HEADERS} headers of {MAX_LINE_LENGTH} bytes a line"
            )
        reasons = [str(exc)]
        while exc.__cause__ is not None:
            exc = exc.__cause__
            reasons.append(str(exc))
        return "the websocket handshake is invalid: " + "; ".join(r for r in reasons if r)


class JsonWebSocket(WebSocketsSansIOProtocol):
    """uvicorn's websocket protocol (websockets' sans-I/O implementation, uvicorn's default)
    whose refusals of a handshake are JSON 4xx answers: 400 for a handshake that is not valid
    (no ``Sec-WebSocket-Key``, a key that is not 16 bytes of base64, a version other than 13,
    a request websockets cannot read), 431 for headers over websockets' limits (a line over
    8 KiB, more than 128 headers). Valid handshakes go to the application as before.
    uvicorn's ``ws`` option."""

    release: Callable[[], None] | None = None  # given by the HTTP connection it came from

    def __init__(
        self,
        config: Config,
        server_state: ServerState,
        app_state: dict[str, Any],
        _loop: asyncio.AbstractEventLoop | None = None,
    ) -> None:
        super().__init__(config, server_state, app_state, _loop)
        self.conn = _JsonRefusals(
            extensions=self.conn.available_extensions,
            max_size=config.ws_max_size,
            logger=logging.getLogger("uvicorn.error"),
        )

    def handle_handshake_exception(self) -> None:
        # websockets could not read the request (uvicorn answers 400 "invalid request", or
        # sends what websockets queued): say why
        self.handshake_complete = True
        self.close_sent = True
        self.conn.data_to_send()  # whatever websockets queued: not sent
        exc = self.conn.handshake_exc
        too_large = exc is not None and isinstance(exc.__cause__, SecurityError)
        response = self.conn.reject(431 if too_large else 400, "")
        self.transport.write(response.serialize())
        self.transport.close()

    def connection_lost(self, exc: Exception | None) -> None:
        super().connection_lost(exc)
        if self.release is not None:
            self.release()
            self.release = None


def connection_cap(wanted: int, log_format: str = "text") -> int:
    """``wanted``, or fewer if the process may not open that many files (each connection is
    one; 64 are kept for the database, logs and the rest)."""
    import resource

    from app.service.logs import announce

    soft, _ = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft != resource.RLIM_INFINITY and soft - 64 < wanted:
        note = f"max_connections {wanted} lowered to {soft - 64} (open files limit {soft})"
        announce(note, log_format, logging.WARNING)
        return max(soft - 64, 1)
    return wanted
