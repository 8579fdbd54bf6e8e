"""Server CPU per part of a REST request (one event per POST), in process, each part toggled.

The request goes through everything the server runs for it except the socket: its bytes, as
wrk writes them, are fed to uvicorn's HTTP protocol (the service's guarded one, as ``serve``
builds it) over an in-memory transport, on uvloop (``serve``'s loop); the protocol parses them,
starts the ASGI task, the service's app answers and the protocol writes the answer to the
transport. Requests go round 64 sessions and 32 connections (kept alive), with the bodies of
``bench_service.py --only rest``; the figure is thread CPU time per request.

Each part is measured by switching it off and nothing else: a run of the whole service and a
run with the part off follow each other (in each round, for every part, in turn), and the part
costs the median over the rounds of (whole - without it). What "off" means for each part:

* guard: uvicorn's own httptools protocol instead of the guarded one (header bounds, read
  deadlines, connection caps: a timer armed and cancelled per request, a header count);
* per-client caps (connections): per *connection*, not per request: timed apart, a connection
  made and lost with and without the guard;
* body and websocket checks: the service's app without the layer(s) that refuse bodies over
  the limit (413) or not JSON (415) and websockets to no websocket route;
* metrics (requests): the app without the request-counting part of the metrics (the route
  template, the counter, the latency histogram, the clock);
* metrics (decisions): the decisions and advice counters not incremented;
* request ids: the service as ``ADVISOR_LOG_FORMAT=json`` runs it (ids on) against the whole
  service (ids off; the benchmarks' setting): a cost only the JSON-logs service pays, so it is
  the difference the other way round;
* access log: uvicorn's call to the access logger skipped (``access_log`` off), at the
  benchmarks' ``--log-level warning`` and at ``serve``'s default ``info`` (where the event
  routes' lines are made and then dropped by the service's filter unless it skips them first);
* token check: the session found by its id without the bearer token read and checked;
* reading the event: ``read_move`` answered from a table of the bodies' moves;
* the decision: the session's ``observe_one`` answered with a decision made beforehand (no
  advisor update, no rings, no replay row);
* answer building: ``decision_json`` answered with bytes of the same length made beforehand;
* route work, all of the above that the endpoint does (token check, read, decide, count,
  write): the endpoint answering stored bytes after reading the body;
* route handler: what the route's ASGI app does around the endpoint function (FastAPI's:
  parameters resolved and validated, exit stacks, exception handling; or the service's own
  handler) against a function calling the endpoint function at once.

The bare FastAPI endpoint of ``baseline_app.py`` (parses the body, answers the same number of
bytes) runs under the same guarded protocol: the yardstick ``bench_service.py`` uses.

    .venv/bin/python benchmarks/rest_parts.py [--rounds 11] [--requests 2000] [--root DIR]

``--root DIR`` takes the service from another source tree (e.g. an older commit unpacked with
``git worktree add``), for before/after figures; this tree's baseline app either way.
"""

from __future__ import annotations

import argparse
import asyncio
import gc
import json
import logging
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parents[1]
SESSIONS = 64
CONNECTIONS = 32
EVENTS = "/sessions/{session_id}/events"

Undo = Callable[[], None]


class Transport(asyncio.Transport):
    """An in-memory transport: counts what the protocol writes, and calls ``done`` at the end
    of each answer (the protocol tells it through ``on_response_complete``)."""

    def __init__(self, peer: tuple[str, int]) -> None:
        super().__init__()
        self.peer = peer
        self.closing = False
        self.written = 0
        self.head = b""
        self.protocol: asyncio.BaseProtocol | None = None

    def get_extra_info(self, name: str, default: Any = None) -> Any:
        if name == "peername":
            return self.peer
        if name == "sockname":
            return ("127.0.0.1", 8000)
        return default

    def write(self, data: bytes | bytearray | memoryview) -> None:
        if not self.head:
            self.head = bytes(data[:16])
        self.written += len(data)

    def is_closing(self) -> bool:
        return self.closing

    def close(self) -> None:
        self.closing = True

    def pause_reading(self) -> None:
        pass

    def resume_reading(self) -> None:
        pass

    def set_protocol(self, protocol: asyncio.BaseProtocol) -> None:
        self.protocol = protocol

    def get_protocol(self) -> asyncio.BaseProtocol:
        assert self.protocol is not None
        return self.protocol


class Connection:
    """One kept-alive connection: a protocol instance over a :class:`Transport`."""

    def __init__(self, protocol_class: type[Any], config: Any, server_state: Any, k: int):
        self.transport = Transport(("127.0.0.1", 40000 + k))
        self.protocol = protocol_class(config, server_state, {}, asyncio.get_running_loop())
        self.transport.set_protocol(self.protocol)
        self.protocol.connection_made(self.transport)
        self.waiter: asyncio.Future[None] | None = None
        complete = self.protocol.on_response_complete

        def on_response_complete() -> None:
            complete()
            if self.waiter is not None:
                self.waiter.set_result(None)

        self.protocol.on_response_complete = on_response_complete

    async def request(self, raw: bytes) -> None:
        self.waiter = asyncio.get_running_loop().create_future()
        self.transport.head = b""
        self.protocol.data_received(raw)
        await self.waiter
        if not self.transport.head.startswith(b"HTTP/1.1 200"):
            raise RuntimeError(f"answer {self.transport.head!r}")

    def close(self) -> None:
        self.protocol.connection_lost(None)


def request_bytes(sid: str, token: str, body: bytes) -> bytes:
    """The request as wrk writes it (``wrk.format``: Host, the headers, Content-Length)."""
    return (
        f"POST /sessions/{sid}/events HTTP/1.1\r\nHost: 127.0.0.1:8000\r\n"
        f"Authorization: Bearer {token}\r\nContent-Type: application/json\r\n"
        f"Content-Length: {len(body)}\r\n\r\n"
    ).encode() + body


class Stack:
    """An app under a protocol class, with its connections (made afresh for each run)."""

    def __init__(self, app: Any, protocol_class: type[Any], requests: list[bytes]):
        from uvicorn.config import Config
        from uvicorn.server import ServerState

        self.app = app
        self.protocol_class = protocol_class
        self.config = Config(app, log_config=None, proxy_headers=False, lifespan="off")
        self.config.load()
        self.state = ServerState()
        self.state.default_headers = [(b"date", b"Thu, 04 Dec 2026 12:00:00 GMT")]
        self.state.default_headers += self.config.encoded_headers
        self.requests = requests

    async def run(self, n: int, access_log: bool = True) -> float:
        """Thread CPU microseconds per request for ``n`` requests."""
        conns = [
            Connection(self.protocol_class, self.config, self.state, k) for k in range(CONNECTIONS)
        ]
        for c in conns:
            c.protocol.access_log = c.protocol.access_log and access_log
        reqs = self.requests
        t0 = time.thread_time()
        for i in range(n):
            await conns[i % CONNECTIONS].request(reqs[i % len(reqs)])
        spent = time.thread_time() - t0
        for c in conns:
            c.close()
        return spent / n * 1e6


async def connection_cost(protocol_class: type[Any], config: Any, n: int) -> float:
    """Thread CPU microseconds for one connection made and lost (no request)."""
    from uvicorn.server import ServerState

    state = ServerState()
    loop = asyncio.get_running_loop()
    t0 = time.thread_time()
    for k in range(n):
        p = protocol_class(config, state, {}, loop)
        t = Transport(("127.0.0.2", 30000 + k % 20000))
        t.set_protocol(p)
        p.connection_made(t)
        p.connection_lost(None)
    return (time.thread_time() - t0) / n * 1e6


def walk_bodies(n: int) -> list[bytes]:
    """The bodies of ``bench_service.py --only rest``: a random walk's events, one a body."""
    import numpy as np

    from app.domain.grid import ACTIONS, GridDomain
    from app.domain.maps import DEFAULT_MAP

    grid = GridDomain.from_file(DEFAULT_MAP)
    s, out = grid.start, []
    for a in np.random.default_rng(1).integers(0, 4, n).tolist():
        out.append(json.dumps({"state": list(grid.cell(s)), "action": ACTIONS[a]},
                              separators=(",", ":")).encode())  # fmt: skip
        s = int(grid.next_state[s, a])
    return out


def without(app: Any, names: set[str]) -> Any:
    """The app's middleware stack without the user middleware classes named ``names``."""
    saved = app.user_middleware
    app.user_middleware = [m for m in saved if m.cls.__name__ not in names]
    try:
        return app.build_middleware_stack()
    finally:
        app.user_middleware = saved


def patch(owner: Any, name: str, value: Any) -> Undo:
    """``owner.name = value`` until the returned function puts back what was there (for an
    instance, nothing of its own: its class's attribute again)."""
    had = name in vars(owner)
    old = vars(owner).get(name)
    setattr(owner, name, value)

    def undo() -> None:
        if had:
            setattr(owner, name, old)
        else:
            delattr(owner, name)

    return undo


async def measure(args: argparse.Namespace) -> dict[str, Any]:
    from starlette.requests import Request
    from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol

    from app.cli.serve import uvicorn_options
    from app.service import ops
    from app.service.config import Settings
    from app.service.main import create_app
    from app.service.routes import sessions as routes
    from app.service.schemas import SessionCreate
    from benchmarks.baseline_app import create_baseline

    bodies = walk_bodies(1000)
    out: dict[str, list[float]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        settings = Settings(data_dir=Path(tmp) / "a", viewer_enabled=False)
        guarded = uvicorn_options(settings, "warning")["http"]
        app = create_app(settings)
        ids_settings = Settings(data_dir=Path(tmp) / "b", viewer_enabled=False, log_format="json")
        ids_app = create_app(ids_settings)
        async with app.router.lifespan_context(app), ids_app.router.lifespan_context(ids_app):
            stacks: dict[str, Stack] = {}
            made_sessions: dict[str, list[tuple[str, str]]] = {}
            for name, a in (("service", app), ("ids", ids_app)):
                a.middleware_stack = a.build_middleware_stack()
                state = a.state.service
                domain = state.catalog.get("default")
                reqs = []
                for _ in range(SESSIONS):
                    session, _ = await ops.open_session(state, domain, SessionCreate())
                    reqs.append((session.id, session.token))
                requests = [request_bytes(*reqs[i % SESSIONS], b) for i, b in
                            enumerate(bodies)]  # fmt: skip
                made_sessions[name] = reqs
                stacks[name] = Stack(a, guarded, requests)
            service = stacks["service"]
            plain = Stack(app, HttpToolsProtocol, service.requests)
            answer = await probe_answer(service)
            bare = Stack(create_baseline(len(answer)), guarded, service.requests)
            state = app.state.service
            grid = state.catalog.get("default").domain

            # ---- the toggles: each returns the function that undoes it ----
            full_stack = app.middleware_stack
            user = {m.cls.__name__ for m in app.user_middleware}

            def stack_off(names: set[str]) -> Callable[[], Undo]:
                alt = without(app, names)

                def on() -> Undo:
                    app.middleware_stack = alt
                    return lambda: setattr(app, "middleware_stack", full_stack)

                return on

            from app.service.wire import events as wire_events

            moves = {b: wire_events.read_move(grid, b) for b in bodies}
            a_session = state.registry.get(made_sessions["service"][0][0])
            made = a_session.advisor.observe(*(moves[bodies[0]] or (0, 0, 0))[:3])
            made_json = ops.decision_json(made, grid)

            async def fixed_observe(session: Any, *move: Any) -> Any:
                return made

            async def no_token(conn: Any, session_id: str, st: Any = None) -> Any:
                st = st or routes.service_of(conn)
                session = await st.sessions.get(session_id)
                st.sessions.touch(session)
                return session

            async def stored_answer(st: Any, session: Any, raw: Any, binary: bool = False) -> Any:
                return answer

            route = next(r for r in app.router.routes if getattr(r, "path", "") == EVENTS)

            async def no_handler(scope: Any, receive: Any, send: Any) -> None:
                request = Request(scope, receive, send)
                response = await routes.post_events(request, scope["path_params"]["session_id"])
                await response(scope, receive, send)

            toggles: dict[str, Callable[[], Undo]] = {
                "route handler (what the route does around the endpoint function)": lambda: patch(
                    route, "app", no_handler
                ),
                "body and websocket checks": stack_off(user & {"BodyLimit", "NoWebSocketRoute"}),
                "metrics (requests)": stack_off(user & {"MetricsMiddleware"}),
                "metrics (decisions)": lambda: patch(ops, "_count", lambda *a: None),
                "token check": lambda: patch(routes, "session_for", no_token),
                "reading the event": lambda: patch(ops, "read_move", lambda g, raw: moves[raw]),
                "the decision": lambda: patch(state.sessions, "observe_one", fixed_observe),
                "answer building": lambda: patch(ops, "decision_json", lambda d, g, *_: made_json),
                "route work (all of the above the endpoint does)": lambda: patch(
                    ops, "answer_events", stored_answer
                ),
            }
            access = logging.getLogger("uvicorn.access")
            n = args.requests
            # every session past its first steps (rings and the replay ring full, as in a
            # benchmark of minutes), then every variant once
            for s in (service, stacks["ids"]):
                await s.run(SESSIONS * args.age)
            for s in (service, plain, bare, stacks["ids"]):
                await s.run(n)
            for make in toggles.values():
                undo = make()
                await service.run(n)
                undo()
            gc.collect()
            gc.freeze()
            for r in range(args.rounds):
                whole: list[float] = []

                async def pair(
                    name: str, run: Any, make: Any = None, sign: float = 1.0, usual: bool = True
                ) -> None:
                    base = await service.run(n)
                    undo = make() if make is not None else None
                    try:
                        other = await run()
                    finally:
                        if undo is not None:
                            undo()
                    if usual:  # the whole service as the benchmarks run it
                        whole.append(base)  # noqa: B023  # this round's list
                    out.setdefault(name, []).append(sign * (base - other))

                await pair("guard", lambda: plain.run(n))
                for name, make in toggles.items():
                    await pair(name, lambda: service.run(n), make)
                await pair("request ids (JSON logs only)", lambda: stacks["ids"].run(n), None, -1)
                await pair("access log call, --log-level warning", lambda: service.run(n, False))
                access.setLevel(logging.INFO)
                try:
                    await pair("access log, --log-level info (serve's default)",
                               lambda: service.run(n, False), usual=False)  # fmt: skip
                finally:
                    access.setLevel(logging.WARNING)
                out.setdefault("whole service", []).append(statistics.median(whole))
                out.setdefault("bare FastAPI", []).append(await bare.run(n))
                print(f"round {r + 1}/{args.rounds}", file=sys.stderr, flush=True)
            gc.unfreeze()
            for _ in range(3):
                for name, cls in (("guarded", guarded), ("plain", HttpToolsProtocol)):
                    cost = await connection_cost(cls, service.config, 20000)
                    out.setdefault(f"connection, {name}", []).append(cost)
    return {k: statistics.median(v) for k, v in out.items()} | {"runs": out}


async def probe_answer(stack: Stack) -> bytes:
    """The service's answer to one request (its size sets the bare endpoint's)."""
    from app.service.routes import sessions as routes

    got: list[bytes] = []
    real = routes.ops.answer_events

    async def keep(*a: Any, **k: Any) -> bytes:
        text: bytes = await real(*a, **k)
        got.append(text)
        return text

    routes.ops.answer_events = keep
    try:
        await stack.run(1)
    finally:
        routes.ops.answer_events = real
    return got[0]


def report(res: dict[str, Any], args: argparse.Namespace) -> str:
    parts = [k for k in res if k not in ("runs", "whole service", "bare FastAPI")
             and not k.startswith("connection")]  # fmt: skip
    lines = [
        f"| part of a one-event request | us of CPU a request (median of {args.rounds} "
        "paired rounds) |",
        "|---|---|",
    ]
    for k in parts:
        lines.append(f"| {k} | {res[k]:.1f} |")
    lines += [
        f"| **whole service** | **{res['whole service']:.1f}** |",
        f"| bare FastAPI endpoint, same protocol | {res['bare FastAPI']:.1f} |",
        f"| ratio bare / service | {res['bare FastAPI'] / res['whole service']:.2f} |",
        "",
        f"A connection made and lost: {res['connection, guarded']:.1f} us guarded, "
        f"{res['connection, plain']:.1f} us plain (per connection; wrk keeps its 32 open).",
    ]
    return "\n".join(lines)


def main() -> None:
    sys.path.insert(0, str(HERE))  # this tree's benchmarks (--root's app goes before it)
    from benchmarks._report import arguments, machine

    ap = arguments(__doc__)
    ap.add_argument("--rounds", type=int, default=11)
    ap.add_argument("--requests", type=int, default=2000, help="requests per run")
    ap.add_argument("--age", type=int, default=600, help="events per session before the runs")
    ap.add_argument("--root", type=Path, default=HERE, help="source tree of the service")
    args = ap.parse_args()
    sys.path.insert(0, str(args.root.resolve()))
    try:
        import uvloop

        runner: Any = uvloop.run
    except ImportError:  # pragma: no cover - uvicorn[standard] brings it
        runner = asyncio.run
    logging.getLogger("uvicorn.access").setLevel(logging.WARNING)
    logging.getLogger("uvicorn.access").addHandler(logging.NullHandler())
    res = runner(measure(args))
    print(f"root {args.root}; {machine()}")
    print(report(res, args))
    print(json.dumps(res["runs"]), file=sys.stderr)


if __name__ == "__main__":
    main()
