"""A real server per test module: ``python -m app serve`` (uvicorn) on a free loopback port,
a temporary data dir, extra ``ADVISOR_*`` settings from the environment."""

from __future__ import annotations

import contextlib
import dataclasses
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx
import pytest

from tests.client.conftest import free_port
from tests.conftest import service_kernels_compiled
from tests.service.conftest import db_url  # noqa: F401  (the fixture: SQLite or PostgreSQL)

REPO = Path(__file__).resolve().parents[2]


@dataclass
class Live:
    """A running ``python -m app serve`` process."""

    url: str
    port: int
    admin_key: str
    data_dir: Path
    process: subprocess.Popen[bytes]
    log: Path

    @property
    def admin(self) -> dict[str, str]:
        return {"X-API-Key": self.admin_key}

    def pid(self) -> int:
        return self.process.pid


def start(
    data_dir: Path, port: int | None = None, timeout: float = 60.0, log_level: str = "warning",
    viewer_port: int | None = None, preexec_fn: Callable[[], None] | None = None, **env: str,
) -> Live:  # fmt: skip
    """Start the service on 127.0.0.1 and wait until ``/health`` answers (or fail, showing its
    log). ``env``: extra settings, e.g. ``ADVISOR_MAX_SESSIONS="5"``; ``log_level`` "info"
    writes uvicorn's access log too; ``viewer_port``: with its viewer there (else none);
    ``preexec_fn``: run in the server's process before it starts (e.g. to lower a limit)."""
    service_kernels_compiled()  # not on the clock below
    port = port or free_port()
    data_dir.mkdir(parents=True, exist_ok=True)
    log = data_dir.parent / f"server-{port}.log"
    environ = os.environ | {"ADVISOR_BOOTSTRAP_PER_GOAL": "2"} | env
    cmd = [sys.executable, "-m", "app", "serve", "--host", "127.0.0.1", "--port", str(port),
           "--data-dir", str(data_dir), "--log-level", log_level]  # fmt: skip
    if viewer_port is None:
        cmd.append("--no-viewer")
    else:
        environ = environ | {"ADVISOR_VIEWER_PORT": str(viewer_port)}
    with log.open("ab") as out:
        proc = subprocess.Popen(
            cmd, cwd=REPO, env=environ, stdout=out, stderr=out, preexec_fn=preexec_fn
        )
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + timeout
    with httpx.Client(timeout=2.0) as http:
        while True:
            if proc.poll() is not None:
                raise RuntimeError(f"server exited {proc.returncode}: {log.read_text()[-2000:]}")
            with contextlib.suppress(httpx.TransportError):
                if http.get(f"{url}/health").status_code == 200:
                    break
            if time.monotonic() > deadline:
                proc.kill()
                proc.wait(10)
                raise RuntimeError(f"server at {url} did not answer /health: {log.read_text()}")
            time.sleep(0.05)
    configured = environ.get("ADVISOR_ADMIN_KEY")
    key = configured or (data_dir / "admin_key").read_text().strip()
    return Live(url, port, key, data_dir, proc, log)


def stop(live: Live, sig: int = signal.SIGTERM) -> int:
    """Stop the server (SIGTERM: a clean shutdown; SIGKILL: a crash); its exit code."""
    if live.process.poll() is None:
        live.process.send_signal(sig)
    return live.process.wait(30)


def server_errors(live: Live) -> list[str]:
    """Tracebacks the server logged (uvicorn logs every unhandled exception)."""
    text = live.log.read_text(errors="replace")
    return [line for line in text.splitlines() if "Exception in ASGI application" in line]


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    """One server for the module, stopped (cleanly) after it."""
    server = start(tmp_path_factory.mktemp("live") / "data")
    yield server
    stop(server)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """schemathesis gives every operation's test the same node id; each gets its operation in
    brackets, so that reports name it and pytest-xdist, which schedules a file's tests by node
    id (``--dist loadfile``), runs every one (with one id it ran one of them, and
    ``test_every_operation_was_fuzzed`` failed). pytest 9.2 keeps the id as a ``NodeId``
    (``_id``), earlier versions as a string (``_nodeid``)."""
    for item in items:
        label = getattr(item, "operation_label", None)
        if label is None or item.nodeid.endswith("]"):
            continue
        ident = getattr(item, "_id", None)
        if ident is not None and hasattr(ident, "params"):
            item._id = dataclasses.replace(ident, params=label)
        else:
            item._nodeid = f"{item.nodeid}[{label}]"  # type: ignore[attr-defined]
