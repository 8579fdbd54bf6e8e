"""Two source trees' services side by side, in one run: REST and websocket, interleaved.

Both services run at once (``python -m app serve`` from each tree, one worker each), beside the
bare FastAPI endpoint of ``baseline_app.py``; every round measures each in turn (REST: wrk, one
event per POST; websocket: 500 events a message, JSON and binary answers), so that the machine's
drifting load falls on all of them alike. Each figure is the median of the rounds; ``after /
before`` is the median of the per-round ratios. CPU is the server process's user + system time.

    python benchmarks/service_vs.py --before /tmp/before --label "commit 36317f0" \\
        [--repeats 5] [--seconds 4] [--write docs/PERFORMANCE.md] [--section MARKER]
"""

from __future__ import annotations

import statistics
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.domain.grid import GridDomain  # noqa: E402
from app.domain.maps import DEFAULT_MAP  # noqa: E402
from benchmarks._load import (  # noqa: E402
    EVENTS_LUA,
    Server,
    create_sessions,
    load_average,
    run_wrk,
    start_advisor,
    start_baseline,
    stream_load,
    write_sessions,
)
from benchmarks._report import arguments, machine, write_section  # noqa: E402
from benchmarks.bench_service import FRAME, answer_size, dumps, frames_for, stream_urls, walk  # noqa: E402


def measure(
    tmp: Path, before: Path, repeats: int, seconds: float, conns: int, ws_conns: int
) -> dict[str, list[float]]:
    grid = GridDomain.from_file(DEFAULT_MAP)
    bodies = [dumps(e) for e in walk(grid, np.random.default_rng(1), 1000)]
    bodies_file = tmp / "bodies.txt"
    bodies_file.write_text("\n".join(bodies) + "\n")
    frames = frames_for(grid, 2)
    out: dict[str, list[float]] = {}
    with start_advisor(tmp, ROOT) as after, start_advisor(tmp, before) as old:
        servers = {"after": after, "before": old}
        made = {k: create_sessions(s, 64, tmp) for k, s in servers.items()}
        rest = {k: write_sessions(made[k], tmp / f"rest-{k}.txt") for k in servers}
        ws = {k: stream_urls(s, create_sessions(s, ws_conns, tmp)) for k, s in servers.items()}
        size = answer_size(after, made["after"][0], bodies[:300])
        probe = stream_load(ws["after"][:1], frames, FRAME, 1.0, max_messages=len(frames))
        with start_baseline(tmp, size, probe.answer_bytes) as bare:
            echo = stream_urls(bare, [("x", "x")] * ws_conns, "stream")
            for _ in range(repeats):
                for name, server, sessions in (("after", after, rest["after"]),
                                               ("before", old, rest["before"]),
                                               ("bare", bare, rest["after"])):  # fmt: skip
                    cpu = server.cpu_seconds()
                    r = run_wrk(server.url, EVENTS_LUA, [str(sessions), str(bodies_file), "0"],
                                seconds, conns, tmp)  # fmt: skip
                    if r.errors:
                        raise RuntimeError(f"REST {name}: {r.errors} failed requests")
                    _add(out, f"rest {name}", r.rate, (server.cpu_seconds() - cpu) / r.requests)
                targets: list[tuple[str, Server, list[str]]] = [
                    ("ws json after", after, ws["after"]),
                    ("ws json before", old, ws["before"]),
                    ("ws binary after", after, [f"{u}&format=binary" for u in ws["after"]]),
                    ("ws binary before", old, [f"{u}&format=binary" for u in ws["before"]]),
                    ("ws echo", bare, echo),
                ]
                for name, server, urls in targets:
                    cpu = server.cpu_seconds()
                    s = stream_load(urls, frames, FRAME, seconds)
                    _add(out, name, s.rate, (server.cpu_seconds() - cpu) / s.events)
    return out


def _add(out: dict[str, list[float]], name: str, rate: float, cpu_s: float) -> None:
    out.setdefault(f"{name} rate", []).append(rate)
    out.setdefault(f"{name} cpu_us", []).append(cpu_s * 1e6)


def report(runs: dict[str, list[float]], label: str, loads: list[float], args: Any) -> str:
    med = {k: statistics.median(v) for k, v in runs.items()}

    def per_round(a: str, b: str) -> float:
        return statistics.median(x / y for x, y in zip(runs[a], runs[b], strict=True))

    rows = [("measurement", f"before ({label})", "after", "after / before")]
    for what, key, unit in (
        ("REST, one event per POST (decisions/s)", "rest", "request"),
        (f"websocket, {FRAME} events a message, JSON answers (decisions/s)", "ws json", "decision"),
        (f"websocket, {FRAME} events a message, binary answers (decisions/s)", "ws binary",
         "decision"),
    ):  # fmt: skip
        rows.append((what, f"{med[f'{key} before rate']:,.0f}", f"{med[f'{key} after rate']:,.0f}",
                     f"{per_round(f'{key} after rate', f'{key} before rate'):.2f}"))  # fmt: skip
        cpu = per_round(f"{key} after cpu_us", f"{key} before cpu_us")
        rows.append((f"{what.split(' (')[0]}: server CPU per {unit} (us)",
                     f"{med[f'{key} before cpu_us']:.2f}", f"{med[f'{key} after cpu_us']:.2f}",
                     f"{cpu:.2f}"))  # fmt: skip
    rows.append(("REST ratio service / bare FastAPI (target >= 0.8)",
                 f"{per_round('rest before rate', 'rest bare rate'):.2f}",
                 f"{per_round('rest after rate', 'rest bare rate'):.2f}", ""))  # fmt: skip
    rows.append(("websocket ratio service / echo, binary answers",
                 f"{per_round('ws binary before rate', 'ws echo rate'):.2f}",
                 f"{per_round('ws binary after rate', 'ws echo rate'):.2f}", ""))  # fmt: skip
    table = "\n".join("| " + " | ".join(r) + " |" for r in rows[:1])
    table += "\n|---|---|---|---|\n" + "\n".join("| " + " | ".join(r) + " |" for r in rows[1:])
    command = "python benchmarks/service_vs.py " + " ".join(sys.argv[1:])
    return (
        f"Command: `{command}`\n\nMachine: {machine()}; 1-minute load average "
        f"{min(loads):.1f}-{max(loads):.1f} during the run.\n\n{table}\n\n"
        f"Medians of {args.repeats} rounds of {args.seconds:g} s a figure, every service "
        f"measured in turn in each round (REST: wrk, 1 thread, {args.rest_conns} connections, "
        f"64 sessions; websocket: {args.ws_conns} connections, one session each); after / "
        f"before and the ratios are medians of the per-round ratios.\n"
    )


def main() -> None:
    ap = arguments(__doc__)
    ap.add_argument("--before", type=Path, required=True, help="the older source tree")
    ap.add_argument("--label", default="before", help="what the older tree is")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--seconds", type=float, default=4.0)
    ap.add_argument("--rest-conns", type=int, default=32)
    ap.add_argument("--ws-conns", type=int, default=4)
    ap.add_argument("--write", type=Path, help="rewrite this file's marked section")
    ap.add_argument("--section", default="service_before_after", help="the section's marker")
    args = ap.parse_args()
    loads = [load_average()]
    with tempfile.TemporaryDirectory(prefix="service-vs-") as tmp:
        runs = measure(Path(tmp), args.before.resolve(), args.repeats, args.seconds,
                       args.rest_conns, args.ws_conns)  # fmt: skip
    loads.append(load_average())
    body = report(runs, args.label, loads, args)
    print(body)
    if args.write:
        write_section(args.write, args.section, body)


if __name__ == "__main__":
    main()
