"""Load tools for the service benchmarks: servers as subprocesses on free loopback ports, wrk
(Debian's ``wrk``, Lua scripts below) for HTTP, an asyncio ``websockets`` driver for streams.

Every load is bounded twice: wrk runs for ``-d`` seconds at most (and, for counted loads, stops
each thread after its quota of answers); the websocket driver stops at a deadline or after a
number of messages. Only 127.0.0.1 is ever used.
"""

from __future__ import annotations

import asyncio
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import numpy as np
from websockets.asyncio.client import connect

ROOT = Path(__file__).resolve().parents[1]
HOST = "127.0.0.1"

# ---- wrk scripts -------------------------------------------------------------------------------
# args: sessions file ("id token" lines), bodies file (one JSON text a line), quota (0: none)
EVENTS_LUA = r"""
local sessions, bodies = {}, {}
local i, j, quota, answered, issued = 0, 0, 0, 0, 0
local counter = 0
function setup(thread)
  thread:set("tid", counter)
  counter = counter + 1
end
function init(args)
  for line in io.lines(args[1]) do
    local sid, token = line:match("(%S+) (%S+)")
    sessions[#sessions + 1] = {"/sessions/" .. sid .. "/events", "Bearer " .. token}
  end
  for line in io.lines(args[2]) do bodies[#bodies + 1] = line end
  quota = tonumber(args[3] or "0")
  marker = args[4] or ""
  issued = -1  -- wrk calls request() once before the run, to check it
  i = (tid * 7919) % #sessions
  j = (tid * 104729) % #bodies
end
function request()
  issued = issued + 1
  if quota > 0 and issued > quota then return wrk.format("GET", "/health") end
  i = i % #sessions + 1
  j = j % #bodies + 1
  local s = sessions[i]
  return wrk.format("POST", s[1],
    {["Authorization"] = s[2], ["Content-Type"] = "application/json"}, bodies[j])
end
"""
COUNTED_LUA = r"""
function response(status, headers, body)
  answered = answered + 1
  if quota > 0 and answered == quota then io.open(marker, "w"):close() end
end
"""
# args: output prefix, quota, path, body
CREATE_LUA = r"""
local f, made, quota, path, body, issued = nil, 0, 0, "", "", 0
local counter = 0
function setup(thread)
  thread:set("tid", counter)
  counter = counter + 1
end
function init(args)
  f = io.open(args[1] .. "." .. tid, "w")
  quota, path, body = tonumber(args[2]), args[3], args[4]
  issued = -1  -- wrk calls request() once before the run, to check it
  args_marker = args[1] .. ".done"
end
function request()
  issued = issued + 1
  if issued > quota then return wrk.format("GET", "/health") end  -- exactly quota sessions
  return wrk.format("POST", path, {["Content-Type"] = "application/json"}, body)
end
function response(status, headers, answer)
  if made >= quota then return end
  if status == 201 then
    local sid = answer:match('"session_id":"([^"]+)"')
    local token = answer:match('"token":"([^"]+)"')
    f:write(sid, " ", token, "\n")
    made = made + 1
    if made >= quota then
      f:close()
      io.open(args_marker, "w"):close()
    end
  end
end
"""
DONE_LUA = r"""
function done(summary, latency, requests)
  io.write(string.format('\nRESULT {"requests": %d, "duration_us": %d, "bytes": %d, '
    .. '"p50_us": %d, "p99_us": %d, "max_us": %d, "status_errors": %d, "socket_errors": %d}\n',
    summary.requests, summary.duration, summary.bytes, latency:percentile(50),
    latency:percentile(99), latency.max, summary.errors.status,
    summary.errors.connect + summary.errors.read + summary.errors.write
    + summary.errors.timeout))
end
"""


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind((HOST, 0))
        return int(sock.getsockname()[1])


def wrk_path() -> str:
    path = shutil.which("wrk")
    if path is None:
        raise SystemExit("wrk is not installed: `make bench` installs it (apt-get install wrk)")
    return path


@dataclass
class WrkResult:
    requests: int
    seconds: float
    bytes: int
    p50_ms: float
    p99_ms: float
    max_ms: float
    errors: int

    @property
    def rate(self) -> float:
        return self.requests / self.seconds


def run_wrk(
    url: str, script: str, args: list[str], seconds: float, connections: int, workdir: Path,
    done: Callable[[], bool] | None = None, threads: int = 1,
) -> WrkResult:  # fmt: skip
    """One wrk run (``threads`` threads) of at most ``seconds``, with a Lua ``script``; stopped
    early (SIGINT: wrk then reports as usual) as soon as ``done()`` says so."""
    lua = workdir / f"wrk-{abs(hash(script)) % 10**8}.lua"
    lua.write_text(script + DONE_LUA)
    cmd = [wrk_path(), f"-t{threads}", f"-c{connections}", f"-d{max(1, round(seconds))}s",
           "--latency", "--timeout", "10s", "-s", str(lua), url, "--", *args]  # fmt: skip
    with subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) as proc:
        if done is not None:
            deadline = time.monotonic() + seconds + 5
            while proc.poll() is None and time.monotonic() < deadline:
                if done():
                    proc.send_signal(signal.SIGINT)
                    break
                time.sleep(0.05)
        stdout, stderr = proc.communicate(timeout=seconds + 60)
    if proc.returncode != 0:
        raise RuntimeError(f"wrk failed ({proc.returncode}): {stderr[-2000:]}")
    line = next(x for x in stdout.splitlines() if x.startswith("RESULT "))
    r = json.loads(line[len("RESULT ") :])
    return WrkResult(
        r["requests"], r["duration_us"] / 1e6, r["bytes"], r["p50_us"] / 1e3, r["p99_us"] / 1e3,
        r["max_us"] / 1e3, r["status_errors"] + r["socket_errors"],
    )  # fmt: skip


# ---- servers -----------------------------------------------------------------------------------
@dataclass
class Server:
    """A server subprocess on a free loopback port (its own process group, stopped by pid)."""

    proc: subprocess.Popen[bytes]
    port: int
    log: Path

    @property
    def url(self) -> str:
        return f"http://{HOST}:{self.port}"

    @property
    def ws_url(self) -> str:
        return f"ws://{HOST}:{self.port}"

    def cpu_seconds(self) -> float:
        fields = Path(f"/proc/{self.proc.pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    def rss_bytes(self) -> int:
        for line in Path(f"/proc/{self.proc.pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
        raise RuntimeError("no VmRSS")

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=10)

    def __enter__(self) -> Server:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def _start(cmd: list[str], cwd: Path, env: dict[str, str], log: Path, health: str) -> Server:
    port = int(cmd[cmd.index("--port") + 1])
    with log.open("wb") as out:
        proc = subprocess.Popen(
            cmd, cwd=cwd, env=env, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL
        )
    server = Server(proc, port, log)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"{cmd} exited: {log.read_text()[-2000:]}")
        try:
            if httpx.get(server.url + health, timeout=2).status_code < 500:
                return server
        except httpx.HTTPError:
            time.sleep(0.2)
    server.stop()
    raise RuntimeError(f"{cmd} did not start")


def start_advisor(
    workdir: Path, root: Path = ROOT, max_sessions: int = 20_000, log_level: str = "warning",
    **env: str,
) -> Server:  # fmt: skip
    """``python -m app serve --no-viewer`` from source tree ``root``, on a fresh data dir
    (``log_level`` info: uvicorn's access log on, written to the server's log file)."""
    port = free_port()
    data = workdir / f"data-{port}"
    settings = {  # one client measuring capacity: the per-client quotas as the service's own
        "ADVISOR_ADMIN_KEY": "bench", "ADVISOR_MAX_SESSIONS": str(max_sessions),
        "ADVISOR_CLIENT_MAX_SESSIONS": str(max_sessions),
        "ADVISOR_CLIENT_MAX_SESSION_MEMORY": str(1024 * 1024 * 1024),
    }  # fmt: skip
    cmd = [sys.executable, "-m", "app", "serve", "--no-viewer", "--port", str(port),
           "--data-dir", str(data), "--log-level", log_level]  # fmt: skip
    log = workdir / f"advisor-{port}.log"
    return _start(cmd, root, os.environ | settings | env, log, "/health")


def start_baseline(workdir: Path, answer_bytes: int, frame_answer_bytes: int) -> Server:
    port = free_port()
    cmd = [sys.executable, str(ROOT / "benchmarks" / "baseline_app.py"), "--port", str(port),
           "--answer-bytes", str(answer_bytes), "--frame-answer-bytes", str(frame_answer_bytes),
           "--log-level", "warning"]  # fmt: skip
    return _start(cmd, ROOT, dict(os.environ), workdir / f"baseline-{port}.log", "/docs")


# ---- sessions ----------------------------------------------------------------------------------
def create_sessions(
    server: Server, n: int, workdir: Path, body: dict[str, Any] | None = None,
    domain: str = "default", seconds: float = 300,
) -> list[tuple[str, str]]:  # fmt: skip
    """``n`` new sessions (id, token), created by wrk (16 connections, at most ``seconds``)."""
    prefix = workdir / f"created-{time.monotonic_ns()}"
    marker = Path(f"{prefix}.done")
    args = [str(prefix), str(n), f"/domains/{domain}/sessions", json.dumps(body or {})]
    run_wrk(server.url, CREATE_LUA, args, seconds, min(16, n), workdir, marker.exists)
    lines = [x.split() for f in sorted(workdir.glob(prefix.name + ".[0-9]*")) for x in f.open()]
    made = [(sid, token) for sid, token in lines]
    if len(made) < n:
        raise RuntimeError(f"created {len(made)} of {n} sessions within {seconds} s")
    return made[:n]


def write_sessions(sessions: list[tuple[str, str]], path: Path) -> Path:
    path.write_text("".join(f"{sid} {token}\n" for sid, token in sessions))
    return path


# ---- websocket streams -------------------------------------------------------------------------
@dataclass
class StreamResult:
    events: int
    seconds: float
    latencies: list[float] = field(repr=False)  # per message, seconds
    answer_bytes: int

    @property
    def rate(self) -> float:
        return self.events / self.seconds

    def latency_ms(self, q: float) -> float:
        return float(np.percentile(self.latencies, q) * 1e3) if self.latencies else float("nan")


async def _stream(
    url: str, frames: list[str], per_frame: int, start: asyncio.Barrier, seconds: float,
    max_messages: int, out: StreamResult,
) -> None:  # fmt: skip
    async with connect(url, compression=None, max_size=None, open_timeout=30) as ws:
        await start.wait()  # every connection is open: the clock starts
        deadline = time.perf_counter() + seconds
        k = 0
        while time.perf_counter() < deadline and k < max_messages:
            t0 = time.perf_counter()
            await ws.send(frames[k % len(frames)])
            answer = await ws.recv()
            out.latencies.append(time.perf_counter() - t0)
            out.events += per_frame
            out.answer_bytes = len(answer)
            k += 1


def stream_load(
    urls: list[str], frames: list[str], per_frame: int, seconds: float,
    max_messages: int = 1_000_000,
) -> StreamResult:  # fmt: skip
    """One connection per url, each sending ``frames`` in turn and waiting for each answer,
    until ``seconds`` have passed (or ``max_messages`` per connection)."""

    async def run() -> StreamResult:
        out = StreamResult(0, 0.0, [], 0)
        start = asyncio.Barrier(len(urls) + 1)
        tasks = [
            asyncio.create_task(_stream(u, frames, per_frame, start, seconds, max_messages, out))
            for u in urls
        ]
        await start.wait()
        t0 = time.perf_counter()
        await asyncio.gather(*tasks)
        out.seconds = time.perf_counter() - t0
        return out

    return asyncio.run(run())


def load_average() -> float:
    return os.getloadavg()[0]


# ---- paced explorers and a concurrent writer ---------------------------------------------------
@dataclass
class Paced:
    """Decisions of paced explorers: when each event was sent (time.monotonic) and its
    round-trip latency (seconds)."""

    sent: list[float] = field(default_factory=list)
    latency: list[float] = field(default_factory=list)
    errors: int = 0


async def _explorer(
    url: str, walk: list[str], rate: float, start: asyncio.Barrier, until: asyncio.Event,
    out: Paced,
) -> None:  # fmt: skip
    period = 1.0 / rate
    async with connect(url, compression=None, open_timeout=60) as ws:
        await start.wait()
        # spread the explorers over one period, so that they do not all send at once
        await asyncio.sleep(period * (hash(url) % 1000) / 1000)
        k, next_at = 0, time.monotonic()
        while not until.is_set():
            t0 = time.monotonic()
            await ws.send(walk[k % len(walk)])
            answer = await ws.recv()
            out.sent.append(t0)
            out.latency.append(time.monotonic() - t0)
            if '"detail"' in str(answer)[:20]:
                out.errors += 1
            k += 1
            next_at = max(next_at + period, time.monotonic())  # never burst to catch up
            await asyncio.sleep(next_at - time.monotonic())


async def paced_explorers(
    urls: list[str], walks: list[list[str]], rate: float, until: asyncio.Event
) -> Paced:
    """One explorer per url, each sending its walk's events one per message at ``rate`` per
    second (waiting for each answer) until ``until`` is set."""
    out = Paced()
    start = asyncio.Barrier(len(urls))
    await asyncio.gather(
        *(_explorer(u, w, rate, start, until, out) for u, w in zip(urls, walks, strict=True))
    )
    return out


def post_all(url: str, path: str, key: str, bodies: list[bytes]) -> tuple[float, float, int]:
    """Post ``bodies`` one after the other (in a worker process): (first sent, last answered,
    failures), times from time.monotonic (one clock for every process of the machine)."""
    failures = 0
    headers = {"X-API-Key": key, "Content-Type": "application/json"}
    with httpx.Client(base_url=url, timeout=120) as http:
        t0 = time.monotonic()
        for body in bodies:
            if http.post(path, content=body, headers=headers).status_code != 201:
                failures += 1
        return t0, time.monotonic(), failures
