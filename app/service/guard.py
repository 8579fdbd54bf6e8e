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
* malformed HTTP answered as every other client error is: a JSON body ``{"detail": ...}``.

httptools stays the parser (uvicorn's h11 bounds headers too, but parses several times slower
in pure Python; docs/PERFORMANCE.md). ``make run`` still needs only Python.
"""

from __future__ import annotations

import asyncio
import http
import json
import logging
from typing import Any

import httptools
from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol

log = logging.getLogger("uvicorn.error")


class _Refused(Exception):
    """Raised in a parser callback once the request was refused: the parser stops there."""


class GuardedHttpTools(HttpToolsProtocol):
    """:class:`HttpToolsProtocol` with bounded headers, read deadlines and a connection cap
    (the class attributes; :func:`guarded_http` sets them from the service's settings)."""

    max_header_bytes = 16 * 1024
    header_timeout = 10.0
    body_timeout = 30.0
    max_connections = 1000

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._in_headers = True
        self._header_bytes = 0
        self._timer: asyncio.TimerHandle | None = None
        self._refused = False
        if len(self.connections) > self.max_connections:
            self.refuse(503, f"the service holds its maximum of {self.max_connections} connections")
            return
        self._arm_headers()

    def connection_lost(self, exc: Exception | None) -> None:
        self._disarm()
        super().connection_lost(exc)

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
        if self.cycle is not None and self.cycle.scope is self.scope:  # not an upgrade
            self._arm(self.body_timeout, "body")

    def on_message_complete(self) -> None:
        self._disarm()
        super().on_message_complete()

    def handle_websocket_upgrade(self) -> None:
        self._disarm()
        super().handle_websocket_upgrade()

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
    max_header_bytes: int, header_timeout: float, body_timeout: float, max_connections: int
) -> type[GuardedHttpTools]:
    """The protocol class with these bounds (uvicorn's ``http`` option)."""
    attrs: dict[str, Any] = {
        "max_header_bytes": max_header_bytes,
        "header_timeout": header_timeout,
        "body_timeout": body_timeout,
        "max_connections": max_connections,
    }
    return type("GuardedHttp", (GuardedHttpTools,), attrs)


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
