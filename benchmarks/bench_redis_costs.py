"""What a session costs in Redis with workers: the bytes of its state and decision records as a
commit writes them (every strategy, window 300 and 10,000), and the CPU Redis spends on the
commit script of a REST event (its commands and the script around them).

    python benchmarks/bench_redis_costs.py [--seconds 8]

1. In process (no Redis): a session on the shipped maze per strategy and window (with the
   parameters the codec's tests use), fed random walks in 500-event batches until its window
   is full; its state as ``codec.dump`` writes it and as ``codec.packed`` sends it (with the
   time packing takes, median of 20), the last batch's decision record plain and packed, and
   a one-event record.
2. Against the Redis at ``ADVISOR_REDIS_URL`` (default 127.0.0.1:6379; skipped, saying so, when
   it does not answer): one worker, the sticky REST load of ``bench_workers.py``; Redis'
   ``INFO commandstats`` over the measured seconds, per request, its own CPU and the events a
   read of its sockets carries, and a script that returns at once with the same arguments as
   the commit, for the script's fixed cost.
"""

from __future__ import annotations

import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import redis

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.service.config import Settings
from app.service.live.codec import decision_record, dump, packed, packed_record, replay_record
from app.service.live.registry import SessionSettings
from app.service.state import open_state
from app.strategies import STRATEGIES
from benchmarks._load import create_sessions, run_wrk, start_advisor, write_sessions
from benchmarks._report import arguments, machine
from benchmarks.bench_workers import CONNECTIONS, STICKY_LUA, walk
from tests.service.live.test_codec import params_for  # the sessions the codec tests round-trip

REDIS_URL = os.environ.get("ADVISOR_REDIS_URL", "redis://127.0.0.1:6379/0")
PREFIX = "bench-redis-costs"


def sizes() -> list[str]:
    rows = [
        "| strategy | window | state | packed | packing | 500-decision record | packed | "
        "one-event record |",
        "|---|---|---|---|---|---|---|---|",
    ]
    with tempfile.TemporaryDirectory() as tmp:
        state, _ = open_state(Settings(data_dir=Path(tmp), viewer_enabled=False))
        try:
            domain = state.catalog.get("default")
            state.catalog.guide_map(domain)  # goal priors and the guide map
            grid, reg = domain.domain, state.registry
            rng = np.random.default_rng(0)
            for strategy in STRATEGIES:
                for window in (300, 10_000):
                    s, _ = reg.create(
                        domain,
                        SessionSettings.of(strategy, 0.3, window, params_for(strategy)),
                    )
                    here, last = grid.start, None
                    for _ in range(window // 500 + 1):
                        moves = _moves(grid, here, 500, rng)
                        here = int(moves[2][-1])
                        last = reg.observe_batch(s, moves)
                    assert last is not None
                    raw = dump(s, replay=False)
                    times = []
                    for _ in range(20):
                        t0 = time.perf_counter()
                        data = packed(raw)
                        times.append((time.perf_counter() - t0) * 1e6)
                    record = replay_record(last)
                    one = _moves(grid, here, 1, rng)
                    d = reg.observe_one(s, *(int(m[0]) for m in one))
                    single = packed_record(decision_record(d, 0.3, 0, 0.0))
                    rows.append(
                        f"| {strategy} | {window:,} | {len(raw):,} B | {len(data):,} B | "
                        f"{statistics.median(times):.0f} us | {len(record):,} B | "
                        f"{len(packed_record(record)):,} B | {len(single)} B |"
                    )
                    reg.end(s.id)
        finally:
            state.close()
    return rows


def _moves(grid, s: int, n: int, rng: np.random.Generator):  # type: ignore[no-untyped-def]
    states, actions, nexts = [], [], []
    for a in rng.integers(0, 4, n).tolist():
        s2 = int(grid.next_state[s, a])
        states.append(s)
        actions.append(a)
        nexts.append(s2)
        s = s2
    return np.array(states), np.array(actions), np.array(nexts)


def commit_cost(seconds: float) -> list[str]:
    r = redis.Redis.from_url(REDIS_URL)
    try:
        r.ping()
    except redis.RedisError as exc:
        return [f"Redis at {REDIS_URL} does not answer ({exc}): the commit's cost not measured."]
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        server = start_advisor(tmp, ADVISOR_REDIS_URL=REDIS_URL, ADVISOR_REDIS_PREFIX=PREFIX)
        try:
            bodies = tmp / "bodies.txt"
            bodies.write_text("\n".join(json.dumps(e) for e in walk(1000, 1)) + "\n")
            made = write_sessions(create_sessions(server, CONNECTIONS, tmp), tmp / "s.txt")
            load = [str(made), str(bodies)]
            run_wrk(server.url, STICKY_LUA, load, 2, CONNECTIONS, tmp, threads=CONNECTIONS)
            r.config_resetstat()
            cpu0 = _cpu(r)
            w = run_wrk(server.url, STICKY_LUA, load, seconds, CONNECTIONS, tmp,
                        threads=CONNECTIONS)  # fmt: skip
            cpu = _cpu(r) - cpu0
            stats, io = r.info("commandstats"), r.info("stats")
        finally:
            server.stop()
            for key in r.scan_iter(f"{PREFIX}*"):
                r.delete(key)
    rows = [
        f"{w.requests:,} REST events, one worker, {seconds:g} s; Redis' `INFO commandstats`:",
        "",
        "| command | calls / event | us / call | us / event |",
        "|---|---|---|---|",
    ]
    for name, v in sorted(stats.items(), key=lambda kv: -kv[1]["usec"]):
        if v["calls"] >= w.requests / 2:
            rows.append(
                f"| {name.removeprefix('cmdstat_')} | {v['calls'] / w.requests:.2f} | "
                f"{v['usec_per_call']:.2f} | {v['usec'] / w.requests:.2f} |"
            )
    n = w.requests
    rows += [
        "",
        f"Redis in all: {cpu * 1e6 / n:.1f} us of CPU an event; "
        f"{io['total_reads_processed'] / n:.2f} reads and "
        f"{io['total_writes_processed'] / n:.2f} writes of its sockets an event "
        f"({n / max(io['total_reads_processed'], 1):.2f} events a read).",
    ]
    sha = r.script_load("return 1")
    blob, record = os.urandom(2200), os.urandom(90)
    r.config_resetstat()
    for _ in range(5000):
        r.evalsha(sha, 0, PREFIX, "commit", "sid", "1", "2", blob, record, 1, 3,
                  1_700_000_000_000, 500, "default|1|1|0|0.5", 3_600_000)  # fmt: skip
    empty = r.info("commandstats")["cmdstat_evalsha"]["usec_per_call"]
    rows += ["", f"A script that returns at once, with the commit's arguments: {empty:.1f} us."]
    return rows


def _cpu(r: redis.Redis) -> float:
    """Seconds of CPU the Redis server has used (user and system, its main thread)."""
    info = r.info("cpu")
    return float(info["used_cpu_user_main_thread"]) + float(info["used_cpu_sys_main_thread"])


def main() -> None:
    ap = arguments(__doc__)
    ap.add_argument("--seconds", type=float, default=8.0, help="length of the REST load")
    args = ap.parse_args()
    print(f"{machine()}\n")
    print("\n".join(sizes()) + "\n")
    print("\n".join(commit_cost(args.seconds)))


if __name__ == "__main__":
    main()
