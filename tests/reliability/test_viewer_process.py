"""The viewer in a process of its own (the issue: it ran inside the API's process, so one
anonymous websocket could take the API's memory: 10 file-upload parts of 16 MiB raised the API's
RSS by 167 MiB, never returned). Over the real ``serve``: the viewer is a child process that
reads the API over HTTP; what a browser sends it is bounded and never reaches the API."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import httpx
import pytest
from websockets.exceptions import ConnectionClosed, InvalidStatus

from tests.client.conftest import free_port
from tests.reliability.conftest import start, stop
from tests.reliability.soak import eventually, rss_mib
from tests.viewer.conftest import Browser

MiB = 1024 * 1024


def children(pid: int) -> list[tuple[int, str]]:
    """(pid, command line) of the processes whose parent is ``pid``."""
    out = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            cmdline = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except OSError:
            continue
        if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
            out.append((int(entry.name), cmdline))
    return out


def test_serve_runs_the_viewer_apart_and_a_browser_cannot_reach_the_api(tmp_path: Path) -> None:
    viewer_port = free_port()
    published = "http://viewer.example:9090"  # a name and port the viewer is reached by
    live = start(tmp_path / "data", viewer_port=viewer_port,
                 ADVISOR_VIEWER_ORIGINS=f'["{published}"]')  # fmt: skip
    try:
        viewers = [p for p, cmd in children(live.pid()) if " app viewer " in cmd]
        assert len(viewers) == 1, children(live.pid())
        viewer = viewers[0]
        assert eventually(lambda: _answers(f"http://127.0.0.1:{viewer_port}/"), 30)
        status = httpx.get(f"{live.url}/viewer").json()
        assert status == {
            "enabled": True, "running": True, "port": viewer_port, "host": "127.0.0.1"
        }  # fmt: skip
        # a page of another site cannot open the viewer's websocket
        with pytest.raises(InvalidStatus) as refused:
            Browser(viewer_port, origin="https://evil.example")
        assert refused.value.response.status_code == 403
        # pages of its own address, and of the origins the settings add, are let in
        for page in (f"http://127.0.0.1:{viewer_port}", published):
            Browser(viewer_port, origin=page).close()
        # 10 messages of 16 MiB: the first closes the connection, none is held anywhere
        api_before, viewer_before = rss_mib(live.pid()), rss_mib(viewer)
        for _ in range(10):
            browser = Browser(viewer_port, max_size=None)
            with pytest.raises((ConnectionClosed, OSError)):
                browser.send_raw({"type": "FileTransferPart", "content": b"x" * (16 * MiB)})
                for _ in range(50):
                    browser.socket.ping().wait(1)
            browser.close()
        api_grew, viewer_grew = rss_mib(live.pid()) - api_before, rss_mib(viewer) - viewer_before
        print(f"\n10 x 16 MiB at the viewer: viewer RSS +{viewer_grew:.1f} MiB, "
              f"API +{api_grew:.1f} MiB")  # fmt: skip
        assert viewer_grew < 24 and api_grew < 4
        assert httpx.get(f"{live.url}/health").status_code == 200
        # the service killed outright: its viewer goes too
        os.kill(live.pid(), signal.SIGKILL)
        live.process.wait(30)
        assert eventually(lambda: not Path(f"/proc/{viewer}").exists(), 30)
    finally:
        stop(live)


def test_a_viewer_that_dies_shows_as_down(tmp_path: Path) -> None:
    """GET /viewer says whether the viewer runs (the pages hide their link when it does not):
    the viewer killed while the service goes on is down at once, its port freed or not."""
    viewer_port = free_port()
    live = start(tmp_path / "data", viewer_port=viewer_port)
    try:
        assert eventually(lambda: httpx.get(f"{live.url}/viewer").json()["running"], 30)
        (viewer,) = [p for p, cmd in children(live.pid()) if " app viewer " in cmd]
        os.kill(viewer, signal.SIGKILL)
        assert eventually(lambda: not httpx.get(f"{live.url}/viewer").json()["running"], 30)
        status = httpx.get(f"{live.url}/viewer").json()
        assert status == {
            "enabled": True, "running": False, "port": viewer_port, "host": "127.0.0.1"
        }  # fmt: skip
        assert httpx.get(f"{live.url}/health").status_code == 200  # the API goes on
    finally:
        stop(live)


def _answers(url: str) -> bool:
    try:
        return httpx.get(url, timeout=5).status_code == 200
    except httpx.HTTPError:
        return False
