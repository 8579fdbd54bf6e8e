"""GET /viewer says whether the viewer ``serve`` started is alive: from its process (one
worker holds it) or its process id (workers read it from their environment)."""

from __future__ import annotations

import subprocess
import sys

from app.service.routes.viewer import viewer_running


def sleeper() -> subprocess.Popen[bytes]:
    return subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])


def test_the_viewer_process_alive_then_dead() -> None:
    process = sleeper()
    try:
        assert viewer_running(process, None)
    finally:
        process.kill()
        process.wait(10)
    assert not viewer_running(process, None)


def test_the_viewer_pid_alive_then_reaped() -> None:
    process = sleeper()
    pid = str(process.pid)
    try:
        assert viewer_running(None, pid)
    finally:
        process.kill()
        process.wait(10)  # serve reaps it (a thread waits on it)
    assert not viewer_running(None, pid)


def test_a_viewer_this_service_did_not_start_is_taken_as_running() -> None:
    assert viewer_running(None, None)
    assert viewer_running(None, "not a pid")
