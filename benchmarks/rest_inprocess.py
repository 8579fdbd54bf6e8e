"""One event per POST, in process: the service's ASGI app and the bare endpoint of
``baseline_app.py`` called directly (no server, no socket), thread CPU time per request.

What the service adds on top of the framework for one event, without the noise of a load
generator sharing the cores; ``bench_service.py`` measures the same through uvicorn and wrk.
Requests go round 64 sessions; runs of 2,000 requests alternate between the two apps and the
figure is the first quartile of each app's runs.

    .venv/bin/python benchmarks/rest_inprocess.py [--runs 12] [--root DIR]

``--root DIR`` takes the service from another source tree (e.g. an older commit unpacked with
``git archive``), for before/after figures.
"""

from __future__ import annotations

import asyncio
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parents[1]


async def drive(app: Any, targets: list[tuple[bytes, list[tuple[bytes, bytes]]]], body: bytes,
                n: int) -> float:  # fmt: skip
    """Microseconds of thread CPU per request for ``n`` POSTs of ``body`` to ``targets``."""

    async def receive() -> dict[str, Any]:
        return {"type": "http.request", "body": body, "more_body": False}

    async def send(message: dict[str, Any]) -> None:
        if message["type"] == "http.response.start" and message["status"] != 200:
            raise RuntimeError(f"status {message['status']}")

    t0 = time.thread_time()
    for i in range(n):
        path, headers = targets[i % len(targets)]
        scope = {
            "type": "http", "asgi": {"version": "3.0"}, "http_version": "1.1",
            "method": "POST", "scheme": "http", "path": path.decode(), "raw_path": path,
            "query_string": b"", "root_path": "", "headers": headers,
            "client": ("127.0.0.1", 1), "server": ("127.0.0.1", 8000), "state": {},
        }  # fmt: skip
        await app(scope, receive, send)
    return (time.thread_time() - t0) / n * 1e6


async def run(runs: int) -> tuple[float, float]:
    from app.service.config import Settings
    from app.service.main import create_app
    from app.service.schemas import SessionCreate

    sys.path.insert(0, str(HERE))  # the baseline is always this tree's
    from benchmarks.baseline_app import create_baseline

    with tempfile.TemporaryDirectory() as tmp:
        app = create_app(Settings(data_dir=Path(tmp), viewer_enabled=False))
        async with app.router.lifespan_context(app):
            from app.service import ops

            state = app.state.service
            domain = state.catalog.get("default")
            body = json.dumps({"state": list(domain.domain.cell(domain.domain.start)),
                               "action": "E"}).encode()  # fmt: skip
            targets = []
            for _ in range(64):
                session, _ = asyncio.run(ops.open_session(state, domain, SessionCreate()))
                headers = [(b"authorization", f"Bearer {session.token}".encode()),
                           (b"content-type", b"application/json"),
                           (b"content-length", str(len(body)).encode())]  # fmt: skip
                targets.append((f"/sessions/{session.id}/events".encode(), headers))
            bare = create_baseline(280)
            await drive(app, targets, body, 500)
            await drive(bare, targets, body, 500)
            service_us, bare_us = [], []
            for _ in range(runs):
                service_us.append(await drive(app, targets, body, 2000))
                bare_us.append(await drive(bare, targets, body, 2000))
    q = runs // 4
    return sorted(service_us)[q], sorted(bare_us)[q]


def main() -> None:
    sys.path.insert(0, str(HERE))  # this tree's benchmarks (--root's app goes before it)
    from benchmarks._report import arguments

    ap = arguments(__doc__)
    ap.add_argument("--runs", type=int, default=12)
    ap.add_argument("--root", type=Path, default=HERE, help="source tree of the service")
    args = ap.parse_args()
    sys.path.insert(0, str(args.root.resolve()))
    service, bare = asyncio.run(run(args.runs))
    print(f"service {service:.1f} us, bare {bare:.1f} us a request: the service adds "
          f"{service - bare:.1f} us (root {args.root})")  # fmt: skip


if __name__ == "__main__":
    main()
