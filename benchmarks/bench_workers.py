"""Workers and durable sessions, side by side in one run: decisions per second for one and two
workers (REST, one event per request; websocket, 500-event frames), with sessions in Redis
(every event acknowledged once its session's new state is there) against the embedded single
process without it; what Redis costs per event (its CPU, its commands) and holds per session.

    python benchmarks/bench_workers.py [--seconds 8] [--repeats 3] [--write docs/PERFORMANCE.md]

The three services run at once; each round measures one load on the three back to back, then
the next load, in the opposite order every other round (the machine is shared and its speed
drifts: figures that are compared are taken seconds apart). wrk (16 connections over 16
sessions; hopping between sessions, then each connection keeping to its own) is the REST load;
an asyncio websocket driver in this process the stream load (4 sessions, each sending a
500-event frame and waiting for its answer). The load generator, Redis and the workers share
this machine's 2 cores.
"""

from __future__ import annotations

import json
import re
import statistics
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import redis

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.domain.grid import ACTIONS, GridDomain
from app.domain.maps import DEFAULT_MAP
from app.service.live.shared import SCRIPT
from benchmarks._load import (
    EVENTS_LUA,
    Server,
    create_sessions,
    run_wrk,
    start_advisor,
    stream_load,
    write_sessions,
)
from benchmarks._report import arguments, command_line, machine, write_section

REDIS_URL = "redis://127.0.0.1:6379/0"
PREFIX = "bench-workers"
CONFIGS: dict[str, dict[str, str]] = {
    "one process, no Redis": {},
    "1 worker, Redis": {"ADVISOR_REDIS_URL": REDIS_URL, "ADVISOR_REDIS_PREFIX": PREFIX + "1"},
    "2 workers, Redis": {
        "ADVISOR_REDIS_URL": REDIS_URL, "ADVISOR_REDIS_PREFIX": PREFIX + "2",
        "ADVISOR_WORKERS": "2",
    },
}  # fmt: skip
# args: sessions file ("id token" lines), bodies file: each wrk thread (one connection) keeps
# to one session, as an explorer keeps its connection (so its events reach one worker)
STICKY_LUA = r"""
local counter = 0
function setup(thread)
  thread:set("tid", counter)
  counter = counter + 1
end
local path, auth, bodies, j = "", "", {}, 0
function init(args)
  local k = 0
  for line in io.lines(args[1]) do
    if k == tid then
      local sid, token = line:match("(%S+) (%S+)")
      path, auth = "/sessions/" .. sid .. "/events", "Bearer " .. token
    end
    k = k + 1
  end
  for line in io.lines(args[2]) do bodies[#bodies + 1] = line end
  j = (tid * 104729) % #bodies
end
function request()
  j = j % #bodies + 1
  return wrk.format("POST", path, {["Authorization"] = auth,
                    ["Content-Type"] = "application/json"}, bodies[j])
end
"""
CONNECTIONS = 16
CORES = {"one process, no Redis": 1, "1 worker, Redis": 1, "2 workers, Redis": 2}


def walk(n: int, seed: int) -> list[dict[str, Any]]:
    grid = GridDomain.from_file(DEFAULT_MAP)
    rng = np.random.default_rng(seed)
    s, out = grid.start, []
    for a in rng.integers(0, 4, n).tolist():
        out.append({"state": list(grid.cell(s)), "action": ACTIONS[a]})
        s = int(grid.next_state[s, a])
    return out


def tree_cpu(server: Server) -> float:
    """CPU seconds of the server and its worker processes."""
    import os

    pids = [server.proc.pid]
    children = Path(f"/proc/{server.proc.pid}/task/{server.proc.pid}/children")
    pids += [int(p) for p in children.read_text().split()]
    total = 0.0
    for pid in pids:
        try:
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        except FileNotFoundError:
            continue
        total += (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    return total


def children_cpu() -> float:
    """CPU seconds of this process' children that have ended (wrk, once it exits)."""
    import os

    t = os.times()
    return t.children_user + t.children_system


def redis_cpu(r: redis.Redis) -> float:
    info = r.info("cpu")
    return float(info["used_cpu_sys"]) + float(info["used_cpu_user"])


def redis_calls(r: redis.Redis) -> int:
    """Round trips to Redis so far: the commands clients sent (a script is one; the commands
    a script runs inside are not counted)."""
    stats = r.info("commandstats")
    inside = {c.lower() for c in re.findall(r"redis\.call\('([A-Z]+)'", SCRIPT)}
    return sum(
        int(v["calls"]) for k, v in stats.items()
        if k.removeprefix("cmdstat_") not in inside and k != "cmdstat_info"
    )  # fmt: skip


def clear(r: redis.Redis) -> None:
    for cfg in CONFIGS.values():
        prefix = cfg.get("ADVISOR_REDIS_PREFIX")
        if prefix:
            keys = list(r.scan_iter(f"{prefix}:*", count=1000))
            if keys:
                r.delete(*keys)


def held(r: redis.Redis, prefix: str, sid: str) -> tuple[int, int]:
    """Bytes Redis holds for session ``sid``: its state, its kept decisions (both strings)."""

    def size(key: str) -> int:
        return int(r.memory_usage(key, samples=0) or 0)  # type: ignore[arg-type]

    return size(f"{prefix}:s:{sid}"), size(f"{prefix}:r:{sid}") + size(f"{prefix}:r:{sid}:old")


def bench(tmp: Path, seconds: float, repeats: int) -> dict[str, Any]:
    r = redis.Redis.from_url(REDIS_URL)
    clear(r)
    bodies = tmp / "bodies.txt"
    bodies.write_text("\n".join(json.dumps(e) for e in walk(1000, 1)) + "\n")
    frames = [json.dumps(walk(500, seed)) for seed in range(8)]
    servers = {name: start_advisor(tmp, **env) for name, env in CONFIGS.items()}
    runs: dict[str, dict[str, list[float]]] = {name: {} for name in CONFIGS}
    try:
        files, streams = {}, {}
        for name, server in servers.items():
            made = create_sessions(server, CONNECTIONS, tmp)
            files[name] = write_sessions(made, tmp / f"sessions-{server.port}.txt")
            ws = create_sessions(server, 4, tmp)
            streams[name] = [f"{server.ws_url}/sessions/{sid}/stream?token={t}" for sid, t in ws]
        names = list(servers)
        for i in range(repeats):
            # each load on the three services back to back (the ratios compare figures taken
            # seconds apart, not a minute), in the opposite order every other round
            order = names if i % 2 == 0 else names[::-1]
            for name in order:
                server, row = servers[name], runs[name]
                hop = run_wrk(server.url, EVENTS_LUA, [str(files[name]), str(bodies), "0"],
                              seconds, CONNECTIONS, tmp)  # fmt: skip
                if hop.errors:
                    raise RuntimeError(f"{name}: {hop.errors} failed requests")
                row.setdefault("rest_hop", []).append(hop.rate)
            for name in order:
                server, row = servers[name], runs[name]
                cpu, rcpu, calls = tree_cpu(server), redis_cpu(r), redis_calls(r)
                load = children_cpu()
                w = run_wrk(server.url, STICKY_LUA, [str(files[name]), str(bodies)],
                            seconds, CONNECTIONS, tmp, threads=CONNECTIONS)  # fmt: skip
                if w.errors:
                    raise RuntimeError(f"{name}: {w.errors} failed requests")
                row.setdefault("rest", []).append(w.rate)
                row.setdefault("rest_p99", []).append(w.p99_ms)
                row.setdefault("rest_cpu_us", []).append(
                    (tree_cpu(server) - cpu) / w.requests * 1e6
                )
                row.setdefault("rest_redis_us", []).append((redis_cpu(r) - rcpu) / w.requests * 1e6)
                row.setdefault("rest_redis_calls", []).append(
                    (redis_calls(r) - calls - 2) / w.requests
                )
                row.setdefault("rest_wrk_us", []).append((children_cpu() - load) / w.requests * 1e6)
            for name in order:
                server, row = servers[name], runs[name]
                cpu, rcpu, calls = tree_cpu(server), redis_cpu(r), redis_calls(r)
                s = stream_load(streams[name], frames, 500, seconds)
                row.setdefault("ws", []).append(s.rate)
                row.setdefault("ws_cpu_us", []).append((tree_cpu(server) - cpu) / s.events * 1e6)
                row.setdefault("ws_redis_us", []).append((redis_cpu(r) - rcpu) / s.events * 1e6)
                messages = s.events / 500
                row.setdefault("ws_redis_calls", []).append((redis_calls(r) - calls - 2) / messages)
        sizes = {}
        for name, cfg in CONFIGS.items():
            prefix = cfg.get("ADVISOR_REDIS_PREFIX")
            if prefix:  # a websocket session after the load: its state and kept decisions
                sid = streams[name][0].split("/sessions/")[1].split("/")[0]
                rest_sid = files[name].read_text().split()[0]
                state, kept = held(r, prefix, sid)
                rest_state, rest_kept = held(r, prefix, rest_sid)
                sizes[name] = (state, kept, rest_state, rest_kept)
    finally:
        for server in servers.values():
            server.stop()
        clear(r)
    out: dict[str, Any] = {"runs": runs, "sizes": sizes}
    return out


def report(result: dict[str, Any], seconds: float, repeats: int) -> str:
    runs = result["runs"]
    med = {n: {k: statistics.median(v) for k, v in row.items()} for n, row in runs.items()}
    base, one, two = "one process, no Redis", "1 worker, Redis", "2 workers, Redis"
    lines = [
        f"Command: `{command_line()}`  ",
        f"Machine: {machine()}.",
        "",
        f"{repeats} rounds of {seconds:g} s per load, each load measured on the three services "
        "back to back (in the opposite order every other round); medians (all rounds in "
        f"brackets). REST: wrk, {CONNECTIONS} connections, one "
        "event per request, each connection keeping to its own session as an explorer keeps "
        "its connection (with several workers, a connection stays with one worker: its "
        "session's events mostly find their state in that worker); 'hopping': each request "
        "to the next session, so that with two workers half the events reach the worker that "
        "did not make the last one (a load from Redis first). Websocket: 4 sessions, each "
        "sending a 500-event frame and waiting for its answer. Server CPU: the server's "
        "processes (workers included) per event; Redis CPU: what Redis reports it used, per "
        "event; round trips: the commands workers sent Redis per request or frame (a script "
        "is one).",
        "",
        "| service | REST decisions/s | hopping | REST p99 | server CPU / event | "
        "Redis CPU / event | round trips / request | websocket decisions/s | per core | "
        "server CPU / event | Redis CPU / event | round trips / frame |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, m in med.items():
        rest = ", ".join(f"{v:,.0f}" for v in runs[name]["rest"])
        ws = ", ".join(f"{v:,.0f}" for v in runs[name]["ws"])
        lines.append(
            f"| {name} | {m['rest']:,.0f} ({rest}) | {m['rest_hop']:,.0f} | "
            f"{m['rest_p99']:.1f} ms | "
            f"{m['rest_cpu_us']:.0f} us | {m['rest_redis_us']:.1f} us | "
            f"{m['rest_redis_calls']:.2f} | {m['ws']:,.0f} ({ws}) | "
            f"{m['ws'] / CORES[name]:,.0f} | {m['ws_cpu_us']:.2f} us | {m['ws_redis_us']:.2f} us | "
            f"{m['ws_redis_calls']:.2f} |"
        )
    rest_ratio = [b / a for a, b in zip(runs[one]["rest"], runs[two]["rest"], strict=True)]
    c1, c2 = med[one]["rest_cpu_us"], med[two]["rest_cpu_us"]
    load_us = med[two]["rest_wrk_us"] + med[two]["rest_redis_us"]
    bound = 2 * c1 / (c2 + load_us)
    ws_ratio = [b / a for a, b in zip(runs[base]["ws"], runs[one]["ws"], strict=True)]
    ws2_ratio = [b / 2 / a for a, b in zip(runs[base]["ws"], runs[two]["ws"], strict=True)]
    cpu_ratio = med[base]["ws_cpu_us"] / med[one]["ws_cpu_us"]
    lines += [
        "",
        f"- REST, 2 workers against 1 (both with Redis), round by round: "
        f"{', '.join(f'{x:.2f}' for x in rest_ratio)} (median {statistics.median(rest_ratio):.2f}; "
        f"the medians' ratio {med[two]['rest'] / med[one]['rest']:.2f}; target 1.4). What the "
        "CPU figures allow: one worker runs at most 1 / C1 events a second "
        f"(C1 = {c1:.0f} us of its CPU an event); two share the 2 cores with Redis and wrk, so "
        f"at most 2 / (C2 + Redis + wrk) = 2 / ({c2:.0f} + "
        f"{med[two]['rest_redis_us']:.0f} + {med[two]['rest_wrk_us']:.0f}) us: a ratio of about "
        f"{bound:.2f} (an estimate from the medians; single rounds scatter round it).",
        f"- Websocket 500-event frames with durability against the single process without it, "
        f"per core: 1 worker {', '.join(f'{x:.2f}' for x in ws_ratio)} (median "
        f"{statistics.median(ws_ratio):.2f}; the medians' ratio "
        f"{med[one]['ws'] / med[base]['ws']:.2f}; by the server's CPU per event "
        f"{cpu_ratio:.2f}); 2 workers {', '.join(f'{x:.2f}' for x in ws2_ratio)} "
        f"(median {statistics.median(ws2_ratio):.2f}, two workers, Redis and the load generator "
        "on 2 cores); target 0.8.",
    ]
    for name, (state, kept, rest_state, rest_kept) in result["sizes"].items():
        lines.append(
            f"- Bytes in Redis per session ({name}, window 300, Redis' MEMORY USAGE): a "
            f"websocket session {state:,} (its state) + {kept:,} (its last 500 steps' "
            f"decisions); a REST session {rest_state:,} + {rest_kept:,}."
        )
    return "\n".join(lines)


def main() -> None:
    p = arguments(__doc__)
    p.add_argument("--seconds", type=float, default=8.0, help="length of each load (default 8)")
    p.add_argument("--repeats", type=int, default=3, help="rounds of every load (default 3)")
    p.add_argument("--write", type=Path, help="rewrite this doc's workers section")
    args = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        result = bench(Path(tmp), args.seconds, args.repeats)
    text = "## Workers and durable sessions\n\n" + report(result, args.seconds, args.repeats)
    print(text)
    if args.write:
        write_section(args.write, "bench_workers", text)


if __name__ == "__main__":
    main()
