"""Real service (uvicorn in a thread, temp data dir, free ports), its viewer reading it over
HTTP, and real headless Chromium.

Every page a test opens records console errors and uncaught exceptions; the ``page`` fixture
fails the test if there were any. Screenshots go to ``test-artifacts/`` at the repository root.
"""

from __future__ import annotations

import re
import shutil
import socket
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import pytest
import uvicorn
from fastapi import FastAPI
from playwright.sync_api import Browser, ConsoleMessage, Page, sync_playwright

from app.service.config import Settings
from app.service.main import create_app
from app.service.wire.loops import warm_building
from app.viewer.remote import RemoteFeed
from app.viewer.viewer import Viewer

CHROMIUM = "/usr/bin/chromium"
FLAGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
    "--disable-component-update", "--disable-sync", "--no-first-run",
    "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
]  # fmt: skip
ARTIFACTS = Path(__file__).resolve().parents[2] / "test-artifacts"
ADMIN = "browser-test-admin-key"


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def wait_until(condition: Callable[[], object], timeout: float = 20.0, what: str = "") -> None:
    """Poll ``condition`` until it is truthy; fail naming ``what`` after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout}s waiting for {what or condition}")
        time.sleep(0.05)


@dataclass
class Service:
    app: FastAPI
    base: str
    http: httpx.Client
    viewer: Viewer

    @property
    def operator_key(self) -> str:
        key: str = self.app.state.service.operator_key
        return key

    def new_session(self, moves: str = "", kappa: float = 0.5) -> tuple[str, dict[str, str]]:
        """A session on ``default`` that made ``moves`` (one list of events)."""
        created = self.http.post("/domains/default/sessions", json={"kappa": kappa})
        assert created.status_code == 201, created.text
        body = created.json()
        sid, auth = body["session_id"], {"Authorization": f"Bearer {body['token']}"}
        self.move(sid, auth, body["decision"]["state"], moves)
        return sid, auth

    def move(self, sid: str, auth: dict[str, str], state: list[int], moves: str) -> list[int]:
        for a in moves:
            answer = self.http.post(
                f"/sessions/{sid}/events", json={"state": state, "action": a}, headers=auth
            )
            assert answer.status_code == 200, answer.text
            state = answer.json()["state"]
        return state


@pytest.fixture(scope="package")
def service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Service]:
    """The service and its viewer for the browser tests, stopped after the last of them: the
    viewer reads the service every tick, and in this process those requests would count in
    the metrics and take CPU from every later test. Idle connections are kept open (uvicorn
    closes them after 5 s by default, which raced with a client reusing one: a reset).

    A building's loops are compiled here first (:func:`warm_building`, cached for the
    process): the server compiles them in the first PUT of a building, and the tests put
    buildings with a client that waits 30 s; from a cold cache, with another process busy,
    that PUT outlasted it."""
    warm_building()
    settings = Settings(
        host="127.0.0.1",
        port=free_port(),
        data_dir=tmp_path_factory.mktemp("browser-data"),
        admin_key=ADMIN,
        viewer_enabled=True,
        viewer_port=free_port(),
        overview_seconds=0.0,  # every read sees the events before it
    )
    app = create_app(settings)
    config = uvicorn.Config(
        app, host="127.0.0.1", port=settings.port, log_level="warning", timeout_keep_alive=3600
    )
    server = uvicorn.Server(config)
    thread = threading.Thread(target=server.run, name="uvicorn", daemon=True)
    thread.start()
    # no deadline of ours: the startup compiles the kernels the service runs when numba's
    # cache is cold (80 s measured on a slow day, from a fresh clone); a server that stopped
    # fails at once, and pytest-timeout (setup included) bounds a hang
    while not server.started:
        if not thread.is_alive():
            pytest.fail("uvicorn stopped before it started (its log is above)")
        time.sleep(0.05)
    base = f"http://127.0.0.1:{settings.port}"
    # the viewer as `python -m app viewer` runs it (serve starts that process): reading the
    # service over HTTP with the operator key; here in the test's process, to look inside it
    with httpx.Client(base_url=base, timeout=30.0) as http, \
            httpx.Client(base_url=base, timeout=30.0) as feed_http:  # fmt: skip
        key = app.state.service.operator_key
        viewer = Viewer(RemoteFeed(feed_http, key), port=settings.viewer_port)
        viewer.start()
        yield Service(app, base, http, viewer)
        viewer.stop()
    server.should_exit = True
    thread.join(timeout=30.0)


@pytest.fixture(scope="package")
def browser() -> Iterator[Browser]:
    if shutil.which(CHROMIUM) is None:
        pytest.fail(f"{CHROMIUM} is missing: install Debian's chromium (make chromium)")
    with sync_playwright() as pw:
        chromium = pw.chromium.launch(executable_path=CHROMIUM, args=FLAGS)
        yield chromium
        chromium.close()


@dataclass
class Problems:
    """Console errors and uncaught page errors seen by one page, but for those a test said it
    causes on purpose (:meth:`expect`)."""

    messages: list[str] = field(default_factory=list)
    expected: list[re.Pattern[str]] = field(default_factory=list)
    seen_expected: list[str] = field(default_factory=list)

    def expect(self, pattern: str) -> None:
        """The test causes console errors matching ``pattern`` (say, the browser's own line for
        an answer the test provokes, "the server responded with a status of 403"): they are
        not problems."""
        self.expected.append(re.compile(pattern))

    def console(self, message: ConsoleMessage) -> None:
        if message.type != "error":
            return
        if any(p.search(message.text) for p in self.expected):
            self.seen_expected.append(message.text)
        else:
            self.messages.append(f"console error: {message.text} at {message.location}")

    def page_error(self, error: Exception) -> None:
        self.messages.append(f"uncaught: {error}")


@pytest.fixture
def problems() -> Problems:
    """What the ``page`` fixture fails the test on, for a test to name errors it provokes."""
    return Problems()


@pytest.fixture
def page(browser: Browser, problems: Problems) -> Iterator[Page]:
    context = browser.new_context(viewport={"width": 1280, "height": 860})
    tab = context.new_page()
    tab.set_default_timeout(20_000)
    tab.on("console", problems.console)
    tab.on("pageerror", problems.page_error)
    yield tab
    context.close()
    assert not problems.messages, "\n".join(problems.messages)


def screenshot(page: Page, name: str, full_page: bool = False) -> Path:
    """The page as shown (the whole page, scrolled, with ``full_page``) in
    ``test-artifacts/<name>.png``; ``make screenshots`` copies them into docs/screenshots/."""
    ARTIFACTS.mkdir(exist_ok=True)
    path = ARTIFACTS / f"{re.sub(r'[^A-Za-z0-9_.-]', '_', name)}.png"
    page.screenshot(path=str(path), full_page=full_page)
    return path
