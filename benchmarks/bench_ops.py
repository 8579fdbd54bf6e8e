"""What operations cost the hot path: the access log and the Prometheus metrics.

Four servers (``python -m app serve --no-viewer --log-level info``, one uvicorn worker each,
the access log written to a file) answer one event per POST from Debian's ``wrk`` (1 thread,
32 connections, the events spread over 64 sessions), runs alternated so that a drifting load
hits them alike:

* ``log every request, no metrics``: what the service did before it had metrics
  (``ADVISOR_ACCESS_LOG_EVENTS=true ADVISOR_METRICS_ENABLED=false``);
* ``log every request, metrics``: ``ADVISOR_ACCESS_LOG_EVENTS=true``;
* ``events counted, not logged (default)``: the defaults;
* ``no event log, no metrics``: ``ADVISOR_METRICS_ENABLED=false``: the metrics' own cost is
  the difference to the default.

    .venv/bin/python benchmarks/bench_ops.py [--repeats 3] [--write docs/PERFORMANCE.md]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.domain.grid import ACTIONS, GridDomain  # noqa: E402
from app.domain.maps import DEFAULT_MAP  # noqa: E402
from benchmarks._load import (  # noqa: E402
    EVENTS_LUA,
    create_sessions,
    load_average,
    run_wrk,
    start_advisor,
    write_sessions,
)
from benchmarks._report import arguments, command_line, machine, write_section  # noqa: E402

CONFIGS: dict[str, dict[str, str]] = {
    "log every request, no metrics (before)": {
        "ADVISOR_ACCESS_LOG_EVENTS": "true",
        "ADVISOR_METRICS_ENABLED": "false",
    },
    "log every request, metrics": {"ADVISOR_ACCESS_LOG_EVENTS": "true"},
    "events counted, not logged (default)": {},
    "no event log, no metrics": {"ADVISOR_METRICS_ENABLED": "false"},
}


def bodies(n: int) -> list[str]:
    grid = GridDomain.from_file(DEFAULT_MAP)
    rng = np.random.default_rng(1)
    s, out = grid.start, []
    for a in rng.integers(0, 4, n).tolist():
        out.append(json.dumps({"state": list(grid.cell(s)), "action": ACTIONS[a]}))
        s = int(grid.next_state[s, a])
    return out


def bench(tmp: Path, repeats: int, seconds: float, conns: int) -> dict[str, dict[str, float]]:
    body_file = tmp / "bodies.txt"
    body_file.write_text("\n".join(bodies(1000)) + "\n")
    servers = {name: start_advisor(tmp, log_level="info", **env) for name, env in CONFIGS.items()}
    runs: dict[str, dict[str, list[float]]] = {name: {} for name in CONFIGS}
    try:
        files = {}
        for name, server in servers.items():
            made = create_sessions(server, 64, tmp)
            files[name] = write_sessions(made, tmp / f"sessions-{server.port}.txt")
        for _ in range(repeats):
            for name, server in servers.items():
                cpu = server.cpu_seconds()
                r = run_wrk(
                    server.url, EVENTS_LUA, [str(files[name]), str(body_file), "0"],
                    seconds, conns, tmp,
                )  # fmt: skip
                if r.errors:
                    raise RuntimeError(f"{name}: {r.errors} failed requests")
                cpu = server.cpu_seconds() - cpu
                for key, v in (("rate", r.rate), ("p50", r.p50_ms), ("p99", r.p99_ms),
                               ("cpu_us", cpu / r.requests * 1e6)):  # fmt: skip
                    runs[name].setdefault(key, []).append(v)
        for name, server in servers.items():
            runs[name]["log_lines"] = [float(sum(1 for _ in server.log.open("rb")))]
    finally:
        for server in servers.values():
            server.stop()
    out: dict[str, dict[str, Any]] = {}
    for name, values in runs.items():
        out[name] = {k: float(statistics.median(v)) for k, v in values.items()}
        out[name]["rates"] = values["rate"]
    return out


def in_process(n: int = 100_000) -> dict[str, float]:
    """Microseconds per request of the metrics alone, in this process (no server, no socket):
    the middleware around a bare ASGI answer, and the decision counters."""
    import asyncio

    from app.service.metrics import METRICS, MetricsMiddleware

    async def bare(scope: Any, receive: Any, send: Any) -> None:
        await send({"type": "http.response.start", "status": 200, "headers": []})
        await send({"type": "http.response.body", "body": b"{}"})

    async def receive() -> dict[str, Any]:
        return {"type": "http.request", "body": b""}

    async def send(message: Any) -> None:
        return None

    scope = {"type": "http", "method": "POST", "headers": [], "path": "/sessions/x/events"}

    async def per_call(app: Any) -> float:
        started = time.perf_counter()
        for _ in range(n):
            await app(dict(scope), receive, send)
        return (time.perf_counter() - started) / n * 1e6

    plain = min(asyncio.run(per_call(bare)) for _ in range(3))
    counted = min(asyncio.run(per_call(MetricsMiddleware(bare))) for _ in range(3))
    started = time.perf_counter()
    for _ in range(n):
        METRICS.decisions("default", "paper", 1, 0)
    decisions = (time.perf_counter() - started) / n * 1e6
    return {"middleware": counted - plain, "decisions": decisions}


def report(args: argparse.Namespace, res: dict[str, dict[str, Any]], loads: list[float]) -> str:
    parts = res.pop("in process")
    before = res["log every request, no metrics (before)"]["rate"]
    default = res["events counted, not logged (default)"]
    bare = res["no event log, no metrics"]
    rows = [
        f"| {name} | {r['rate']:,.0f} | {r['p50']:.1f} | {r['p99']:.1f} | {r['cpu_us']:.0f} | "
        + ", ".join(f"{x:,.0f}" for x in r["rates"])
        + " |"
        for name, r in res.items()
    ]
    return "\n".join([
        "## Metrics and access log",
        "",
        f"Command: `{command_line()}`  ",
        f"Machine: {machine()}; load average {min(loads):.1f}-{max(loads):.1f}.",
        "",
        "One event per POST (`POST /sessions/{id}/events`), wrk 1 thread, "
        f"{args.conns} connections, the events spread over 64 sessions; medians of "
        f"{args.repeats} alternated runs of {args.seconds:g} s; uvicorn at `--log-level info`, "
        "the access log going to a file.",
        "",
        "| server | decisions/s | p50 ms | p99 ms | server CPU us/request | each run |",
        "|---|---|---|---|---|---|",
        *rows,
        "",
        f"Counting the event routes instead of logging them: {default['rate'] / before:.2f} x "
        f"the throughput of logging every request without metrics. The metrics themselves "
        f"(counter and latency histogram per request, decisions and advice per domain and "
        f"strategy): {default['cpu_us'] - bare['cpu_us']:+.0f} us of server CPU per request, "
        f"{default['rate'] / bare['rate']:.2f} x the throughput without them.",
        "",
        "The metrics alone, in process (no server, no socket; best of 3 runs of 100,000 calls): "
        f"the middleware (route template, status, counter, latency histogram) adds "
        f"{parts['middleware']:.1f} us to a request, counting its decisions and advice "
        f"{parts['decisions']:.1f} us; a one-event request costs the server about "
        f"{default['cpu_us']:.0f} us of CPU in all.",
    ]) + "\n"  # fmt: skip


def main() -> None:
    ap = arguments(__doc__)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=6.0)
    ap.add_argument("--conns", type=int, default=32)
    ap.add_argument("--write", type=Path)
    args = ap.parse_args()
    loads = [load_average()]
    with tempfile.TemporaryDirectory(prefix="bench-ops-") as tmp:
        res: dict[str, Any] = bench(Path(tmp), args.repeats, args.seconds, args.conns)
    loads.append(load_average())
    res["in process"] = in_process()
    body = report(args, res, loads)
    print(body)
    if args.write:
        write_section(args.write, "bench_ops", body)


if __name__ == "__main__":
    main()
