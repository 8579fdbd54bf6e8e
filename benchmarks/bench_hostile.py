"""Hostile and careless clients against the real service, measured (docs/RELIABILITY.md).

Each section starts ``python -m app serve`` from a source tree (``--root``: this one by default,
or an older checkout to measure "before") on a free loopback port, makes one bounded load, and
prints markdown rows ``| measurement | value unit |`` (``benchmarks/compare_trees.py`` reads
them). Loads run in processes of their own, so the process that measures latencies waits for
nothing but the service.

    python benchmarks/bench_hostile.py                      # every section, this tree
    python benchmarks/bench_hostile.py --only reads batches  # some sections
    python benchmarks/bench_hostile.py --root /tmp/before --only reads batches attacks memory
    python benchmarks/bench_hostile.py --only combined --write docs/RELIABILITY.md

Sections: ``reads`` (``/health`` latency while two clients read a 400 x 400 prior, and while
clients read ``/overview?limit=1000``, and ``/domains`` with a map of 1,447 goals present),
``batches`` (one client's single-event latency while another session streams 5,000-event
batches), ``attacks`` (a 48 MB header, a 64 KiB one, 300 slow sockets), ``hogs`` (one client
opening as many slow sockets as the service takes connections, while another asks
``/health``), ``throughput`` (wrk: ``/health`` and one-event requests), ``memory`` (150
goal_aware sessions at window 10,000; the service and a domain at the goals x cells cap),
``combined`` (90 s of warm-up, then 60 s: 200 explorers at 10 events a second each, 5
ingesting writers, a watched viewer, two readers of the largest prior, a 500 x 500 domain's,
the largest map the service takes), ``redis_pause`` (the combined load with the live sessions
in a Redis of its own, ``redis-server`` on a free port, stopped with SIGSTOP for 10 s in the
middle: the explorers send each event with its step and send it again after a refusal; what
was acknowledged against what Redis holds at the end, how every refusal was answered, and
how soon latency is back), ``loop`` (the event loop's lag, from a probe task inside
the service that sleeps 10 ms over and over, and ``/health``'s slowest answer, during each
costly request on a 500 x 500 domain of 8 destinations: its PUT, same-map PUTs, the first
goal_aware and guide sessions, an ingestion, a PUT over live sessions, its delete).
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import httpx
import numpy as np
from websockets.sync.client import connect

from benchmarks._load import (
    EVENTS_LUA,
    ROOT,
    Server,
    _start,
    free_port,
    run_wrk,
    write_sessions,
)
from benchmarks._report import arguments, command_line, machine, write_section

ADMIN = {"X-API-Key": "bench"}
MiB = 1024 * 1024
Rows = list[tuple[str, float, str]]


# ---- the service ---------------------------------------------------------------------------------
@contextmanager
def service(root: Path, workdir: Path, viewer: bool = False, **env: str) -> Iterator[Server]:
    """``python -m app serve`` from ``root``, one client measuring: quotas as the service's."""
    port = free_port()
    cmd = [sys.executable, "-m", "app", "serve", "--port", str(port), "--data-dir",
           str(workdir / f"data-{port}"), "--log-level", "warning"]  # fmt: skip
    settings = {
        "ADVISOR_ADMIN_KEY": "bench", "ADVISOR_BOOTSTRAP_PER_GOAL": "2",
        "ADVISOR_CLIENT_MAX_SESSIONS": "20000", "ADVISOR_CLIENT_MAX_SESSION_MEMORY": str(1 << 30),
        "ADVISOR_OVERVIEW_SECONDS": "0",  # every overview built: the worst case
    }  # fmt: skip
    if viewer:
        settings["ADVISOR_VIEWER_PORT"] = str(free_port())
    else:
        cmd.append("--no-viewer")
    server = _start(
        cmd, root, os.environ | settings | env, workdir / f"advisor-{port}.log", "/health"
    )
    try:
        yield server
    finally:
        server.stop()


def percentiles(values: list[float]) -> tuple[float, float, float]:
    """(p50, p99, max) of ``values`` (milliseconds)."""
    arr = np.asarray(values)
    return float(np.percentile(arr, 50)), float(np.percentile(arr, 99)), float(arr.max())


def poll_latency(url: str, seconds: float, every: float = 0.02) -> list[float]:
    """``GET url`` every ``every`` seconds for ``seconds``: each answer's time (ms)."""
    out = []
    with httpx.Client(timeout=60) as http:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            t = time.perf_counter()
            r = http.get(url)
            out.append(1000 * (time.perf_counter() - t))
            assert r.status_code == 200, r.text
            time.sleep(every)
    return out


def reader(
    url: str, headers: dict[str, str], seconds: float, counts: Any, errors: Any = None
) -> None:
    """A process reading ``url`` over and over (bytes, never parsed) for ``seconds``; an answer
    other than 200, or a failed request, counts in ``errors``."""
    with httpx.Client(timeout=120, headers=headers) as http:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            try:
                ok = http.get(url).status_code == 200
            except httpx.HTTPError:
                ok = False
            if ok:
                counts.value += 1
            elif errors is not None:
                errors.value += 1


@contextmanager
def processes(target: Callable[..., None], args: list[tuple[Any, ...]]) -> Iterator[None]:
    procs = [mp.Process(target=target, args=a, daemon=True) for a in args]
    for p in procs:
        p.start()
    try:
        yield
    finally:
        for p in procs:
            p.join(timeout=300)
            if p.is_alive():
                p.terminate()


def open_map(rows: int, cols: int) -> list[str]:
    """An open rows x cols floor, walled round, start and one goal in opposite corners."""
    inner = ["#" + "." * (cols - 2) + "#" for _ in range(rows - 2)]
    inner[0] = "#S" + inner[0][2:]
    inner[-1] = inner[-1][:-2] + "G#"
    return ["#" * cols, *inner, "#" * cols]


# ---- reads ---------------------------------------------------------------------------------------
def bench_reads(root: Path, workdir: Path, seconds: float) -> Rows:
    rows: Rows = []
    with service(root, workdir) as srv, httpx.Client(base_url=srv.url, timeout=120) as http:
        r = http.put("/domains/big", json={"map": open_map(400, 400)}, headers=ADMIN)
        assert r.status_code in (200, 201), r.text
        t = time.perf_counter()
        size = len(http.get("/domains/big/prior").content)
        rows.append(("first read of a 400 x 400 prior", 1000 * (time.perf_counter() - t), "ms"))
        rows.append(("its size", size / 1e6, "MB"))
        baseline = percentiles(poll_latency(srv.url + "/health", 3))
        rows.append(("/health p99, idle", baseline[1], "ms"))
        count = mp.Value("i", 0)
        prior: list[tuple[Any, ...]] = [
            (srv.url + "/domains/big/prior", {}, seconds, count) for _ in range(2)
        ]
        with processes(reader, prior):
            time.sleep(1)
            lat = percentiles(poll_latency(srv.url + "/health", seconds - 2))
        rows += [("/health p50, two clients reading the prior", lat[0], "ms"),
                 ("/health p99, two clients reading the prior", lat[1], "ms"),
                 ("/health max, two clients reading the prior", lat[2], "ms"),
                 ("prior reads answered meanwhile", count.value, "reads")]  # fmt: skip
        # 1,000 sessions with 100 moves each, read whole by an operator
        events = json.dumps([{"state": [398, 1 + i % 2], "action": "E" if i % 2 == 0 else "W"}
                             for i in range(100)])  # fmt: skip
        for _ in range(1000):
            c = http.post("/domains/big/sessions", json={"start": [398, 1]}).json()
            http.post(f"/sessions/{c['session_id']}/events", content=events,
                      headers={"Authorization": f"Bearer {c['token']}"})  # fmt: skip
        t = time.perf_counter()
        http.get("/overview", params={"limit": 1000}, headers=ADMIN)
        rows.append(
            ("GET /overview?limit=1000 (1,000 sessions)", 1000 * (time.perf_counter() - t), "ms")
        )
        count = mp.Value("i", 0)
        view = [(srv.url + "/overview?limit=1000", ADMIN, seconds, count) for _ in range(2)]
        with processes(reader, view):
            time.sleep(1)
            lat = percentiles(poll_latency(srv.url + "/health", seconds - 2))
        rows.append(("/health p99, two clients reading /overview?limit=1000", lat[1], "ms"))
        # GET /domains lists every goal: a map of 249,999 goals is refused now (goals x cells
        # over ADVISOR_MAX_GOAL_CELLS); the most goals a map may have, 1,447, in a corridor
        goals = ["G" * 500 for _ in range(500)]
        goals[0] = "S" + goals[0][1:]
        r = http.put("/domains/goals", json={"map": goals}, headers=ADMIN)
        rows.append(("PUT of a map of 249,999 goals: status", r.status_code, ""))
        corridor = ["#" * 1451, "#S" + "G" * 1447 + ".#", "#" * 1451]
        r = http.put("/domains/goals", json={"map": corridor}, headers=ADMIN)
        assert r.status_code in (200, 201), r.text
        t = time.perf_counter()
        http.get("/domains")
        rows.append(
            ("GET /domains, a 1,447-goal map present", 1000 * (time.perf_counter() - t), "ms")
        )
        count = mp.Value("i", 0)
        listing: list[tuple[Any, ...]] = [
            (srv.url + "/domains", {}, seconds, count) for _ in range(2)
        ]
        with processes(reader, listing):
            time.sleep(1)
            lat = percentiles(poll_latency(srv.url + "/health", seconds - 2))
        rows.append(("/health p99, two clients reading /domains", lat[1], "ms"))
    return rows


# ---- batches -------------------------------------------------------------------------------------
def streamer(ws_url: str, token: str, start: list[int], seconds: float, count: Any) -> None:
    """A process streaming 5,000-event batches back to back on one session (binary answers)."""
    walk = [{"state": start, "action": "E"}, {"state": [start[0], start[1] + 1], "action": "W"}]
    frame = json.dumps(walk * 2500)
    with connect(f"{ws_url}?format=binary", additional_headers={"Authorization": f"Bearer {token}"},
                 max_size=None) as ws:  # fmt: skip
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            ws.send(frame)
            ws.recv()
            count.value += 1


def single_events(srv: Server, seconds: float) -> list[float]:
    """One event at a time on a paper session's websocket: each round trip (ms)."""
    c = httpx.post(srv.url + "/domains/default/sessions", json={}).json()
    url = srv.ws_url + f"/sessions/{c['session_id']}/stream"
    out = []
    with connect(url, additional_headers={"Authorization": f"Bearer {c['token']}"}) as ws:
        deadline = time.monotonic() + seconds
        i = 0
        while time.monotonic() < deadline:
            e = {"state": [28, i % 2], "action": "E" if i % 2 == 0 else "W"}
            t = time.perf_counter()
            ws.send(json.dumps(e))
            ws.recv()
            out.append(1000 * (time.perf_counter() - t))
            i += 1
            time.sleep(0.01)
    return out


def bench_batches(root: Path, workdir: Path, seconds: float) -> Rows:
    rows: Rows = []
    with service(root, workdir) as srv:
        idle = percentiles(single_events(srv, 3))
        rows.append(("single-event p99, alone", idle[1], "ms"))
        for strategy, body in [("goal_aware", {"strategy": "goal_aware", "params": {"beta": 0.5}}),
                               ("mistake", {"strategy": "mistake"})]:  # fmt: skip
            c = httpx.post(srv.url + "/domains/default/sessions", json=body).json()
            url = srv.ws_url + f"/sessions/{c['session_id']}/stream"
            count = mp.Value("i", 0)
            args = [(url, c["token"], c["decision"]["state"], seconds, count)]
            with processes(streamer, args):
                time.sleep(1)
                lat = percentiles(single_events(srv, seconds - 2))
            rows += [(f"single-event p50, a {strategy} session streaming 5,000-event batches",
                      lat[0], "ms"),
                     (f"single-event p99, a {strategy} session streaming 5,000-event batches",
                      lat[1], "ms"),
                     (f"{strategy} batches answered", count.value, "batches")]  # fmt: skip
    return rows


# ---- attacks -------------------------------------------------------------------------------------
def bench_attacks(root: Path, workdir: Path, seconds: float) -> Rows:
    rows: Rows = []
    with service(root, workdir) as srv:
        # a 48 MB header, while another client asks /health
        sock = socket.create_connection(("127.0.0.1", srv.port))
        waits: list[float] = []
        other = threading.Thread(target=lambda: waits.extend(poll_latency(srv.url + "/health", 8)))
        t = time.perf_counter()
        other.start()
        sent = 0
        try:
            sock.sendall(b"GET /health HTTP/1.1\r\nHost: x\r\nX-Big: ")
            while sent < 48 * MiB:
                sock.sendall(b"a" * 65536)
                sent += 65536
            sock.sendall(b"\r\n\r\n")
        except OSError:
            pass
        sock.settimeout(60)
        try:
            status = sock.recv(64).split(b" ")[1].decode()
        except (OSError, IndexError):
            status = "closed"
        answered = time.perf_counter() - t
        sock.close()
        other.join()
        rows += [
            (f"48 MB header: answered {status} after", answered, "s"),
            ("48 MB header: bytes the server took before answering", sent / MiB, "MiB"),
            ("48 MB header: another client's /health max meanwhile", max(waits), "ms"),
        ]
        sock = socket.create_connection(("127.0.0.1", srv.port))
        sock.sendall(b"GET /health HTTP/1.1\r\nHost: x\r\nX-Pad: " + b"a" * 65536 + b"\r\n\r\n")
        sock.settimeout(30)
        rows.append(("64 KiB header: status", float(sock.recv(64).split(b" ")[1]), ""))
        sock.close()
        # 300 sockets trickling a header byte a second
        slow = [socket.create_connection(("127.0.0.1", srv.port)) for _ in range(300)]
        began = time.monotonic()
        for k in range(int(seconds)):
            for s in slow:
                with suppress(OSError):
                    s.send(b"GET /health HTTP/1.1\r\nX: "[k : k + 1] or b"a")
            time.sleep(1.0)
        open_now = 0
        for s in slow:
            s.setblocking(False)
            try:
                s.recv(1)  # an answer (408) or the end: the server let it go
            except BlockingIOError:
                open_now += 1  # nothing back, not closed: the server still holds it
            except OSError:
                pass
            s.close()
        rows.append((f"300 slow sockets: still open after {time.monotonic() - began:.0f} s",
                     open_now, "sockets"))  # fmt: skip
    return rows


# ---- one client taking every connection ----------------------------------------------------------
HOG_SOCKETS = 1000  # ADVISOR_MAX_CONNECTIONS' default: every place the service has


def bench_hogs(root: Path, workdir: Path, seconds: float) -> Rows:
    """One client (127.0.0.1) opens as many slow sockets as the service takes connections and
    trickles a header byte a second on each; another client (127.0.0.2) asks ``/health`` once
    a second meanwhile (``seconds`` under the 10 s header timeout)."""
    with service(root, workdir) as srv:
        hog = [socket.create_connection(("127.0.0.1", srv.port)) for _ in range(HOG_SOCKETS)]
        answers: list[int] = []
        transport = httpx.HTTPTransport(local_address="127.0.0.2")
        with httpx.Client(timeout=30, transport=transport) as other:
            for k in range(max(1, int(seconds))):
                for s in hog:
                    with suppress(OSError):
                        s.send(b"GET /health HTTP/1.1\r\nX: "[k : k + 1] or b"a")
                try:
                    answers.append(other.get(srv.url + "/health").status_code)
                except httpx.TransportError:
                    answers.append(0)  # reset before an answer
                time.sleep(1.0)
        refused = 0
        for s in hog:
            s.setblocking(False)
            try:
                refused += bool(s.recv(1))  # answered (429 or 503) before its headers were in
            except BlockingIOError:
                pass  # still held
            except OSError:
                refused += 1
            s.close()
    return [
        (f"one client's {HOG_SOCKETS} slow sockets: another client's /health answered 200",
         100 * answers.count(200) / len(answers), "%"),
        (f"one client's {HOG_SOCKETS} slow sockets: refused at once", refused, "sockets"),
    ]  # fmt: skip


# ---- throughput ----------------------------------------------------------------------------------
def bench_throughput(root: Path, workdir: Path, seconds: float) -> Rows:
    rows: Rows = []
    with service(root, workdir) as srv:
        health = run_wrk(srv.url + "/health", "", [], seconds, 32, workdir)
        rows.append(("GET /health, wrk 32 connections", health.rate, "req/s"))
        made = []
        for _ in range(64):
            c = httpx.post(srv.url + "/domains/default/sessions", json={}).json()
            made.append((c["session_id"], c["token"]))
        sessions = write_sessions(made, workdir / "sessions.txt")
        bodies = workdir / "bodies.txt"
        # events from [28, 0] east: every session goes back and forth along the bottom row
        lines = [json.dumps({"state": [28, c], "action": a}) for c, a in ((0, "E"), (1, "W"))]
        bodies.write_text("\n".join(lines) + "\n")
        events = run_wrk(srv.url, EVENTS_LUA, [str(sessions), str(bodies), "0"], seconds, 32,
                         workdir)  # fmt: skip
        rows.append(("POST one event, wrk 32 connections", events.rate, "req/s"))
    return rows


# ---- memory --------------------------------------------------------------------------------------
def bench_memory(root: Path, workdir: Path, seconds: float) -> Rows:
    with service(root, workdir) as srv, httpx.Client(base_url=srv.url, timeout=120) as http:
        # back and forth along the bottom corridor: valid moves, 10,000 of them
        walk = [{"state": [28, 0], "action": "E"}, {"state": [28, 1], "action": "W"}] * 5000
        frames = [json.dumps(walk[i : i + 5000]) for i in range(0, 10_000, 5000)]
        body = {"strategy": "goal_aware", "window": 10_000, "params": {"beta": 0.5}}

        def fill(c: dict[str, Any]) -> None:
            url = srv.ws_url + f"/sessions/{c['session_id']}/stream?format=binary"
            with connect(url, additional_headers={"Authorization": f"Bearer {c['token']}"},
                         max_size=None) as ws:  # fmt: skip
                for f in frames:
                    ws.send(f)
                    ws.recv()

        warm = http.post("/domains/default/sessions", json=body).json()
        fill(warm)
        before = srv.rss_bytes()
        made = [http.post("/domains/default/sessions", json=body).json() for _ in range(150)]
        created = srv.rss_bytes()
        for c in made:
            fill(c)
        after = srv.rss_bytes()
        rows = [("RSS of the service with the default domain, after those sessions ended", 0.0, "")]
        for c in [warm, *made]:
            http.delete(f"/sessions/{c['session_id']}", headers=ADMIN)
        rows[0] = (rows[0][0], srv.rss_bytes() / MiB, "MiB")
        # what one domain at the goals x cells cap costs (the per-goal tables of goal_aware and
        # guide, made by their first session): the most goals, and the largest map
        corridor = ["#" * 1451, "#S" + "G" * 1447 + ".#", "#" * 1451]
        wide = open_map(500, 500)
        wide[1] = "#S" + "G" * 7 + wide[1][9:]  # 8 goals x 250,000 cells
        for name, rows_of in (("1,447 goals x 1,449 cells", corridor),
                              ("8 goals x 250,000 cells", wide)):  # fmt: skip
            start = srv.rss_bytes()
            r = http.put("/domains/cap", json={"map": rows_of}, headers=ADMIN)
            assert r.status_code in (200, 201), r.text
            for strategy in ("goal_aware", "guide"):
                c = http.post("/domains/cap/sessions", json={"strategy": strategy})
                assert c.status_code == 201, c.text
            rows.append((f"RSS of a domain of {name} with its per-goal tables",
                         (srv.rss_bytes() - start) / MiB, "MiB"))  # fmt: skip
            assert http.delete("/domains/cap", headers=ADMIN).status_code == 204
    label = "RSS of 150 goal_aware sessions, window 10,000"
    return [
        (f"{label}, just created", (created - before) / MiB, "MiB"),
        (f"{label}, windows full", (after - before) / MiB, "MiB"),
        *rows,
    ]


# ---- loop lag ------------------------------------------------------------------------------------
#: Run as ``python -c PROBED serve ...`` from a source tree: the service as ``python -m app serve``
#: runs it, with a task on its event loop that sleeps 10 ms over and over and writes, for each
#: wake, when it woke (``time.monotonic()``, the same clock in every process) and how late
#: (ms) to the file ``BENCH_LOOP_LAG`` names. Nothing of the service is changed, so an older
#: tree (``--root``) is measured the same way.
PROBED = """
import asyncio, os, sys, time
import uvicorn

_serve = uvicorn.Server.serve


async def _probe(path):
    with open(path, "a", buffering=1) as out:
        while True:
            t = time.monotonic()
            await asyncio.sleep(0.01)
            now = time.monotonic()
            out.write(f"{now:.6f} {1000 * (now - t - 0.01):.3f}\\n")


async def _probed(self, *args, **kwargs):
    task = asyncio.get_running_loop().create_task(_probe(os.environ["BENCH_LOOP_LAG"]))
    try:
        await _serve(self, *args, **kwargs)
    finally:
        task.cancel()


uvicorn.Server.serve = _probed
from app.cli import main

sys.argv = ["app", *sys.argv[1:]]
main()
"""


@contextmanager
def probed_service(root: Path, workdir: Path, lags: Path) -> Iterator[Server]:
    """:func:`service` with the loop-lag probe (:data:`PROBED`) writing to ``lags``."""
    port = free_port()
    cmd = [sys.executable, "-c", PROBED, "serve", "--port", str(port), "--data-dir",
           str(workdir / f"data-{port}"), "--log-level", "warning", "--no-viewer"]  # fmt: skip
    settings = {"ADVISOR_ADMIN_KEY": "bench", "ADVISOR_BOOTSTRAP_PER_GOAL": "2",
                "BENCH_LOOP_LAG": str(lags)}  # fmt: skip
    server = _start(cmd, root, os.environ | settings, workdir / f"advisor-{port}.log", "/health")
    try:
        yield server
    finally:
        server.stop()


def worst_lag(lags: Path, began: float, ended: float) -> float:
    """The latest the probe woke (ms) between ``began`` and shortly after ``ended``
    (``time.monotonic()``): a wake after ``ended`` that was late was held by the request."""
    worst = 0.0
    for line in lags.read_text().splitlines():
        at, late = (float(v) for v in line.split())
        if began <= at <= ended + 0.2 + late / 1000:
            worst = max(worst, late)
    return worst


def wide_map() -> list[str]:
    """A 500 x 500 floor with 8 destinations (8 goals x 250,000 cells: near the goals x cells
    cap, ADVISOR_MAX_GOAL_CELLS)."""
    rows = open_map(500, 500)
    rows[1] = "#S" + "G" * 7 + rows[1][9:]
    return rows


Call = Callable[[], httpx.Response]


def loop_phases(admin: httpx.Client, anyone: httpx.Client, name: str) -> list[tuple[str, Call]]:
    """The requests :func:`bench_loop` measures, in order, on domain ``name`` (each answered
    2xx): none (the probe's own lateness), an admin's PUT of a new domain, same-map PUTs, the
    first sessions that need the goal priors and the guide map (no credential), an
    ingestion, a same-map PUT with them live, another map over them, the domain's delete."""
    rows_of = wide_map()
    other = [*rows_of[:-2], rows_of[-2][:-3] + "#G#", rows_of[-1]]  # a wall added
    # a step from the start along the top row, ended at the first destination, 100 times
    ingest = {"trajectories": [{"steps": [{"state": [1, 1], "action": "E"}], "goal": [1, 2]}
                               for _ in range(100)]}  # fmt: skip
    url = f"/domains/{name}"
    return [
        ("no request (1 s)", lambda: (time.sleep(1), anyone.get("/health"))[1]),
        ("PUT of a new 500 x 500 domain (8 destinations)",
         lambda: admin.put(url, json={"map": rows_of})),
        ("same-map PUT, alpha0 changed",
         lambda: admin.put(url, json={"map": rows_of, "alpha0": 2.0})),
        ("same-map PUT, resolution changed",
         lambda: admin.put(url, json={"map": rows_of, "alpha0": 2.0, "resolution": 0.5})),
        ("first goal_aware session, no credential",
         lambda: anyone.post(f"{url}/sessions", json={"strategy": "goal_aware"})),
        ("first guide session, no credential",
         lambda: anyone.post(f"{url}/sessions", json={"strategy": "guide"})),
        ("100 trajectories ingested (prior and goal priors rebuilt)",
         lambda: admin.post(f"{url}/trajectories", json=ingest)),
        ("same-map PUT with live goal_aware and guide sessions",
         lambda: admin.put(url, json={"map": rows_of, "alpha0": 1.5})),
        ("PUT of another map over those sessions", lambda: admin.put(url, json={"map": other})),
        ("DELETE of the domain", lambda: admin.delete(url)),
    ]  # fmt: skip


def bench_loop(root: Path, workdir: Path, seconds: float) -> Rows:
    """The event loop's lag (a task sleeping 10 ms, how late it woke) during each request of
    :func:`loop_phases` on a 500 x 500 domain of 8 destinations, and ``/health``'s slowest
    answer meanwhile (asked every 20 ms by a thread); each the worst of ``REPEATS`` domains."""
    lags = workdir / "loop-lag.txt"
    worst: dict[str, list[float]] = {}
    health: dict[str, list[float]] = {}
    took: dict[str, list[float]] = {}
    grew: dict[str, list[float]] = {}
    with (
        probed_service(root, workdir, lags) as srv,
        httpx.Client(base_url=srv.url, timeout=300, headers=ADMIN) as admin,
        httpx.Client(base_url=srv.url, timeout=300) as anyone,  # no credential
    ):
        time.sleep(1)  # the probe's first wakes
        for k in range(REPEATS):
            for label, call in loop_phases(admin, anyone, f"wide{k}"):
                waits: list[float] = []
                stop = threading.Event()

                def poll(waits: list[float] = waits, stop: threading.Event = stop) -> None:
                    with httpx.Client(timeout=60) as h:
                        while not stop.is_set():
                            t = time.perf_counter()
                            h.get(srv.url + "/health")
                            waits.append(1000 * (time.perf_counter() - t))
                            time.sleep(0.02)

                poller = threading.Thread(target=poll)
                poller.start()
                rss = srv.rss_bytes()
                began = time.monotonic()
                r = call()
                ended = time.monotonic()
                grew.setdefault(label, []).append((srv.rss_bytes() - rss) / MiB)
                time.sleep(0.5)  # the probe's wakes after the answer, /health after it
                stop.set()
                poller.join()
                assert r.is_success, f"{label}: {r.status_code} {r.text[:300]}"
                worst.setdefault(label, []).append(worst_lag(lags, began, ended))
                health.setdefault(label, []).append(max(waits, default=0.0))
                took.setdefault(label, []).append(1000 * (ended - began))
    rows: Rows = []
    for label in worst:
        each = ", ".join(f"{v:.0f}" for v in worst[label])
        print(f"loop lag of each domain, {label}: {each} ms", file=sys.stderr)
        rows.append((f"loop lag max, {label}", max(worst[label]), "ms"))
        rows.append((f"/health max, {label}", max(health[label]), "ms"))
        rows.append((f"answered in (slowest), {label}", max(took[label]), "ms"))
        if label.startswith(("PUT of a new", "first")):  # where a domain's tables are made
            # the first domain's: later ones reuse what the ones before them freed
            rows.append((f"RSS growth (the first domain), {label}", grew[label][0], "MiB"))
    return rows


# ---- combined ------------------------------------------------------------------------------------
def explorers(ws_url: str, created: list[tuple[str, str, list[int]]], seconds: float,
              out: Any, errors: Any) -> None:  # fmt: skip
    """A process of explorers, each sending one event every 100 ms on its websocket; the
    round trips (ms) into ``out`` (a shared array, one slot per answer up to its size)."""
    import asyncio

    from websockets.asyncio.client import connect as aconnect

    async def one(sid: str, token: str, start: list[int]) -> None:
        url = f"{ws_url}/sessions/{sid}/stream"
        async with aconnect(url, additional_headers={"Authorization": f"Bearer {token}"}) as ws:
            deadline = time.monotonic() + seconds
            i = 0
            while time.monotonic() < deadline:
                e = {"state": [start[0], start[1] + i % 2], "action": "E" if i % 2 == 0 else "W"}
                t = time.perf_counter()
                await ws.send(json.dumps(e))
                answer = json.loads(await ws.recv())
                if "detail" in answer:
                    errors.value += 1
                with out.get_lock():
                    k = int(out[0])
                    if k + 1 < len(out):
                        out[k + 1] = 1000 * (time.perf_counter() - t)
                        out[0] = k + 1
                i += 1
                await asyncio.sleep(max(0.0, 0.1 - (time.perf_counter() - t)))

    async def counted(sid: str, token: str, start: list[int]) -> None:
        try:
            await one(sid, token, start)
        except Exception:  # a closed socket, a refused handshake: an error, not a crash
            errors.value += 1

    async def run() -> None:
        await asyncio.gather(*(counted(*c) for c in created))

    asyncio.run(run())


def writer(url: str, seconds: float, count: Any, errors: Any) -> None:
    """A process ingesting one expert trajectory per request, back to back."""
    steps = [{"state": [28, c], "action": "E"} for c in range(6)]
    body = {"trajectories": [{"steps": steps}]}
    with httpx.Client(base_url=url, timeout=60, headers=ADMIN) as http:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            try:
                ok = http.post("/domains/default/trajectories", json=body).status_code == 201
            except httpx.HTTPError:
                ok = False
            count.value += 1
            if not ok:
                errors.value += 1
            time.sleep(0.05)


def watcher(port: int, seconds: float, errors: Any) -> None:
    """A browser on the viewer, as viser's web client connects (reads all it is sent); the
    connection failing counts in ``errors``."""
    try:
        _watch(port, seconds)
    except Exception:
        errors.value += 1


def _watch(port: int, seconds: float) -> None:
    import msgspec
    import viser
    from viser import _messages
    from websockets.typing import Subprotocol

    protocol = Subprotocol(f"viser-v{viser.__version__}")
    with connect(f"ws://127.0.0.1:{port}", subprotocols=[protocol], max_size=None) as ws:
        camera = _messages.ViewerCameraMessage(
            wxyz=(1.0, 0.0, 0.0, 0.0), position=(0.0, 0.0, 10.0), fov=1.0, near=0.01, far=1e3,
            image_height=480, image_width=640, look_at=(0.0, 0.0, 0.0),
            up_direction=(0.0, 1.0, 0.0),
        )  # fmt: skip
        ws.send(msgspec.msgpack.encode(camera.as_serializable_dict()))
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            with suppress(TimeoutError):
                ws.recv(timeout=1)


def bench_combined(root: Path, workdir: Path, seconds: float) -> Rows:
    with (
        service(root, workdir, viewer=True) as srv,
        httpx.Client(base_url=srv.url, timeout=120) as http,
    ):
        # the largest prior the service holds: a map of ADVISOR_MAX_MAP_CELLS (250,000) cells
        r = http.put("/domains/big", json={"map": open_map(500, 500)}, headers=ADMIN)
        assert r.status_code in (200, 201), r.text
        viewer_port = http.get("/viewer").json()["port"]
        created = []
        for _ in range(200):
            c = http.post("/domains/default/sessions", json={}).json()
            created.append((c["session_id"], c["token"], [28, 0]))
        errors = mp.Value("i", 0)
        writes = mp.Value("i", 0)
        reads = mp.Value("i", 0)
        rtts = mp.Array("d", 200 * int(seconds) * 11)
        groups = [created[i::4] for i in range(4)]
        procs = [mp.Process(target=explorers, args=(srv.ws_url, g, seconds, rtts, errors))
                 for g in groups]  # fmt: skip
        procs += [mp.Process(target=writer, args=(srv.url, seconds, writes, errors))
                  for _ in range(5)]  # fmt: skip
        prior = srv.url + "/domains/big/prior"
        procs += [mp.Process(target=reader, args=(prior, {}, seconds, reads, errors))
                  for _ in range(2)]  # fmt: skip
        procs.append(mp.Process(target=watcher, args=(viewer_port, seconds, errors)))
        for p in procs:
            p.start()
        rss = []
        began = time.monotonic()
        while any(p.is_alive() for p in procs) and time.monotonic() - began < seconds + 120:
            rss.append((time.monotonic() - began, srv.rss_bytes() / MiB))
            time.sleep(5)
        for p in procs:
            p.join(timeout=60)
        crashed = sum(p.exitcode != 0 for p in procs)  # a load process that died: an error too
        health = http.get("/health").json()
        print("RSS (s, MiB):", ", ".join(f"{t:.0f}: {m:.0f}" for t, m in rss), file=sys.stderr)
    count = int(rtts[0])
    lat = percentiles(list(rtts[1 : count + 1]))
    warm = [m for t, m in rss if t >= WARM_UP]
    return [
        ("combined: events answered", count, "events"),
        (
            "combined: errors (error answers, failed requests, ingests, reads or connections, "
            "load processes that died)",
            errors.value + crashed,
            "",
        ),
        ("combined: trajectories ingested", writes.value, ""),
        ("combined: prior reads answered", reads.value, ""),
        ("combined: single-event p50", lat[0], "ms"),
        ("combined: single-event p99", lat[1], "ms"),
        ("combined: single-event max", lat[2], "ms"),
        (
            f"combined: RSS at {WARM_UP:.0f} s (after warm-up)",
            warm[0] if warm else float("nan"),
            "MiB",
        ),
        ("combined: RSS at the end", warm[-1] if warm else float("nan"), "MiB"),
        (
            f"combined: RSS growth over the last {seconds - WARM_UP:.0f} s",
            (warm[-1] - warm[0]) if warm else float("nan"),
            "MiB",
        ),
        ("combined: live sessions at the end", health["sessions"], ""),
    ]


# ---- Redis paused in the middle of the combined load ---------------------------------------------
#: seconds from the start of the load: measured from, Redis stopped at, and for how long
FAULT_FROM, FAULT_AT, FAULT_FOR = 20.0, 30.0, 10.0
#: after Redis returns, latency must be back under this (ms) within this many seconds
FAULT_P99, FAULT_BACK = 100.0, 5.0
#: what an answer of the fault run was: a decision, a 503, anything else
DECIDED, REFUSED, WRONG = 1.0, 2.0, 3.0


@contextmanager
def private_redis(workdir: Path) -> Iterator[tuple[str, subprocess.Popen[bytes]]]:
    """``redis-server`` of the benchmark's own on a free port, nothing kept on disk."""
    import redis

    server = shutil.which("redis-server")
    if server is None:
        raise SystemExit("redis-server is not installed (apt-get install redis-server)")
    port = free_port()
    home = workdir / f"redis-{port}"
    home.mkdir()
    with (home / "redis.log").open("ab") as log:
        proc = subprocess.Popen(
            [server, "--port", str(port), "--bind", "127.0.0.1", "--save", "", "--appendonly",
             "no", "--dir", str(home)], stdout=log, stderr=log,
        )  # fmt: skip
    try:
        client = redis.Redis(port=port, socket_timeout=1)
        for _ in range(300):
            with suppress(redis.exceptions.RedisError):
                if client.ping():
                    break
            time.sleep(0.02)
        yield f"redis://127.0.0.1:{port}/0", proc
    finally:
        proc.kill()
        proc.wait(30)


def stepped_explorers(ws_url: str, created: list[tuple[int, str, str]], seconds: float,
                      out: Any, acked: Any, errors: Any) -> None:  # fmt: skip
    """A process of explorers, each sending one event every 100 ms on its websocket with its
    step; a 503 frame: the same event at the next tick. Each answer into ``out`` (a shared
    array: a count, then (when sent, round trip in ms, DECIDED/REFUSED/WRONG) triplets); the
    last step each session had acknowledged into ``acked``."""
    import asyncio

    from websockets.asyncio.client import connect as aconnect

    async def one(k: int, sid: str, token: str) -> None:
        url = f"{ws_url}/sessions/{sid}/stream"
        async with aconnect(url, additional_headers={"Authorization": f"Bearer {token}"}) as ws:
            deadline = time.monotonic() + seconds
            step = 1
            while time.monotonic() < deadline:
                e = {"state": [28, (step - 1) % 2], "action": "E" if step % 2 else "W",
                     "step": step}  # fmt: skip
                t, sent = time.perf_counter(), time.monotonic()
                await ws.send(json.dumps(e))
                answer = json.loads(await ws.recv())
                rtt = 1000 * (time.perf_counter() - t)
                if answer.get("step") == step:
                    kind = DECIDED
                    acked[k] = step
                    step += 1
                elif answer.get("status") == 503 and "Redis" in answer.get("detail", ""):
                    kind = REFUSED
                else:
                    kind = WRONG
                    errors.value += 1
                with out.get_lock():
                    n = int(out[0])
                    if 3 * n + 3 < len(out):
                        out[3 * n + 1], out[3 * n + 2], out[3 * n + 3] = sent, rtt, kind
                        out[0] = n + 1
                await asyncio.sleep(max(0.0, 0.1 - (time.perf_counter() - t)))

    async def counted(k: int, sid: str, token: str) -> None:
        try:
            await one(k, sid, token)
        except Exception:  # a closed socket, a refused handshake: an error, not a crash
            errors.value += 1

    async def run() -> None:
        await asyncio.gather(*(counted(*c) for c in created))

    asyncio.run(run())


def steady_writer(url: str, seconds: float, acked: Any, refused: Any, errors: Any) -> None:
    """A process ingesting one expert trajectory per request; 503s counted apart."""
    steps = [{"state": [28, c], "action": "E"} for c in range(6)]
    body = {"trajectories": [{"steps": steps}]}
    with httpx.Client(base_url=url, timeout=60, headers=ADMIN) as http:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            try:
                status = http.post("/domains/default/trajectories", json=body).status_code
            except httpx.HTTPError:
                status = 0
            if status == 201:
                acked.value += 1
            elif status == 503:
                refused.value += 1
            else:
                errors.value += 1
            time.sleep(0.05)


def steady_reader(url: str, seconds: float, counts: Any, refused: Any, errors: Any) -> None:
    with httpx.Client(timeout=120) as http:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            try:
                status = http.get(url).status_code
            except httpx.HTTPError:
                status = 0
            if status == 200:
                counts.value += 1
            elif status == 503:
                refused.value += 1
                time.sleep(0.1)
            else:
                errors.value += 1


def bench_redis_pause(root: Path, workdir: Path, seconds: float) -> Rows:
    """The combined load (200 explorers at 10 events a second, 5 writers, two readers of the
    largest prior, a watched viewer) with the sessions in a Redis of its own, which is stopped
    (SIGSTOP) at ``FAULT_AT`` s for ``FAULT_FOR`` s; ``seconds`` in all."""
    with (
        private_redis(workdir) as (redis_url, redis_proc),
        service(root, workdir, viewer=True, ADVISOR_REDIS_URL=redis_url) as srv,
        httpx.Client(base_url=srv.url, timeout=120) as http,
    ):
        r = http.put("/domains/big", json={"map": open_map(500, 500)}, headers=ADMIN)
        assert r.status_code in (200, 201), r.text
        viewer_port = http.get("/viewer").json()["port"]
        before = http.get("/domains/default").json()["trajectories"]
        created = []
        for k in range(200):
            c = http.post("/domains/default/sessions", json={}).json()
            created.append((k, c["session_id"], c["token"]))
        errors, writes, reads = mp.Value("i", 0), mp.Value("i", 0), mp.Value("i", 0)
        refused_writes, refused_reads = mp.Value("i", 0), mp.Value("i", 0)
        acked = mp.Array("i", 200)
        answers = mp.Array("d", 1 + 3 * 200 * int(seconds) * 12)
        procs = [mp.Process(target=stepped_explorers,
                            args=(srv.ws_url, created[i::4], seconds, answers, acked, errors))
                 for i in range(4)]  # fmt: skip
        procs += [mp.Process(target=steady_writer,
                             args=(srv.url, seconds, writes, refused_writes, errors))
                  for _ in range(5)]  # fmt: skip
        prior = srv.url + "/domains/big/prior"
        procs += [mp.Process(target=steady_reader,
                             args=(prior, seconds, reads, refused_reads, errors))
                  for _ in range(2)]  # fmt: skip
        procs.append(mp.Process(target=watcher, args=(viewer_port, seconds, errors)))
        began = time.monotonic()
        for p in procs:
            p.start()
        health: list[tuple[float, str, int, float]] = []  # (when, path, status, ms)
        paused = resumed = None
        while any(p.is_alive() for p in procs) and time.monotonic() - began < seconds + 120:
            now = time.monotonic() - began
            if paused is None and now >= FAULT_AT:
                os.kill(redis_proc.pid, signal.SIGSTOP)
                paused = time.monotonic()
            if paused is not None and resumed is None and now >= FAULT_AT + FAULT_FOR:
                os.kill(redis_proc.pid, signal.SIGCONT)
                resumed = time.monotonic()
            for path in ("/health/live", "/health/ready"):
                t = time.perf_counter()
                try:
                    status = http.get(path, timeout=10).status_code
                except httpx.HTTPError:
                    status = 0
                health.append((time.monotonic(), path, status, 1000 * (time.perf_counter() - t)))
            time.sleep(0.25)
        for p in procs:
            p.join(timeout=60)
        crashed = sum(p.exitcode != 0 for p in procs)
        assert paused is not None and resumed is not None, "the load ended before the pause"
        lost = twice = 0
        for k, sid, token in created:
            held = http.get(f"/sessions/{sid}", headers={"Authorization": f"Bearer {token}"})
            steps = held.json()["steps"] if held.status_code == 200 else 0
            lost += max(0, acked[k] - steps)
            twice += max(0, steps - acked[k])
        stored = http.get("/domains/default").json()["trajectories"] - before
        sessions_end = http.get("/health").json()["sessions"]
    n = int(answers[0])
    rows_of = np.asarray(answers[1 : 1 + 3 * n]).reshape(-1, 3)
    sent, rtt, kind = rows_of[:, 0], rows_of[:, 1], rows_of[:, 2]
    decided, refusal = kind == DECIDED, kind == REFUSED
    start = began + FAULT_FROM

    def p99(mask: Any) -> float:
        return float(np.percentile(rtt[mask], 99)) if mask.any() else float("nan")

    before_pause = decided & (sent >= start) & (sent < paused)
    first_after = decided & (sent >= resumed) & (sent < resumed + FAULT_BACK)
    later = decided & (sent >= resumed + FAULT_BACK)
    # the first second after Redis returned from which every 1-s window's p99 is under target
    # (nan: not within the run), and the first whose p99 is back under the one before the pause
    windows = np.arange(resumed, sent.max() - 1.0 + 1e-9, 1.0)
    by_second = [p99(decided & (sent >= w) & (sent < w + 1)) for w in windows]
    over = [k for k, v in enumerate(by_second) if not v < FAULT_P99]
    back = float("nan") if over and over[-1] == len(by_second) - 1 else (
        float(over[-1] + 1) if over else 0.0
    )  # fmt: skip
    baseline = p99(before_pause)
    again = next((float(k) for k, v in enumerate(by_second) if v <= baseline), float("nan"))
    refusals = rtt[refusal]
    late = refusal & (sent >= paused + 2.0)  # the breaker's: Redis known to be down
    series = []
    for w in np.arange(began + FAULT_FROM, sent.max(), 1.0):
        within = (sent >= w) & (sent < w + 1)
        series.append(f"{w - began:.0f}: {p99(decided & within):.0f} ms, "
                      f"{int((within & refusal).sum())} refused")  # fmt: skip
    print("single-event p99 by second of the load:", "; ".join(series), file=sys.stderr)
    live_bad = sum(1 for _, path, st, _ in health if path == "/health/live" and st != 200)
    live_max = max(ms for _, path, _, ms in health if path == "/health/live")
    ready_503 = sum(1 for t, path, st, _ in health
                    if path == "/health/ready" and st == 503 and paused <= t < resumed)  # fmt: skip
    return [
        ("redis pause: events answered with a decision", int(decided.sum()), "events"),
        ("redis pause: events refused 503 (Redis named, sent again)", int(refusal.sum()),
         "events"),
        ("redis pause: ingests and prior reads refused 503",
         refused_writes.value + refused_reads.value, ""),
        ("redis pause: other errors (answers neither a decision nor a 503, failed requests "
         "or connections, load processes that died)", errors.value + crashed, ""),
        ("redis pause: acknowledged events Redis does not hold at the end (lost)", lost, ""),
        ("redis pause: events Redis holds that were not acknowledged", twice, ""),
        ("redis pause: trajectories acknowledged", writes.value, ""),
        ("redis pause: trajectories acknowledged and not stored",
         max(0, writes.value - stored), ""),
        ("redis pause: trajectories stored and not acknowledged", max(0, stored - writes.value),
         ""),
        ("redis pause: prior reads answered", reads.value, ""),
        ("redis pause: single-event p99 before the pause", p99(before_pause), "ms"),
        ("redis pause: 503 answers p50", float(np.percentile(refusals, 50)), "ms"),
        ("redis pause: 503 answers p99", float(np.percentile(refusals, 99)), "ms"),
        ("redis pause: 503 answers max", float(refusals.max()), "ms"),
        ("redis pause: 503 answers p99, from 2 s after Redis stopped (refused by the breaker)",
         float(np.percentile(rtt[late], 99)) if late.any() else float("nan"), "ms"),
        (f"redis pause: single-event p99, first {FAULT_BACK:.0f} s after Redis returned",
         p99(first_after), "ms"),
        (f"redis pause: single-event p99 from {FAULT_BACK:.0f} s after Redis returned to the end",
         p99(later), "ms"),
        (f"redis pause: seconds after Redis returned until every 1-s window's p99 < "
         f"{FAULT_P99:.0f} ms (nan: not within the run)", back, "s"),
        ("redis pause: seconds after Redis returned until a 1-s window's p99 is back under the "
         "p99 before the pause", again, "s"),
        ("redis pause: /health/live answers other than 200", live_bad, ""),
        ("redis pause: /health/live slowest answer", live_max, "ms"),
        ("redis pause: /health/ready answered 503 while Redis was stopped", ready_503, "times"),
        ("redis pause: live sessions at the end", sessions_end, ""),
    ]  # fmt: skip


SECTIONS: dict[str, tuple[Callable[[Path, Path, float], Rows], float]] = {
    "reads": (bench_reads, 15.0),
    "batches": (bench_batches, 15.0),
    "attacks": (bench_attacks, 20.0),
    "hogs": (bench_hogs, 5.0),
    "throughput": (bench_throughput, 10.0),
    "memory": (bench_memory, 0.0),
    "loop": (bench_loop, 0.0),
    "combined": (bench_combined, 150.0),
    "redis_pause": (bench_redis_pause, 70.0),
}
#: Domains the loop-lag section makes, each measured the same way (its rows: the worst of them)
REPEATS = 3
#: The combined load's first seconds, while caches fill and the allocator grows its arenas
#: (measured: RSS rises for 60 to 80 s, then stays within a few MiB)
WARM_UP = 90.0


def main() -> None:
    parser = arguments(__doc__)
    parser.add_argument("--root", type=Path, default=ROOT, help="source tree of the service")
    parser.add_argument("--only", nargs="*", choices=sorted(SECTIONS), default=list(SECTIONS))
    parser.add_argument("--write", type=Path, help="rewrite this document's section")
    parser.add_argument("--seconds", type=float, help="each section's load this long instead")
    args = parser.parse_args()
    rows: Rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.only:
            fn, seconds = SECTIONS[name]
            got = fn(args.root, Path(tmp), args.seconds or seconds)
            rows += got
            for label, value, unit in got:
                print(f"| {label} | {value:,.2f} {unit} |", flush=True)
    if args.write:
        table = "\n".join(f"| {label} | {value:,.2f} {unit} |" for label, value, unit in rows)
        body = (
            f"Measured with `{command_line()}` ({machine()}):\n\n"
            f"| measurement | value |\n|---|---|\n{table}\n"
        )
        key = "hostile_" + "_".join(args.only)
        write_section(args.write, key, body)


if __name__ == "__main__":
    mp.set_start_method("fork")
    main()
