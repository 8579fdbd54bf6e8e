"""A real server: ``python -m app serve`` (uvicorn) on a free port with a temporary data dir."""

from __future__ import annotations

import contextlib
import os
import socket
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx
import pytest

from tests.conftest import service_kernels_compiled

REPO = Path(__file__).resolve().parents[2]


@dataclass
class Server:
    url: str
    admin_key: str
    data_dir: Path
    process: subprocess.Popen[str]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def start_server(data_dir: Path, timeout: float = 60.0) -> Server:
    """Start the service and wait until /health answers (or fail with its output)."""
    service_kernels_compiled()  # not on the clock below
    port = free_port()
    env = os.environ | {"ADVISOR_BOOTSTRAP_PER_GOAL": "2", "ADVISOR_SWEEP_SECONDS": "3600"}
    cmd = [sys.executable, "-m", "app", "serve", "--port", str(port), "--data-dir", str(data_dir),
           "--no-viewer", "--log-level", "warning"]  # fmt: skip
    proc = subprocess.Popen(
        cmd, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    url = f"http://127.0.0.1:{port}"
    with httpx.Client(timeout=2.0) as http:
        for _ in range(int(timeout / 0.1)):
            if proc.poll() is not None:
                raise RuntimeError(
                    f"server exited {proc.returncode}: {proc.stderr.read() if proc.stderr else ''}"
                )
            try:
                if http.get(f"{url}/health").status_code == 200:
                    break
            except httpx.TransportError:
                pass
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(0.1)
        else:
            proc.kill()
            raise RuntimeError(f"server at {url} did not answer /health")
    key = (data_dir / "admin_key").read_text().strip()
    return Server(url, key, data_dir, proc)


def stop_server(server: Server) -> tuple[str, str]:
    server.process.terminate()
    out, err = server.process.communicate(timeout=30)
    return out, err


@pytest.fixture(scope="session")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    srv = start_server(tmp_path_factory.mktemp("data"))
    yield srv
    stop_server(srv)
