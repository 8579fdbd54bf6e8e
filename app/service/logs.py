"""Logs: optional JSON lines with a request id, and the event routes kept out of the access log.

``ADVISOR_LOG_FORMAT=json`` writes every log line (uvicorn's, the access log's, the service's,
the viewer's, and the lines for the operator such as a key made at first start, through
:func:`announce`) as one JSON object: ``time``, ``level``, ``logger``, ``message``, the
``request_id`` of the request being answered (given by the client as ``X-Request-ID`` or made
here, and echoed in the answer's header), and for access lines ``method``, ``path``,
``status``, ``client``.

A line per request costs a small endpoint about a third of its throughput (docs/PERFORMANCE.md,
"Metrics and access log"), so by default the event routes (``POST /sessions/{id}/events`` and
the websocket) are counted by the metrics and not logged line by line (the HTTP protocol does
not even make their lines: :func:`event_lines_dropped`); ``ADVISOR_ACCESS_LOG_EVENTS=true``
logs them too. Every other route keeps its access line.
"""

from __future__ import annotations

import logging
import re
import secrets
import sys
import time
from contextvars import ContextVar
from typing import Any

from pythonjsonlogger.core import RESERVED_ATTRS
from pythonjsonlogger.orjson import OrjsonFormatter

REQUEST_ID: ContextVar[str | None] = ContextVar("advisor_request_id", default=None)
#: the paths of the event routes, as uvicorn's log lines carry them
EVENT_PATH = re.compile(r"^/sessions/[^/?]+/(?:events|stream)(?:\?|$)")
#: the same for a request's raw path (ASGI's ``raw_path``, the bytes the log line shows)
EVENT_RAW_PATH = re.compile(EVENT_PATH.pattern.encode())
ACCESS_FIELDS = ("client", "method", "path", "http_version", "status")
#: python-json-logger's field names -> this service's
RENAMED = {"asctime": "time", "levelname": "level", "name": "logger", "exc_info": "exception"}


def new_request_id() -> str:
    return secrets.token_hex(8)


class JsonFormatter(OrjsonFormatter):
    """One JSON object per line: python-json-logger's formatter (with orjson, which the
    service serializes with anyway; no slower a record than the one written here before:
    docs/ARCHITECTURE.md), its fields named ``time`` (UTC, milliseconds), ``level``,
    ``logger``, ``message`` and ``exception``, with the request id and an access line's
    fields added. A record's ``extra`` fields come along (uvicorn's ``color_message`` not)."""

    default_time_format = "%Y-%m-%dT%H:%M:%S"
    default_msec_format = "%s.%03dZ"
    converter = time.gmtime  # type: ignore[assignment]  # (typeshed: gmtime has overloads)

    def __init__(self) -> None:
        super().__init__(
            "{asctime}{levelname}{name}{message}",
            style="{",
            rename_fields=RENAMED,
            reserved_attrs=[*RESERVED_ATTRS, "color_message"],
        )

    def add_fields(
        self, log_data: dict[str, Any], record: logging.LogRecord, message_dict: dict[str, Any]
    ) -> None:
        super().add_fields(log_data, record, message_dict)
        rid = REQUEST_ID.get()
        if rid is not None:
            log_data["request_id"] = rid
        args = record.args
        if record.name == "uvicorn.access" and isinstance(args, tuple) and len(args) == 5:
            log_data.update(zip(ACCESS_FIELDS, args, strict=True))


def announce(
    message: str, log_format: str = "text", level: int = logging.INFO, logger: str = "advisor"
) -> None:
    """A line for the operator on stderr (a key made, the default domain created, sessions
    kept...), written whether or not logging is set up yet: as it is, or with ``log_format``
    "json" as one JSON object like every other line."""
    if log_format == "json":
        record = logging.LogRecord(logger, level, __file__, 0, message, None, None)
        message = JsonFormatter().format(record)
    print(message, file=sys.stderr, flush=True)


def json_logging(level: int = logging.INFO) -> None:
    """The root logger writes JSON lines to stderr, and Python's warnings go through it (for a
    process that does not run uvicorn: the viewer)."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(JsonFormatter())
    logging.basicConfig(level=level, handlers=[handler], force=True)
    logging.captureWarnings(True)


class SkipEventRoutes(logging.Filter):
    """Drops uvicorn's line for each event request and websocket connection (they are counted
    by the metrics instead)."""

    def filter(self, record: logging.LogRecord) -> bool:
        args = record.args
        if record.name == "uvicorn.access":
            path = args[2] if isinstance(args, tuple) and len(args) > 2 else None
        elif isinstance(record.msg, str) and record.msg.startswith('%s - "WebSocket'):
            path = args[1] if isinstance(args, tuple) and len(args) > 1 else None
        else:  # websockets' own "connection open/closed": the only websocket is the stream
            return record.msg not in ("connection open", "connection closed")
        return not (isinstance(path, str) and EVENT_PATH.match(path))


def quiet_event_routes() -> None:
    """Install :class:`SkipEventRoutes` on uvicorn's access and error loggers (once)."""
    for name in ("uvicorn.access", "uvicorn.error"):
        logger = logging.getLogger(name)
        if not any(isinstance(f, SkipEventRoutes) for f in logger.filters):
            logger.addFilter(SkipEventRoutes())


def event_lines_dropped() -> bool:
    """Whether the access log drops the event routes' lines (:func:`quiet_event_routes`): the
    HTTP protocol then does not make them (``app.service.guard``). Making a line that the
    filter drops costs about 40 us of CPU a request at ``--log-level info``, where the line
    is made; at ``warning`` a few, for the arguments of a call that logs nothing."""
    logger = logging.getLogger("uvicorn.access")
    return any(isinstance(f, SkipEventRoutes) for f in logger.filters)


def json_log_config(level: str = "info") -> dict[str, Any]:
    """uvicorn's ``log_config`` for JSON lines: its loggers and the root (the service's own
    loggers) to stderr, the access log to stdout, as uvicorn's default has them."""
    formatter = {"()": f"{__name__}.JsonFormatter"}
    handler = {"class": "logging.StreamHandler", "formatter": "json"}
    return {
        "version": 1,
        "disable_existing_loggers": False,
        "formatters": {"json": formatter},
        "handlers": {
            "default": handler | {"stream": "ext://sys.stderr"},
            "access": handler | {"stream": "ext://sys.stdout"},
        },
        "loggers": {
            "uvicorn": {"handlers": ["default"], "level": level.upper(), "propagate": False},
            "uvicorn.error": {"level": level.upper()},
            "uvicorn.access": {"handlers": ["access"], "level": "INFO", "propagate": False},
        },
        "root": {"handlers": ["default"], "level": "INFO"},
    }
