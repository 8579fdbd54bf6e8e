"""What the live viewer costs: one pump tick, the registry lock it takes, and API throughput
with the viewer on and off.

1. In process: a service (its app, through an in-process HTTP client) with ``--sessions`` live
   sessions on the default maze (each with a full recent history); the time of
   ``registry.snapshot`` (its numbers copied under the registry lock), of one feed call (the
   viewer's ``RemoteFeed``: ``GET /viewer/snapshot`` read and shaped), and of one viewer tick
   (a real viser server, one browser-like client) when every session moved since the last tick
   (worst case) and when nothing changed.
2. Out of process: ``python -m app serve`` without the viewer, with it (its own process) and
   nobody watching, and with it watched (a websocket client speaking viser's protocol receives
   every scene update, as a browser would, without a browser's rendering cost); one client
   posts batches of ``--batch`` events round-robin to ``--sessions`` sessions; events per
   second, and the API's CPU per event (the viewer's polls of its snapshot route included).

    .venv/bin/python benchmarks/bench_viewer.py [--repeats 3] [--write docs/PERFORMANCE.md]
"""

from __future__ import annotations

import multiprocessing as mp
import os
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Protocol

import httpx
import msgspec
import numpy as np
import viser
from viser import _messages
from websockets.sync.client import connect
from websockets.typing import Subprotocol

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fastapi.testclient import TestClient

from app.domain.grid import ACTIONS, GridDomain
from app.domain.maps import DEFAULT_MAP
from app.service.config import Settings
from app.service.live.registry import SessionSettings
from app.service.main import create_app
from app.service.state import ServiceState
from app.viewer.remote import RemoteFeed
from app.viewer.viewer import Viewer
from benchmarks._report import arguments, command_line, machine, median_of, write_section

ROOT = Path(__file__).resolve().parents[1]


class EventLike(Protocol):
    def is_set(self) -> bool: ...


class ValueLike(Protocol):
    value: int


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def advance(state: ServiceState, rng: np.random.Generator, steps: int) -> None:
    """Every live session takes ``steps`` random moves."""
    for session in state.registry.sessions():
        grid = session.domain.domain
        a = rng.integers(0, 4, steps)
        s = np.empty(steps + 1, dtype=np.int64)
        s[0] = session.position
        for i in range(steps):
            s[i + 1] = grid.next_state[s[i], a[i]]
        state.registry.observe_batch(session, (s[:-1], a.astype(np.int64), s[1:]))


def timed_ms(fn: Callable[[], object], calls: int) -> float:
    t0 = time.perf_counter()
    for _ in range(calls):
        fn()
    return (time.perf_counter() - t0) / calls * 1e3


def bench_in_process(n_sessions: int, repeats: int) -> dict[str, float]:
    with tempfile.TemporaryDirectory() as tmp:
        settings = Settings(data_dir=Path(tmp), admin_key="bench", viewer_enabled=False)
        with TestClient(create_app(settings)) as client:
            state: ServiceState = client.app.state.service  # type: ignore[attr-defined]
            domain = state.catalog.get("default")
            for _ in range(n_sessions):
                state.registry.create(
                    domain, SessionSettings.of("paper", 0.5, 300, start=domain.domain.start)
                )
            rng = np.random.default_rng(0)
            advance(state, rng, 300)  # full recent path / p_normal / advice history
            feed = RemoteFeed(client, state.operator_key)
            viewer = Viewer(feed, port=free_port())
            viewer.start(pump=False)
            stop, received = mp.Event(), mp.Value("q", 0)
            browser = mp.Process(target=watch, args=(viewer.port, stop, received))
            browser.start()
            try:
                while not viewer.views:
                    time.sleep(0.05)
                viewer.tick()
                out = {
                    "snapshot": median_of(
                        lambda: timed_ms(lambda: state.registry.snapshot(64), 50), repeats
                    )[0],
                    "feed": median_of(lambda: timed_ms(feed, 50), repeats)[0],
                    "idle": median_of(lambda: timed_ms(viewer.tick, 20), repeats)[0],
                }

                def busy() -> float:
                    total = 0.0
                    for _ in range(10):
                        advance(state, rng, 1)
                        t0 = time.perf_counter()
                        viewer.tick()
                        total += time.perf_counter() - t0
                    return total / 10 * 1e3

                out["busy"] = median_of(busy, repeats)[0]
            finally:
                stop.set()
                browser.join()
                viewer.stop()
    return out


def serve(port: int, viewer_port: int, data_dir: Path, viewer: bool) -> subprocess.Popen[bytes]:
    env = os.environ | {"ADVISOR_ADMIN_KEY": "bench", "ADVISOR_VIEWER_PORT": str(viewer_port)}
    cmd = [sys.executable, "-m", "app", "serve", "--port", str(port), "--data-dir",
           str(data_dir), "--log-level", "warning"]  # fmt: skip
    if not viewer:
        cmd.append("--no-viewer")
    proc = subprocess.Popen(
        cmd, cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        try:
            if httpx.get(f"http://127.0.0.1:{port}/health", timeout=1).status_code == 200:
                return proc
        except httpx.HTTPError:
            time.sleep(0.2)
    proc.kill()
    raise RuntimeError("the service did not start")


def load(base: str, n_sessions: int, batch: int, requests: int) -> float:
    """Events per second for ``requests`` posts of ``batch`` events, round-robin."""
    grid = GridDomain.from_file(DEFAULT_MAP)
    rng = np.random.default_rng(1)
    with httpx.Client(base_url=base, timeout=30) as http:
        walkers = []
        for _ in range(n_sessions):
            body = http.post("/domains/default/sessions", json={}).json()
            walkers.append([body["session_id"], {"Authorization": f"Bearer {body['token']}"},
                            grid.start])  # fmt: skip
        bodies = []
        for k in range(requests):
            w = walkers[k % n_sessions]
            events, s = [], w[2]
            for a in rng.integers(0, 4, batch).tolist():
                events.append({"state": list(grid.cell(s)), "action": ACTIONS[a]})
                s = int(grid.next_state[s, a])
            w[2] = s
            bodies.append((w[0], w[1], events))
        t0 = time.perf_counter()
        for sid, auth, events in bodies:
            r = http.post(f"/sessions/{sid}/events", json=events, headers=auth)
            r.raise_for_status()
        return requests * batch / (time.perf_counter() - t0)


def watch(port: int, stop: EventLike, received: ValueLike) -> None:
    """Stay connected to the viewer like a browser tab, draining every message it sends (run in
    its own process, so it does not take the load generator's GIL)."""
    url = f"ws://127.0.0.1:{port}"
    with connect(url, subprotocols=[Subprotocol(f"viser-v{viser.__version__}")],
                 open_timeout=60) as ws:  # fmt: skip
        # viser makes a client of a connection at its first camera pose, as a page sends it
        camera = _messages.ViewerCameraMessage(
            wxyz=(1.0, 0.0, 0.0, 0.0), position=(0.0, 0.0, 10.0), fov=1.0, near=0.01, far=1e3,
            image_height=480, image_width=640, look_at=(0.0, 0.0, 0.0),
            up_direction=(0.0, 1.0, 0.0),
        )  # fmt: skip
        ws.send(msgspec.msgpack.encode(camera.as_serializable_dict()))
        while not stop.is_set():
            try:
                message = ws.recv(timeout=0.2)
            except TimeoutError:
                continue
            received.value += len(message)


MODES = ("off", "on", "watched")


def cpu_seconds(pid: int) -> float:
    """User + system CPU time a process has used so far (Linux /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def bench_api(n_sessions: int, batch: int, requests: int, repeats: int) -> dict[str, float]:
    keys = [k for m in MODES for k in (m, f"{m} cpu")]
    out: dict[str, list[float]] = {k: [] for k in keys}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(repeats):
            for mode in MODES:  # interleaved, so drifting load hits every mode alike
                port, viewer_port = free_port(), free_port()
                proc = serve(port, viewer_port, Path(tmp) / f"{mode}{r}", viewer=mode != "off")
                ctx = mp.get_context("spawn")
                stop, received = ctx.Event(), ctx.Value("q", 0)
                watcher = ctx.Process(target=watch, args=(viewer_port, stop, received))
                if mode == "watched":
                    watcher.start()
                    time.sleep(3)  # the viewer process up, the browser connected
                base = f"http://127.0.0.1:{port}"
                try:
                    cpu = cpu_seconds(proc.pid)
                    out[mode].append(load(base, n_sessions, batch, requests))
                    cpu = cpu_seconds(proc.pid) - cpu
                    out[f"{mode} cpu"].append(cpu / (requests * batch) * 1e6)
                finally:
                    stop.set()
                    if watcher.pid is not None:
                        watcher.join()
                    proc.terminate()
                    proc.wait(timeout=30)
                if mode == "watched" and received.value == 0:
                    raise RuntimeError("the watcher received nothing from the viewer")
    return {k: float(np.median(v)) for k, v in out.items()}


def main() -> None:
    parser = arguments(__doc__)
    parser.add_argument("--sessions", type=int, default=64)
    parser.add_argument("--batch", type=int, default=100)
    parser.add_argument("--requests", type=int, default=1000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--write", type=Path, default=None)
    args = parser.parse_args()
    tick = bench_in_process(args.sessions, args.repeats)
    api = bench_api(args.sessions, args.batch, args.requests, args.repeats)
    n, batch = args.sessions, args.batch
    rows = [
        (f"`registry.snapshot(64)` with {n} live sessions (the numbers copied under "
         "the registry lock, shaped after it; once per tick)", f"{tick['snapshot']:.2f} ms"),
        ("one feed call (`GET /viewer/snapshot` in process, read and shaped as viewer data)",
         f"{tick['feed']:.2f} ms"),
        ("one pump tick, nothing changed", f"{tick['idle']:.2f} ms"),
        (f"one pump tick, all {n} sessions moved since the last tick", f"{tick['busy']:.2f} ms"),
        (f"API CPU per event, `--no-viewer` ({n} sessions, {batch} events per POST)",
         f"{api['off cpu']:.1f} us ({api['off']:,.0f} events/s)"),
        ("API CPU per event, viewer on (its own process), nobody watching, same load",
         f"{api['on cpu']:.1f} us ({api['on']:,.0f} events/s)"),
        ("API CPU per event, viewer on and watched (it reads the snapshot route 10 times a "
         "second), same load",
         f"{api['watched cpu']:.1f} us ({api['watched']:,.0f} events/s)"),
    ]  # fmt: skip
    table = "\n".join(f"| {what} | {value} |" for what, value in rows)
    body = f"""## Live viewer

Command: `{command_line()}` (median of {args.repeats} runs each)

Machine: {machine()}

| measurement | result |
|---|---|
{table}

The viewer runs in a process of its own and reads the API over HTTP: its pump ticks at a fixed
rate whatever the event rate (nothing runs per event), 10 Hz while a browser watches and not at
all when none does, and slower when a tick is so expensive that ticking would take more than
10 % of the time. What it costs the API is one `GET /viewer/snapshot` a tick (and a domain's
map and prior when they change): the API's CPU per event (from /proc) measures that more
steadily than events/s, which swing by 2x on this shared machine.
"""
    print(body)
    if args.write:
        write_section(args.write, "bench_viewer", body)


if __name__ == "__main__":
    main()
