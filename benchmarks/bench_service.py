"""The service against its framework's limit, and how its cost grows.

Every server is a subprocess (``python -m app serve --no-viewer`` on a fresh data directory, or
the bare FastAPI app of ``benchmarks/baseline_app.py`` under the same uvicorn settings), one
uvicorn worker each, on free 127.0.0.1 ports; loads come from Debian's ``wrk`` (HTTP) and an
asyncio ``websockets`` driver (streams), bounded in time and count. Sections (``--only``):

* ``rest``: one event per POST, service vs a bare endpoint that parses the same body and
  answers a text of the same size; ``--rest-pairs`` interleaved pairs of runs (the order
  swapped every other pair); decisions/s, p50, p99, server CPU per request; the ratio is the
  median of the pairs' ratios, and so is the CPU-per-request ratio beside it.
* ``ws``: 500 events per websocket message, service (JSON and binary answers) vs an echo of
  the same frames and vs a bare endpoint answering each frame with a text the size of the
  service's JSON answer.
* ``parts``: the parts of one such message in this process (no server): reading, deciding,
  writing, and the libm calls the decisions make; what any framework would add to.
* ``sessions``: throughput with 1 to 100,000 live sessions (REST spread over every session,
  websocket on a few), resident memory; then every session given 200 more events (all its
  buffers full) and the memory measured again.
* ``curves``: websocket throughput against window length and maze size (through the service).
* ``ingest``: 1,000 expert trajectories posted while 100 explorers stream, paced; the
  explorers' decision latency before and during the ingestion.

Figures go to docs/figures/service_*.png; ``--write`` rewrites this benchmark's section of
docs/PERFORMANCE.md. ``--root DIR`` serves the advisor from another source tree (e.g. an older
commit, for before/after figures; written as the ``bench_service_before`` section).

    .venv/bin/python benchmarks/bench_service.py [--repeats 5] [--write docs/PERFORMANCE.md]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import multiprocessing as mp
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import httpx
import matplotlib
import orjson

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.domain.generate import generate_domain  # noqa: E402
from app.domain.grid import ACTIONS, GridDomain  # noqa: E402
from app.domain.maps import DEFAULT_MAP  # noqa: E402
from app.domain.paths import expert_trajectories  # noqa: E402
from benchmarks._load import (  # noqa: E402
    COUNTED_LUA,
    EVENTS_LUA,
    Server,
    create_sessions,
    load_average,
    paced_explorers,
    post_all,
    run_wrk,
    start_advisor,
    start_baseline,
    stream_load,
    write_sessions,
)
from benchmarks._report import arguments, command_line, machine, write_section  # noqa: E402

FIGURES = ROOT / "docs" / "figures"
ADMIN = {"X-API-Key": "bench"}
FRAME = 500  # events per websocket message
WARM = 200  # events per session before the memory is measured
Row = tuple[str, str, str]


def med(values: list[float]) -> float:
    return float(statistics.median(values))


def walk(grid: GridDomain, rng: np.random.Generator, n: int) -> list[dict[str, Any]]:
    """A random walk of ``n`` events from the start (a bump into a wall stays put)."""
    s, out = grid.start, []
    for a in rng.integers(0, 4, n).tolist():
        out.append({"state": list(grid.cell(s)), "action": ACTIONS[a]})
        s = int(grid.next_state[s, a])
    return out


def dumps(value: Any) -> str:
    return json.dumps(value, separators=(",", ":"))


def frames_for(grid: GridDomain, seed: int, count: int = 8, size: int = FRAME) -> list[str]:
    rng = np.random.default_rng(seed)
    return [dumps(walk(grid, rng, size)) for _ in range(count)]


def stream_urls(server: Server, sessions: list[tuple[str, str]], path: str = "stream") -> list[str]:
    return [f"{server.ws_url}/sessions/{sid}/{path}?token={token}" for sid, token in sessions]


def answer_size(server: Server, session: tuple[str, str], bodies: list[str]) -> int:
    """Mean length of the service's answers to ``bodies`` (REST)."""
    sid, token = session
    auth = {"Authorization": f"Bearer {token}", "Content-Type": "application/json"}
    with httpx.Client(base_url=server.url, timeout=30) as http:
        sizes = [len(http.post(f"/sessions/{sid}/events", content=b, headers=auth).content)
                 for b in bodies]  # fmt: skip
    return round(float(np.mean(sizes)))


# ---- REST -------------------------------------------------------------------------------------
def bench_rest(tmp: Path, root: Path, pairs: int, seconds: float, conns: int) -> dict[str, Any]:
    grid = GridDomain.from_file(DEFAULT_MAP)
    bodies = [dumps(e) for e in walk(grid, np.random.default_rng(1), 1000)]
    bodies_file = tmp / "rest-bodies.txt"
    bodies_file.write_text("\n".join(bodies) + "\n")
    with start_advisor(tmp, root) as advisor:
        sessions = create_sessions(advisor, 64, tmp)
        sessions_file = write_sessions(sessions, tmp / "rest-sessions.txt")
        size = answer_size(advisor, sessions[0], bodies[:300])
        with start_baseline(tmp, size, 0) as bare:
            out: dict[str, list[float]] = {}
            both = (("service", advisor), ("bare", bare))
            for k in range(pairs):  # interleaved: drifting load hits both alike
                for name, server in both if k % 2 == 0 else both[::-1]:
                    args = [str(sessions_file), str(bodies_file), "0"]
                    cpu = server.cpu_seconds()
                    r = run_wrk(server.url, EVENTS_LUA, args, seconds, conns, tmp)
                    if r.errors:
                        raise RuntimeError(f"{name}: {r.errors} failed requests")
                    cpu = server.cpu_seconds() - cpu
                    for key, v in (("rate", r.rate), ("p50", r.p50_ms), ("p99", r.p99_ms),
                                   ("cpu_us", cpu / r.requests * 1e6)):  # fmt: skip
                        out.setdefault(f"{name} {key}", []).append(v)
    res: dict[str, Any] = {k: med(v) for k, v in out.items()}
    res["runs"] = out
    res["answer_bytes"] = size
    rates = zip(out["service rate"], out["bare rate"], strict=True)
    res["pair_ratios"] = [a / b for a, b in rates]
    res["ratio"] = med(res["pair_ratios"])
    cpus = zip(out["bare cpu_us"], out["service cpu_us"], strict=True)
    res["pair_cpu_ratios"] = [b / a for b, a in cpus]  # bare's CPU / the service's, a request
    res["cpu_ratio"] = med(res["pair_cpu_ratios"])
    return res


# ---- websocket --------------------------------------------------------------------------------
def bench_ws(tmp: Path, root: Path, repeats: int, seconds: float, conns: int) -> dict[str, Any]:
    grid = GridDomain.from_file(DEFAULT_MAP)
    frames = frames_for(grid, 2)
    with start_advisor(tmp, root) as advisor:
        sessions = create_sessions(advisor, conns, tmp)
        urls = stream_urls(advisor, sessions)
        binary_urls = [f"{u}&format=binary" for u in urls]
        probe = stream_load(urls[:1], frames, FRAME, 1.0, max_messages=len(frames))
        size = probe.answer_bytes
        with start_baseline(tmp, 64, size) as bare:
            targets: dict[str, tuple[Server, list[str]]] = {
                "service": (advisor, urls),
                "binary": (advisor, binary_urls),
                "echo": (bare, stream_urls(bare, sessions, "stream")),
                "sized": (bare, stream_urls(bare, sessions, "answer")),
            }
            if root != ROOT:  # an older tree may not have binary answers
                del targets["binary"]
            out: dict[str, list[float]] = {}
            for _ in range(repeats):
                for name, (server, target) in targets.items():
                    cpu = server.cpu_seconds()
                    r = stream_load(target, frames, FRAME, seconds)
                    cpu = server.cpu_seconds() - cpu
                    for key, v in (("rate", r.rate), ("p50", r.latency_ms(50)),
                                   ("p99", r.latency_ms(99)),
                                   ("cpu_us", cpu / r.events * 1e6),
                                   ("answer_bytes", r.answer_bytes)):  # fmt: skip
                        out.setdefault(f"{name} {key}", []).append(v)
    res: dict[str, Any] = {k: med(v) for k, v in out.items()}
    res["runs"] = out
    res["frame_bytes"] = float(np.mean([len(f) for f in frames]))
    res["answer_bytes"] = size
    res["ratio_echo"] = res["service rate"] / res["echo rate"]
    res["ratio_sized"] = res["service rate"] / res["sized rate"]
    if "binary rate" in res:
        res["ratio_binary_echo"] = res["binary rate"] / res["echo rate"]
        pairs = zip(out["binary rate"], out["echo rate"], strict=True)
        res["binary_pair_ratios"] = [a / b for a, b in pairs]
    return res


# ---- parts of one message, in process --------------------------------------------------------
def bench_parts(tmp: Path, repeats: int) -> dict[str, float]:
    """Microseconds per 500-event message for each part of the websocket path, in this process
    (no server, no socket): what the service must do for a message whatever the framework."""
    from numba import njit

    from app.service import ops
    from app.service.config import Settings
    from app.service.schemas import SessionCreate
    from app.service.state import open_state
    from app.service.wire.encode import batch_binary, batch_json, decision_dict
    from app.service.wire.events import read_moves

    @njit(cache=False)
    def libm_only(x: Any) -> float:  # pragma: no cover - compiled
        """One exp and four logs per value: the calls each decision makes (eqs. (5) and (6))."""
        total = 0.0
        for v in x:
            total += np.exp(-v) + np.log(v) + np.log(v + 1) + np.log(v + 2) + np.log(v + 3)
        return total

    state, _ = open_state(Settings(data_dir=tmp / "parts", viewer_enabled=False))
    domain = state.catalog.get("default")
    grid = domain.domain
    frames = frames_for(grid, 7)
    limit = state.settings.max_batch_events
    session, _ = asyncio.run(ops.open_session(state, domain, SessionCreate()))
    moves = [read_moves(grid, f, limit)[0] for f in frames]

    def everything(frame: str | bytes, binary: bool) -> bytes:
        """What the event routes do with a batch (in one slice): read, decide, write."""
        got, _, first = read_moves(grid, frame, limit)
        decided = state.registry.observe_batch(session, got, first)
        return batch_binary(decided, grid) if binary else batch_json(decided, grid)

    ops.warm_up()
    libm_only(np.random.default_rng(0).random(FRAME) + 0.5)
    advisor = session.advisor
    out = advisor.observe_batch(*moves[0])
    values = np.random.default_rng(1).random(FRAME) + 0.5
    cases: dict[str, Callable[[int], Any]] = {
        "read": lambda i: read_moves(grid, frames[i % len(frames)], limit),
        "decide": lambda i: advisor.observe_batch(*moves[i % len(moves)]),
        "libm": lambda i: libm_only(values),
        "encode_binary": lambda i: batch_binary(out, grid),
        "encode_json": lambda i: batch_json(out, grid),
        # the JSON writer as a library alone: orjson over the decisions as dicts
        "encode_json_orjson": lambda i: orjson.dumps(
            [decision_dict(d, grid) for d in out.decisions()]
        ),
        "all_binary": lambda i: everything(frames[i % len(frames)], True),
        "all_json": lambda i: everything(frames[i % len(frames)], False),
    }
    res: dict[str, list[float]] = {}
    for _ in range(repeats):
        for name, call in cases.items():
            t0 = time.thread_time()
            for i in range(200):
                call(i)
            res.setdefault(name, []).append((time.thread_time() - t0) / 200 * 1e6)
    state.close()
    return {name: med(v) for name, v in res.items()}


# ---- live sessions and memory -----------------------------------------------------------------
def bench_sessions(
    tmp: Path, root: Path, counts: list[int], seconds: float, conns: int
) -> dict[str, Any]:
    grid = GridDomain.from_file(DEFAULT_MAP)
    bodies = [dumps(e) for e in walk(grid, np.random.default_rng(3), 1000)]
    bodies_file = tmp / "sess-bodies.txt"
    bodies_file.write_text("\n".join(bodies) + "\n")
    frames = frames_for(grid, 4)
    rows: list[dict[str, float]] = []
    sessions: list[tuple[str, str]] = []
    top = max(counts)
    with start_advisor(tmp, root, max_sessions=top + 1000) as advisor:
        rss0 = advisor.rss_bytes()
        for n in counts:
            t0, had = time.perf_counter(), len(sessions)
            sessions += create_sessions(advisor, n - had, tmp, seconds=600)
            created = time.perf_counter() - t0
            sessions_file = write_sessions(sessions, tmp / "sess-all.txt")
            args = [str(sessions_file), str(bodies_file), "0"]
            r = run_wrk(advisor.url, EVENTS_LUA, args, seconds, 32, tmp)
            some = [sessions[k % len(sessions)] for k in range(conns)]
            s = stream_load(stream_urls(advisor, some), frames, FRAME, seconds)
            rows.append({
                "sessions": n, "rest": r.rate, "rest_p99": r.p99_ms, "ws": s.rate,
                "rss": advisor.rss_bytes(), "created_per_s": (n - had) / created,
            })  # fmt: skip
        fresh = advisor.rss_bytes()
        # every session gets 200 more events in one request: recent path (100), posterior
        # history (200) and advice log (50) full; the window's ring (300) is allocated whole
        # when the session starts
        warm = [dumps(walk(grid, np.random.default_rng(10 + k), WARM)) for k in range(16)]
        warm_file = tmp / "warm-bodies.txt"
        warm_file.write_text("\n".join(warm) + "\n")
        t0 = time.perf_counter()
        marker = tmp / "warm.done"
        args = [str(tmp / "sess-all.txt"), str(warm_file), str(len(sessions)), str(marker)]
        w = run_wrk(advisor.url, EVENTS_LUA + COUNTED_LUA, args, 900, 8, tmp, marker.exists)
        warm_s = time.perf_counter() - t0
        warmed = advisor.rss_bytes()
        live = httpx.get(advisor.url + "/health").json()["sessions"]
    return {
        "rows": rows, "rss_start": rss0, "rss_fresh": fresh, "rss_warm": warmed,
        "sessions": live, "warm_requests": w.requests, "warm_errors": w.errors,
        "warm_seconds": warm_s,
    }  # fmt: skip


# ---- window length and maze size --------------------------------------------------------------
def bench_curves(
    tmp: Path, root: Path, windows: list[int], sizes: list[int], repeats: int, seconds: float,
    conns: int,
) -> dict[str, Any]:  # fmt: skip
    grid = GridDomain.from_file(DEFAULT_MAP)
    with start_advisor(tmp, root) as advisor, httpx.Client(base_url=advisor.url) as http:
        targets: dict[str, tuple[list[str], list[str]]] = {}
        for w in windows:
            made = create_sessions(advisor, conns, tmp, body={"window": w})
            targets[f"w{w}"] = (stream_urls(advisor, made), frames_for(grid, 5))
        states = {}
        for size in sizes:
            maze = generate_domain(size, size, seed=0, braid=0.2)
            name = f"maze{size}"
            r = http.put(f"/domains/{name}", json={"map": list(maze.rows_text)}, headers=ADMIN,
                         timeout=120)  # fmt: skip
            r.raise_for_status()
            experts = expert_trajectories(maze, np.random.default_rng(0), "anywhere", per_goal=2)
            trajs = [e.pairs for e in experts]
            post_trajectories(http, name, maze, trajs)
            made = create_sessions(advisor, conns, tmp, domain=name)
            targets[name] = (stream_urls(advisor, made), frames_for(maze, 6))
            states[size] = maze.n_states
        out: dict[str, list[float]] = {k: [] for k in targets}
        for _ in range(repeats):
            for key, (urls, frames) in targets.items():
                out[key].append(stream_load(urls, frames, FRAME, seconds).rate)
    return {
        "window": [med(out[f"w{w}"]) for w in windows],
        "maze": [med(out[f"maze{s}"]) for s in sizes],
        "states": [states[s] for s in sizes],
    }


def trajectory_bodies(grid: GridDomain, trajs: list[Any], per_request: int) -> list[bytes]:
    items = [
        {"steps": [{"state": list(grid.cell(int(s))), "action": ACTIONS[int(a)]} for s, a in t],
         "goal": None}
        for t in trajs
        if len(t)
    ]  # fmt: skip
    return [
        dumps({"trajectories": items[k : k + per_request]}).encode()
        for k in range(0, len(items), per_request)
    ]


def post_trajectories(http: httpx.Client, name: str, grid: GridDomain, trajs: list[Any]) -> None:
    """Post in requests of at most ~20,000 steps (the body limit is 2 MiB)."""
    batch: list[Any] = []
    for t in [*trajs, None]:
        if t is None or (batch and sum(len(b) for b in batch) + len(t) > 20_000):
            for body in trajectory_bodies(grid, batch, len(batch)):
                r = http.post(
                    f"/domains/{name}/trajectories",
                    content=body,
                    headers=ADMIN | {"Content-Type": "application/json"},
                    timeout=300,
                )
                r.raise_for_status()  # fmt: skip
            batch = []
        if t is not None:
            batch.append(t)


# ---- prior updates while serving --------------------------------------------------------------
def bench_ingest(
    tmp: Path, root: Path, explorers: int, rate: float, batchings: list[int]
) -> list[dict[str, float]]:
    grid = GridDomain.from_file(DEFAULT_MAP)
    experts = expert_trajectories(grid, np.random.default_rng(7), "anywhere", per_goal=130)
    trajs = [e.pairs for e in experts if len(e.pairs)][
        :1000
    ]  # an expert starting on its goal walks nothing
    results = []
    for per_request in batchings:
        bodies = trajectory_bodies(grid, trajs, per_request)
        with start_advisor(tmp, root) as advisor:
            sessions = create_sessions(advisor, explorers, tmp)
            rng = np.random.default_rng(8)
            walks = [[dumps(e) for e in walk(grid, rng, 400)] for _ in sessions]
            urls = stream_urls(advisor, sessions)
            ctx = mp.get_context("spawn")
            with ctx.Pool(1) as pool:
                pool.apply(time.sleep, (0,))  # the worker is up before the clock matters
                paced, (t0, t1, failures) = asyncio.run(
                    _stream_while_posting(urls, walks, rate, pool, advisor.url, bodies)
                )
        sent, lat = np.array(paced.sent), np.array(paced.latency)
        during = (sent + lat >= t0) & (sent <= t1)
        before = sent + lat < t0
        results.append({
            "per_request": per_request, "requests": len(bodies), "seconds": t1 - t0,
            "failures": failures, "errors": paced.errors, "decisions": int(during.sum()),
            "p50": float(np.percentile(lat[during], 50) * 1e3),
            "p99": float(np.percentile(lat[during], 99) * 1e3),
            "max": float(lat[during].max() * 1e3),
            "before_p50": float(np.percentile(lat[before], 50) * 1e3),
            "before_p99": float(np.percentile(lat[before], 99) * 1e3),
            "rate": len(lat) / (sent.max() - sent.min()) if len(sent) > 1 else 0.0,
        })  # fmt: skip
    return results


async def _stream_while_posting(
    urls: list[str], walks: list[list[str]], rate: float, pool: Any, url: str, bodies: list[bytes]
) -> tuple[Any, tuple[float, float, int]]:
    """Explorers stream alone for 4 s, then while a worker process posts ``bodies``, then 1 s
    more."""
    until = asyncio.Event()
    task = asyncio.create_task(paced_explorers(urls, walks, rate, until))
    await asyncio.sleep(4.0)
    job = pool.apply_async(post_all, (url, "/domains/default/trajectories", "bench", bodies))
    ingest = await asyncio.to_thread(job.get, 600)
    await asyncio.sleep(1.0)
    until.set()
    return await task, ingest


# ---- figures and report -----------------------------------------------------------------------
def plot(path: Path, x: list[int], series: dict[str, list[float]], xlabel: str, title: str,
         log_y: bool = False) -> None:  # fmt: skip
    fig, ax = plt.subplots(figsize=(6, 3.6))
    for label, y in series.items():
        ax.plot(x, np.array(y) / 1e3, marker="o", label=label)
    ax.set_xscale("log")
    if log_y:
        ax.set_yscale("log")
    else:
        ax.set_ylim(bottom=0)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("thousand decisions / s")
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def verdict(ok: bool) -> str:
    return "**met**" if ok else "**not met**"


def report(args: argparse.Namespace, res: dict[str, Any], loads: list[float]) -> str:
    parts = [
        "## Service" + (f" (before: {args.label})" if args.root != ROOT else ""),
        "",
        f"Command: `{command_line()}`",
        "",
        f"Machine: {machine()}; wrk {wrk_version()}; 1-minute load average "
        f"{min(loads):.1f}-{max(loads):.1f} during the run (other work shared the 2 cores when "
        "above 1).",
        "",
    ]
    rows: list[Row] = []
    if "rest" in res:
        r = res["rest"]
        rows += [
            ("REST, one event per POST, service", f"{r['service rate']:,.0f} decisions/s, "
             f"p50 {r['service p50']:.1f} ms, p99 {r['service p99']:.1f} ms, "
             f"{r['service cpu_us']:.0f} us CPU/request", ""),
            ("REST, bare FastAPI: parses the body, answers the same size "
             f"({r['answer_bytes']} B)", f"{r['bare rate']:,.0f} requests/s, p50 "
             f"{r['bare p50']:.1f} ms, p99 {r['bare p99']:.1f} ms, {r['bare cpu_us']:.0f} us "
             "CPU/request", ""),
            (f"REST ratio service / bare, median of {len(r['pair_ratios'])} interleaved "
             "pairs: rates (per pair: " + ", ".join(f"{x:.2f}" for x in r["pair_ratios"])
             + "); server CPU per request, bare / service (per pair: "
             + ", ".join(f"{x:.2f}" for x in r["pair_cpu_ratios"]) + ")",
             f"{r['ratio']:.2f} (CPU per request: {r['cpu_ratio']:.2f})",
             f">= 0.85: {verdict(r['ratio'] >= 0.85)}"),
        ]  # fmt: skip
    if "ws" in res:
        w = res["ws"]
        rows += [
            (f"websocket, {FRAME} events per message, service ({args.ws_conns} connections)",
             f"{w['service rate']:,.0f} decisions/s (p50 {w['service p50']:.1f} ms, "
             f"p99 {w['service p99']:.1f} ms a message; {w['service cpu_us']:.2f} us "
             "CPU/decision)", f">= 200,000/s: {verdict(w['service rate'] >= 200_000)}"),
            (f"websocket echo of the same frames ({w['frame_bytes']:,.0f} B)",
             f"{w['echo rate']:,.0f} events/s", ""),
            (f"websocket, bare: each frame answered with {w['answer_bytes']:,} B (the size of "
             "the service's answer)", f"{w['sized rate']:,.0f} events/s", ""),
            ("websocket ratio service / echo, JSON answers", f"{w['ratio_echo']:.2f}",
             "" if "binary rate" in w else f">= 0.7: {verdict(w['ratio_echo'] >= 0.7)}"),
            ("websocket ratio service / same-size answers, JSON answers",
             f"{w['ratio_sized']:.2f}", ""),
        ]  # fmt: skip
        if "binary rate" in w:
            rows += [
                (f"websocket, {FRAME} events per message, service, binary answers "
                 f"(`?format=binary`, {w['binary answer_bytes']:,.0f} B a message)",
                 f"{w['binary rate']:,.0f} decisions/s (p50 {w['binary p50']:.1f} ms, "
                 f"p99 {w['binary p99']:.1f} ms a message; {w['binary cpu_us']:.2f} us "
                 "CPU/decision)", f">= 200,000/s: {verdict(w['binary rate'] >= 200_000)}"),
                ("websocket ratio service / echo, binary answers (median rates; per pair: "
                 + ", ".join(f"{x:.2f}" for x in w["binary_pair_ratios"]) + ")",
                 f"{w['ratio_binary_echo']:.2f}",
                 f">= 0.7: {verdict(w['ratio_binary_echo'] >= 0.7)}"),
            ]  # fmt: skip
    if "sessions" in res:
        s = res["sessions"]
        n = s["sessions"]
        per = (s["rss_warm"] - s["rss_start"]) / n
        rows += [
            (f"resident memory, {n:,} live sessions, each after {WARM} events or more (every "
             "buffer of a session full)",
             f"{s['rss_warm'] / 2**30:.3f} GiB ({per:,.0f} bytes a session above the "
             f"{s['rss_start'] / 2**20:.0f} MiB of an idle service)",
             f"<= 1 GiB: {verdict(s['rss_warm'] <= 2**30)}"),
            (f"resident memory, {n:,} sessions with at most a few events each",
             f"{s['rss_fresh'] / 2**30:.3f} GiB "
             f"({(s['rss_fresh'] - s['rss_start']) / n:,.0f} bytes a session)", ""),
        ]  # fmt: skip
    if "ingest" in res:
        for g in res["ingest"]:
            rows.append((
                f"1,000 trajectories posted as {g['requests']:.0f} requests of "
                f"{g['per_request']:.0f} while {args.explorers} explorers stream "
                f"({args.explorer_rate:g} events/s each)",
                f"ingested in {g['seconds']:.2f} s; decisions meanwhile: {g['decisions']:,} "
                f"with p50 {g['p50']:.1f} ms, p99 {g['p99']:.1f} ms, max {g['max']:.1f} ms "
                f"(before: p50 {g['before_p50']:.1f} ms, p99 {g['before_p99']:.1f} ms)",
                f"p99 <= 100 ms: {verdict(g['p99'] <= 100)}",
            ))  # fmt: skip
    parts += ["| measurement | result | target |", "|---|---|---|"]
    parts += [f"| {a} | {b} | {c} |" for a, b, c in rows]
    parts.append("")
    parts.append(
        f"Medians of {args.repeats} interleaved runs ({args.rest_pairs} pairs for REST) of "
        f"{args.seconds:g} s per figure (REST: "
        f"wrk, 1 thread, {args.rest_conns} connections, the events spread over 64 sessions; "
        f"websocket: {args.ws_conns} connections, one session each, one message in flight "
        "each). CPU is the server process's user + system time from /proc."
    )
    if "sessions" in res:
        s = res["sessions"]
        head = "| live sessions | " + " | ".join(f"{r['sessions']:,}" for r in s["rows"]) + " |"
        parts += [
            "",
            "### Live sessions",
            "",
            "![sessions](figures/service_sessions.png)",
            "",
            head,
            "|---" * (len(s["rows"]) + 1) + "|",
            "| REST, one event per POST, spread over every session (decisions/s) | "
            + " | ".join(f"{r['rest']:,.0f}" for r in s["rows"]) + " |",
            "| REST p99 (ms) | " + " | ".join(f"{r['rest_p99']:.1f}" for r in s["rows"]) + " |",
            f"| websocket, {FRAME} events per message (decisions/s) | "
            + " | ".join(f"{r['ws']:,.0f}" for r in s["rows"]) + " |",
            "| resident memory (MiB) | "
            + " | ".join(f"{r['rss'] / 2**20:,.0f}" for r in s["rows"]) + " |",
            "",
            f"Then each of the {s['sessions']:,} sessions got one request of {WARM} events "
            f"({s['warm_requests']:,} requests in {s['warm_seconds']:.0f} s, "
            f"{s['warm_errors']} failed): resident memory {s['rss_fresh'] / 2**20:,.0f} -> "
            f"{s['rss_warm'] / 2**20:,.0f} MiB.",
        ]  # fmt: skip
    if "parts" in res:
        parts += parts_report(res["parts"], res.get("ws"))
    if "curves" in res:
        c = res["curves"]
        parts += [
            "",
            "### Window length and maze size, through the service",
            "",
            "![window](figures/service_window.png) ![maze](figures/service_maze.png)",
            "",
            "| window W | " + " | ".join(f"{w:,}" for w in args.windows) + " |",
            "|---" * (len(args.windows) + 1) + "|",
            f"| websocket, {FRAME} events per message (decisions/s) | "
            + " | ".join(f"{v:,.0f}" for v in c["window"]) + " |",
            "",
            "| maze side | " + " | ".join(f"{m} ({n:,} states)" for m, n in
                                         zip(args.sizes, c["states"], strict=True)) + " |",
            "|---" * (len(args.sizes) + 1) + "|",
            f"| websocket, {FRAME} events per message (decisions/s) | "
            + " | ".join(f"{v:,.0f}" for v in c["maze"]) + " |",
        ]  # fmt: skip
    return "\n".join(parts) + "\n"


def parts_report(p: dict[str, float], ws: dict[str, Any] | None) -> list[str]:
    """The in-process parts of one message, and what they leave of 0.7 x the echo."""
    out = [
        "",
        f"### One {FRAME}-event message, part by part (in process, no server)",
        "",
        "| part | us a message | us a decision |",
        "|---|---|---|",
    ]
    names = [
        ("read", "read and check the events (compiled reader)"),
        ("decide", "decide (compiled loop over the session's advisor, with its bookkeeping)"),
        ("libm", "of which the libm calls alone: one exp and four logs a decision"),
        ("encode_binary", "write the binary answer"),
        ("encode_json", "write the JSON answer (orjson's numbers, laid out by a compiled loop)"),
        ("encode_json_orjson", "the same JSON written by orjson from a list of dicts alone"),
        ("all_binary", "everything, binary answer (read, decide, write)"),
        ("all_json", "everything, JSON answer (read, decide, write)"),
    ]
    out += [f"| {label} | {p[k]:.1f} | {p[k] / FRAME * 1e3:.0f} ns |" for k, label in names]
    if ws is not None:
        echo_us = ws["echo cpu_us"] * FRAME  # the echo server's CPU for one message
        budget = FRAME / (0.7 * ws["echo rate"]) * 1e6  # one message at 0.7 x the echo's rate
        floor = echo_us + p["read"] + p["libm"]
        out += [
            "",
            f"At 0.7 x the echo's rate ({0.7 * ws['echo rate']:,.0f} decisions/s) one worker "
            f"has {budget:.0f} us for a message; the echo itself spends {echo_us:.0f} us of "
            f"server CPU on one. Reading the events and the decisions' libm calls alone take "
            f"{p['read'] + p['libm']:.0f} us, so with no other cost at all the service would "
            f"reach {budget / floor * 0.7:.2f} x the echo.",
        ]  # fmt: skip
    return out


def wrk_version() -> str:
    try:
        out = subprocess.run(["wrk", "-v"], capture_output=True, text=True, timeout=10)
    except OSError:
        return "?"
    text = (out.stdout + out.stderr).split()
    return text[1] if len(text) > 1 else "?"


def main() -> None:
    ap = arguments(__doc__)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--rest-pairs", type=int, default=7,
                    help="interleaved pairs of REST runs (service, bare)")  # fmt: skip
    ap.add_argument("--seconds", type=float, default=4.0, help="length of one measured run")
    ap.add_argument("--rest-conns", type=int, default=32)
    ap.add_argument("--ws-conns", type=int, default=4)
    ap.add_argument("--sessions", type=int, nargs="+",
                    default=[1, 10, 100, 1_000, 10_000, 100_000])  # fmt: skip
    ap.add_argument("--windows", type=int, nargs="+", default=[10, 30, 100, 300, 1000, 3000])
    ap.add_argument("--sizes", type=int, nargs="+", default=[30, 60, 100, 150, 200, 300])
    ap.add_argument("--explorers", type=int, default=100)
    ap.add_argument("--explorer-rate", type=float, default=10.0, help="events/s per explorer")
    ap.add_argument("--batchings", type=int, nargs="+", default=[100, 1],
                    help="trajectories per ingestion request")  # fmt: skip
    ap.add_argument("--only", default="rest,ws,parts,sessions,curves,ingest")
    ap.add_argument("--root", type=Path, default=ROOT, help="source tree serving the advisor")
    ap.add_argument("--label", default="", help="what --root is (for the report)")
    ap.add_argument("--write", type=Path)
    args = ap.parse_args()
    only = set(args.only.split(","))
    FIGURES.mkdir(parents=True, exist_ok=True)
    res: dict[str, Any] = {}
    loads = [load_average()]
    steps: list[tuple[str, Callable[[Path], Any]]] = [
        ("rest", lambda t: bench_rest(t, args.root, args.rest_pairs, args.seconds,
                                      args.rest_conns)),
        ("ws", lambda t: bench_ws(t, args.root, args.repeats, args.seconds, args.ws_conns)),
        ("parts", lambda t: bench_parts(t, args.repeats)),
        ("sessions", lambda t: bench_sessions(t, args.root, args.sessions, 3.0, args.ws_conns)),
        ("curves", lambda t: bench_curves(t, args.root, args.windows, args.sizes,
                                          max(1, args.repeats // 2), 2.0, args.ws_conns)),
        ("ingest", lambda t: bench_ingest(t, args.root, args.explorers, args.explorer_rate,
                                          args.batchings)),
    ]  # fmt: skip
    for name, step in steps:
        if name not in only or (name == "parts" and args.root != ROOT):
            continue
        t0 = time.perf_counter()
        with tempfile.TemporaryDirectory(prefix=f"bench-{name}-") as tmp:
            res[name] = step(Path(tmp))
        loads.append(load_average())
        print(f"{name}: {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    if "sessions" in res and args.root == ROOT:
        rows = res["sessions"]["rows"]
        xs = [r["sessions"] for r in rows]
        plot(FIGURES / "service_sessions.png", xs,
             {"REST, 1 event per POST": [r["rest"] for r in rows],
              f"websocket, {FRAME} events per message": [r["ws"] for r in rows]},
             "live sessions", "Service decisions/s against live sessions", log_y=True)  # fmt: skip
    if "curves" in res and args.root == ROOT:
        c = res["curves"]
        plot(FIGURES / "service_window.png", args.windows,
             {f"websocket, {FRAME} events per message": c["window"]}, "window W (pairs)",
             "Service decisions/s against window length")  # fmt: skip
        plot(FIGURES / "service_maze.png", args.sizes,
             {f"websocket, {FRAME} events per message": c["maze"]}, "maze side (cells)",
             "Service decisions/s against maze size (window 300)")  # fmt: skip
    body = report(args, res, loads)
    print(body)
    print(json.dumps(res, default=float, indent=1), file=sys.stderr)
    if args.write:
        key = "bench_service" if args.root == ROOT else "bench_service_before"
        write_section(args.write, key, body)


if __name__ == "__main__":
    main()
