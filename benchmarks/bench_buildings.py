"""Big buildings: the viewer's tick on a 256 x 256 map, guide's websocket batches against the
paper's rule, the API's latency meanwhile, and the buildings experiment's time.

1. In process: a generated 256 x 256 building with ``--sessions`` live guide sessions (each
   with a full recent history), a real viser server (no browser): the tick that builds the
   scene, then idle ticks and busy ticks (every session moved since the last one).
2. Out of process (``python -m app serve``): the same building PUT with simulated experts;
   one paper and one guide session; 500-event websocket messages sent to each in turn (one in
   flight), decisions per second, while another client reads ``/health`` (its latency).
3. ``python -m app experiment buildings`` with ``--maps-dir``'s map files (if any) besides the
   generated buildings: its wall-clock time (the target: under 15 minutes here).

    .venv/bin/python benchmarks/bench_buildings.py [--maps-dir DIR] [--write docs/PERFORMANCE.md]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np
from fastapi.testclient import TestClient
from websockets.sync.client import connect

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.domain.generate import generate_building_domain
from app.domain.grid import ACTIONS, GridDomain
from app.service.config import Settings
from app.service.live.registry import SessionSettings
from app.service.main import create_app
from app.service.state import ServiceState
from app.viewer.remote import RemoteFeed
from app.viewer.viewer import Viewer
from benchmarks._report import arguments, command_line, machine, write_section
from benchmarks.bench_viewer import advance, free_port, serve, watch

ROOT = Path(__file__).resolve().parents[1]
FRAME = 500
SIDE = 256


def walk(grid: GridDomain, rng: np.random.Generator, s: int, n: int) -> tuple[list[Any], int]:
    events = []
    for a in rng.integers(0, 4, n).tolist():
        events.append({"state": list(grid.cell(s)), "action": ACTIONS[a]})
        s = int(grid.next_state[s, a])
    return events, s


def bench_viewer(grid: GridDomain, n_sessions: int, ticks: int) -> dict[str, float]:
    """The viewer as ``serve`` runs it (its feed reading the API with the operator key), one
    browser watching (a websocket client in its own process) with the building picked."""
    with tempfile.TemporaryDirectory() as tmp:
        settings = Settings(data_dir=Path(tmp), admin_key="bench", viewer_enabled=False)
        with TestClient(create_app(settings)) as client:
            state: ServiceState = client.app.state.service  # type: ignore[attr-defined]
            domain, _, _ = state.catalog.put("hall", grid, 1.0)
            t0 = time.perf_counter()
            state.catalog.guide_map(domain)
            guide_ms = (time.perf_counter() - t0) * 1e3
            for _ in range(n_sessions):
                state.registry.create(domain, SessionSettings.of("guide"))
            rng = np.random.default_rng(0)
            advance(state, rng, 300)
            viewer = Viewer(RemoteFeed(client, state.operator_key), port=free_port())
            viewer.start(pump=False)
            stop, received = mp.Event(), mp.Value("q", 0)
            browser = mp.Process(target=watch, args=(viewer.port, stop, received))
            browser.start()
            try:
                while not viewer.views:
                    time.sleep(0.05)
                viewer.tick()
                for view in list(viewer.views.values()):
                    view.controls.domain.value = "hall"  # type: ignore[misc]  # no setter typed
                t0 = time.perf_counter()
                viewer.tick()  # builds the 256 x 256 scene
                first = (time.perf_counter() - t0) * 1e3
                idle, busy = [], []
                for _ in range(ticks):
                    t0 = time.perf_counter()
                    viewer.tick()
                    idle.append((time.perf_counter() - t0) * 1e3)
                    advance(state, rng, 1)
                    t0 = time.perf_counter()
                    viewer.tick()
                    busy.append((time.perf_counter() - t0) * 1e3)
            finally:
                stop.set()
                browser.join()
                viewer.stop()
    return {
        "guide_map_ms": guide_ms, "first_tick_ms": first,
        "idle_tick_ms": statistics.median(idle), "busy_tick_ms": statistics.median(busy),
        "busy_tick_max_ms": max(busy),
    }  # fmt: skip


def bench_ws(grid: GridDomain, rounds: int) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as tmp:
        port = free_port()
        proc = serve(port, free_port(), Path(tmp), viewer=False)
        base = f"http://127.0.0.1:{port}"
        try:
            with httpx.Client(base_url=base, timeout=120) as http:
                body = {"map": grid.to_text().splitlines(), "experts": {"per_goal": 3}}
                t0 = time.perf_counter()
                r = http.put("/domains/hall", json=body, headers={"X-API-Key": "bench"})
                r.raise_for_status()
                put_s = time.perf_counter() - t0
                urls = {}
                for strategy in ("paper", "guide"):
                    c = http.post("/domains/hall/sessions", json={"strategy": strategy}).json()
                    urls[strategy] = f"ws://127.0.0.1:{port}/sessions/{c['session_id']}/stream"
                    urls[strategy] += f"?token={c['token']}"
            rng = np.random.default_rng(1)
            frames: dict[str, list[str]] = {k: [] for k in urls}
            for k in urls:
                s = grid.start
                for _ in range(rounds + 1):
                    events, s = walk(grid, rng, s, FRAME)
                    frames[k].append(json.dumps(events))
            latency: list[float] = []
            stop = threading.Event()

            def health() -> None:
                with httpx.Client(base_url=base, timeout=30) as h:
                    while not stop.is_set():
                        t0 = time.perf_counter()
                        h.get("/health").raise_for_status()
                        latency.append((time.perf_counter() - t0) * 1e3)
                        time.sleep(0.02)

            prober = threading.Thread(target=health, daemon=True)
            rates: dict[str, list[float]] = {k: [] for k in urls}
            sockets = {k: connect(u, max_size=2**24) for k, u in urls.items()}
            try:
                for k, ws in sockets.items():  # warm up: the first message compiles nothing
                    ws.send(frames[k][0])  # in the timed rounds (numba's cache, first use)
                    ws.recv()
                prober.start()
                for i in range(rounds):  # alternating, so drifting load hits both alike
                    for k, ws in sockets.items():
                        t0 = time.perf_counter()
                        ws.send(frames[k][i + 1])
                        answer = json.loads(ws.recv())
                        rates[k].append(FRAME / (time.perf_counter() - t0))
                        assert len(answer) == FRAME
            finally:
                stop.set()
                for ws in sockets.values():
                    ws.close()
                prober.join(timeout=5)
        finally:
            proc.terminate()
            proc.wait(timeout=30)
    paper, guide = statistics.median(rates["paper"]), statistics.median(rates["guide"])
    ratios = [g / p for g, p in zip(rates["guide"], rates["paper"], strict=True)]
    return {
        "put_with_experts_s": put_s, "paper_per_s": paper, "guide_per_s": guide,
        "ratio_median": statistics.median(ratios), "ratio_min": min(ratios),
        # nan: no probe finished while so few rounds ran (--rounds)
        "health_p50_ms": statistics.median(latency) if latency else float("nan"),
        "health_p99_ms": float(np.percentile(latency, 99)) if latency else float("nan"),
        "health_probes": len(latency),
    }  # fmt: skip


def bench_experiment(maps_dir: Path | None, keep: Path | None) -> dict[str, Any]:
    files = sorted(maps_dir.resolve().glob("*.txt")) if maps_dir else []
    cmd = [sys.executable, "-m", "app", "experiment", "buildings", "--no-progress"]
    for f in files:
        cmd += ["--mazes", str(f)]
    with tempfile.TemporaryDirectory() as tmp:
        where = keep.resolve() if keep else Path(tmp)
        where.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        # this tree's app, not whichever one the environment has installed (cwd is elsewhere)
        env = os.environ | {"PYTHONPATH": str(ROOT)}
        subprocess.run(cmd, cwd=where, env=env, check=True, stdout=subprocess.DEVNULL)
        took = time.perf_counter() - t0
    return {"seconds": took, "files": [f.stem for f in files]}


def report(args: argparse.Namespace, v: dict[str, float], w: dict[str, Any],
           e: dict[str, Any] | None) -> str:  # fmt: skip
    lines = [
        "### Big buildings: the viewer at 256 x 256, guide's websocket batches", "",
        f"`{command_line()}` on {machine()}.", "",
        "| measure | value | target |", "|---|---|---|",
        f"| guide map of the 256 x 256 building (BFS from 8 destinations, 8 landmarks) | "
        f"{v['guide_map_ms']:.0f} ms | |",
        f"| viewer: tick that builds the 256 x 256 scene | {v['first_tick_ms']:.0f} ms | |",
        f"| viewer: idle tick, {args.sessions} guide sessions | {v['idle_tick_ms']:.1f} ms | "
        "< 50 ms |",
        f"| viewer: busy tick (every session moved), median / max | "
        f"{v['busy_tick_ms']:.1f} / {v['busy_tick_max_ms']:.1f} ms | < 50 ms |",
        f"| PUT of the 256 x 256 map with experts (3 per destination) | "
        f"{w['put_with_experts_s']:.1f} s | |",
        f"| websocket, {FRAME}-event messages, paper | {w['paper_per_s']:,.0f} decisions/s | |",
        f"| websocket, {FRAME}-event messages, guide | {w['guide_per_s']:,.0f} decisions/s | |",
        f"| guide / paper (median of per-round ratios; min) | {w['ratio_median']:.2f} "
        f"({w['ratio_min']:.2f}) | >= 0.5 |",
        f"| /health meanwhile, p50 / p99 ({w['health_probes']} probes) | "
        f"{w['health_p50_ms']:.1f} / {w['health_p99_ms']:.1f} ms | |",
    ]  # fmt: skip
    if e is not None:
        maps = ", ".join(e["files"]) or "none"
        lines.append(
            f"| `experiment buildings` (4 generated buildings + files: {maps}), defaults | "
            f"{e['seconds'] / 60:.1f} min | < 15 min |"
        )
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = arguments(__doc__)
    ap.add_argument("--sessions", type=int, default=50, help="guide sessions on the map")
    ap.add_argument("--ticks", type=int, default=20, help="viewer ticks measured")
    ap.add_argument("--rounds", type=int, default=30, help="websocket messages per strategy")
    ap.add_argument("--maps-dir", type=Path, default=None,
                    help="map files (*.txt) for the experiment's suite")  # fmt: skip
    ap.add_argument("--no-experiment", action="store_true", help="skip part 3")
    ap.add_argument(
        "--keep",
        type=Path,
        default=None,
        help="run the experiment here and keep its results/ (default: a temp dir)",
    )
    ap.add_argument("--only-experiment", action="store_true", help="part 3 only")
    ap.add_argument("--write", type=Path, default=None, help="docs file to rewrite a section of")
    args = ap.parse_args()
    e = None if args.no_experiment else bench_experiment(args.maps_dir, args.keep)
    if e:
        print(json.dumps(e, indent=1))
    if args.only_experiment:
        return
    grid = generate_building_domain(SIDE, SIDE, 3)
    v = bench_viewer(grid, args.sessions, args.ticks)
    print(json.dumps(v, indent=1))
    w = bench_ws(grid, args.rounds)
    print(json.dumps(w, indent=1))
    text = report(args, v, w, e)
    print(text)
    if args.write:
        write_section(args.write, "bench-buildings", text)


if __name__ == "__main__":
    main()
