"""Prometheus metrics (``GET /metrics``), all named ``advisor_...``.

Requests are counted by a pure ASGI middleware under their *route template*
(``/sessions/{session_id}/events``, never the raw path), method and status, so the number of
series is bounded by the routes the service has; a path no route matches is counted as
``<unmatched>``, and a method that is not the route's (``DELETE /health``, ``PROPFIND``) as
``OTHER`` (on a path no route matches: one that no route has): no label takes a value the
client chose. Decisions and advice are counted per domain and strategy (domains are created
by the admin only, strategies are a fixed list), expert trajectories per domain.

Cost on the hot path: one labelled child per (route, method, status) is looked up in a dict and
incremented; the histograms keep a handful of buckets (docs/PERFORMANCE.md, "Metrics and access
log", measures the difference).

Several worker processes: set ``PROMETHEUS_MULTIPROC_DIR`` (an empty directory, before the
workers start), as prometheus-client's multiprocess mode asks; ``/metrics`` then sums the
workers' counters and histograms. The live-sessions gauge is not a sum: workers share their
sessions through Redis and each counts all of them, so every worker sets it from that global
count, at every scrape it answers (just before it reads the files) and every few seconds, and
``/metrics`` reports the value set last, whoever set it (``livemostrecent``). A worker killed
(SIGKILL) leaves its file behind; its value is older than the scraping worker's, so it does
not count, and the worker uvicorn starts in its place removes the files of processes that no
longer run (``multiprocess.mark_process_dead``, :func:`forget_dead_workers`).
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import time
from collections.abc import Callable, Collection
from pathlib import Path
from typing import Any

from prometheus_client import (
    REGISTRY,
    CollectorRegistry,
    Counter,
    Gauge,
    Histogram,
    disable_created_metrics,
    generate_latest,
)
from prometheus_client import multiprocess as mp
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from app.service.live.sessions import Sessions
from app.service.logs import REQUEST_ID, new_request_id

disable_created_metrics()  # type: ignore[no-untyped-call]  # no ``_created`` series beside each counter (half the text)
UNMATCHED = "<unmatched>"
#: the method label of a request whose method is not its route's (on a path no route matches:
#: no route's)
OTHER_METHOD = "OTHER"
#: seconds; an event answer takes ~0.2 ms, an ingest or a domain PUT up to seconds
LATENCY_BUCKETS = (0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 10)
TICK_BUCKETS = (0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 1.0)
#: how often each worker refreshes its live-sessions gauge besides the scrapes it answers
GAUGE_SECONDS = 5.0

REQUESTS = Counter(
    "advisor_http_requests",
    "HTTP requests answered and websocket connections opened, by method, route template and "
    "status (websockets: 101 accepted, else the close code sent before accepting, or the "
    "HTTP status of a refusal).",
    ["method", "route", "status"],
)
LATENCY = Histogram(
    "advisor_http_request_duration_seconds",
    "Time from a request's arrival to the end of its answer, by method and route template.",
    ["method", "route"],
    buckets=LATENCY_BUCKETS,
)
SESSIONS = Gauge(
    "advisor_live_sessions",
    "Live sessions, by domain.",
    ["domain"],
    # several workers share their sessions through Redis, and each counts all of them: the
    # value set last (at the scrape being answered) is the count, a dead worker's never is
    multiprocess_mode="livemostrecent",
)
DECISIONS = Counter(
    "advisor_decisions",
    "Decisions made (one per event, one per new session).",
    ["domain", "strategy"],
)
ADVICE = Counter(
    "advisor_advice", "Decisions that gave advice (each costs kappa).", ["domain", "strategy"]
)
TRAJECTORIES = Counter(
    "advisor_trajectories_ingested",
    "Expert trajectories stored (posted, or simulated experts of a domain PUT).",
    ["domain"],
)
PAIRS = Counter(
    "advisor_trajectory_pairs_ingested",
    "(state, action) pairs of the expert trajectories stored.",
    ["domain"],
)
VIEWER_TICK = Histogram(
    "advisor_viewer_tick_seconds",
    "Time the viewer takes to bring its scene up to date once (one snapshot, one redraw).",
    buckets=TICK_BUCKETS,
)
MQTT_MESSAGES = Counter(
    "advisor_mqtt_messages",
    "MQTT messages of the bridge: received (events, config) and published (decisions, errors).",
    ["direction", "kind"],
)

Child = tuple[Callable[[float], None], Callable[[float], None]]


class Metrics:
    """The labelled children the hot path uses, made once each (a dict lookup per use)."""

    def __init__(self) -> None:
        self._http: dict[tuple[str, str, int], Child] = {}
        self._decisions: dict[tuple[str, str], tuple[Counter, Counter]] = {}

    def request(self, method: str, route: str, status: int, seconds: float | None) -> None:
        key = (method, route, status)
        child = self._http.get(key)
        if child is None:
            child = (
                REQUESTS.labels(method, route, str(status)).inc,
                LATENCY.labels(method, route).observe,
            )
            self._http[key] = child
        child[0](1.0)
        if seconds is not None:
            child[1](seconds)

    def decisions(self, domain: str, strategy: str, made: int, advised: int) -> None:
        key = (domain, strategy)
        pair = self._decisions.get(key)
        if pair is None:
            pair = (DECISIONS.labels(domain, strategy), ADVICE.labels(domain, strategy))
            self._decisions[key] = pair
        pair[0].inc(made)
        if advised:
            pair[1].inc(advised)

    def forget_domain(self, domain: str) -> None:
        """A deleted domain's series go (its counters would otherwise stay forever)."""
        for key in [k for k in self._decisions if k[0] == domain]:
            del self._decisions[key]
            for metric in (DECISIONS, ADVICE):
                _remove(metric, *key)
        for series in (TRAJECTORIES, PAIRS, SESSIONS):
            _remove(series, domain)


def _remove(metric: Counter | Gauge, *labels: str) -> None:
    with contextlib.suppress(KeyError):
        metric.remove(*labels)


METRICS = Metrics()


def ingested(domain: str, trajectories: int, pairs: int) -> None:
    TRAJECTORIES.labels(domain).inc(trajectories)
    PAIRS.labels(domain).inc(pairs)


def viewer_tick(seconds: float) -> None:
    """The hook the viewer calls after each tick (wherever the viewer runs, this is all it
    needs to report)."""
    VIEWER_TICK.observe(seconds)


async def refresh_sessions(sessions: Sessions) -> None:
    """Set the live-sessions gauge (domains without sessions show 0)."""
    counts = await sessions.count_by_domain()
    for d in sessions.catalog.states():
        SESSIONS.labels(d.name).set(counts.get(d.name, 0))


async def keep_gauges(sessions: Sessions) -> None:
    """Refresh this worker's gauge now and then (other workers' scrapes read it)."""
    while True:
        await refresh_sessions(sessions)
        await asyncio.sleep(GAUGE_SECONDS)


def forget_dead_workers() -> list[int]:
    """In multiprocess mode, mark dead every process whose live-gauge files are in
    ``PROMETHEUS_MULTIPROC_DIR`` but which no longer runs (a worker killed, whose supervisor
    started this one); their pids. Their counters stay: what they counted happened."""
    path = os.environ.get("PROMETHEUS_MULTIPROC_DIR")
    if not path:
        return []
    gone: set[int] = set()
    for f in Path(path).glob("gauge_live*_*.db"):
        digits = f.stem.rsplit("_", 1)[-1]
        if digits.isdigit() and int(digits) != os.getpid() and not _running(int(digits)):
            gone.add(int(digits))
    for pid in gone:
        mp.mark_process_dead(pid, path)  # type: ignore[no-untyped-call]
    return sorted(gone)


def _running(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process: it runs
        return True
    return True


class _SizedFiles(mp.MultiProcessCollector):
    """prometheus-client's collector of every process's files, without the files a process
    has created but not yet sized: a metric's file is created empty and then sized, and
    reading it in between raised (``struct.error``), so /metrics answered 500 while a new
    worker started (prometheus/client_python issue 1199). An empty file holds no value yet."""

    def collect(self) -> Any:
        files = []
        for f in Path(self._path).glob("*.db"):
            with contextlib.suppress(FileNotFoundError):  # a dead worker's live gauge, gone
                if f.stat().st_size >= 8:  # sized: its 8-byte header at least
                    files.append(str(f))
        return self.merge(files, accumulate=True)  # type: ignore[no-untyped-call]


def exposition() -> bytes:
    """The metrics in Prometheus' text format (every worker's, in multiprocess mode)."""
    if "PROMETHEUS_MULTIPROC_DIR" in os.environ:
        registry = CollectorRegistry()
        _SizedFiles(registry)  # type: ignore[no-untyped-call]
        return generate_latest(registry)
    return generate_latest(REGISTRY)


def route_methods(*routers: Any) -> frozenset[str]:
    """The HTTP methods of the routes of ``routers`` (anything with ``routes``: an app's
    router, an ``APIRouter``), as the metrics' method label keeps them."""
    return frozenset(
        method
        for router in routers
        for route in router.routes
        for method in (getattr(route, "methods", None) or ())
    )


class MetricsMiddleware:
    """Counts every request by route template, method and status and times it; a method that
    is not the matched route's, or on a path no route matches none of ``methods`` (the
    routes', :func:`route_methods`), is counted as ``OTHER``. With ``request_ids``, gives
    each request an id (its ``X-Request-ID`` if it sent one of sane length, else a new one)
    that the JSON logs carry and the answer's ``X-Request-ID`` header echoes."""

    def __init__(
        self, app: ASGIApp, request_ids: bool = False, methods: Collection[str] = ()
    ) -> None:
        self.app = app
        self.request_ids = request_ids
        self.methods = frozenset(methods)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        kind = scope["type"]
        if kind == "http":
            await self._http(scope, receive, send)
        elif kind == "websocket":
            await self._websocket(scope, receive, send)
        else:
            await self.app(scope, receive, send)

    async def _http(self, scope: Scope, receive: Receive, send: Send) -> None:
        started = time.perf_counter()
        status = 500
        header: bytes | None = None
        if self.request_ids:
            rid = _given_id(scope) or new_request_id()
            REQUEST_ID.set(rid)
            header = rid.encode("latin-1")

        async def send_counted(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
                if header is not None:
                    message["headers"] = [*message.get("headers", []), (b"x-request-id", header)]
            await send(message)

        try:
            await self.app(scope, receive, send_counted)
        finally:
            method = scope["method"]
            if method not in (getattr(scope.get("route"), "methods", None) or self.methods):
                method = OTHER_METHOD  # not the route's (405), or no route's
            METRICS.request(method, _route(scope), status, time.perf_counter() - started)

    async def _websocket(self, scope: Scope, receive: Receive, send: Send) -> None:
        status = 1006  # the connection went before an answer

        async def send_counted(message: Message) -> None:
            nonlocal status
            if status == 1006:
                if message["type"] == "websocket.accept":
                    status = 101
                elif message["type"] == "websocket.close":
                    status = int(message.get("code", 1000))
                elif message["type"] == "websocket.http.response.start":
                    status = int(message["status"])  # refused with an HTTP answer
            await send(message)

        try:
            await self.app(scope, receive, send_counted)
        finally:
            METRICS.request("WS", _route(scope), status, None)


def _route(scope: Scope) -> str:
    """The route template; for a mounted app (static files) its prefix and ``/{path}``."""
    path = getattr(scope.get("route"), "path", None)
    if isinstance(path, str):
        return path
    mounted = scope.get("root_path")
    return f"{mounted}/{{path}}" if isinstance(mounted, str) and mounted else UNMATCHED


def _given_id(scope: Scope) -> str | None:
    for key, value in scope["headers"]:
        if key == b"x-request-id":
            text: str = value.decode("latin-1")
            if 0 < len(text) <= 64 and text.isprintable():
                return text
    return None
