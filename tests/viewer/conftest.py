"""Fixtures for the viewer: a small maze, a prior, and a real viser server on a free port."""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import msgspec
import numpy as np
import pytest
import viser
from viser import _messages
from viser.infra import Message
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect
from websockets.typing import Origin, Subprotocol

from app.advice.advisor import Advisor
from app.advice.models import AdviceTables
from app.domain.building import Building, Domain
from app.domain.floorplans import generate_floors
from app.domain.generate import generate_domain
from app.domain.grid import GridDomain
from app.viewer.state import AdviceGiven, SessionView, Snapshot
from app.viewer.viewer import Viewer


def wait_until(condition: Callable[[], object], timeout: float = 20.0) -> None:
    """Poll ``condition`` until it is truthy; fail after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout}s waiting for {condition}")
        time.sleep(0.05)


def choose(handle: Any, value: object) -> None:
    """Set a GUI input's value from code, as a browser's change arrives (viser's typing gives
    ``value`` no setter for the checker, though it has one)."""
    handle.value = value


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


@pytest.fixture(scope="module")
def domain() -> GridDomain:
    return generate_domain(11, 13, seed=3, braid=0.3, n_goals=3)


@pytest.fixture(scope="module")
def theta(domain: GridDomain) -> np.ndarray:
    rng = np.random.default_rng(0)
    return rng.dirichlet(np.full(4, 0.5), size=domain.n_states)


@pytest.fixture(scope="module")
def tower() -> Building:
    """A generated hospital of two floors (4 m apart), lifts and stairs, named destinations."""
    return generate_floors(20, 20, 2, np.random.default_rng(3), n_goals=3, purpose="hospital",
                           name="tower")  # fmt: skip


@pytest.fixture(scope="module")
def tower_theta(tower: Building) -> np.ndarray:
    rng = np.random.default_rng(0)
    return rng.dirichlet(np.full(6, 0.5), size=tower.n_states)


@pytest.fixture(scope="module")
def server() -> Iterator[viser.ViserServer]:
    srv = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    yield srv
    srv.stop()


class FakeFeed:
    """A feed whose snapshot the test sets."""

    def __init__(self) -> None:
        self.snapshot = Snapshot()
        self.calls = 0

    def __call__(self) -> Snapshot:
        self.calls += 1
        return self.snapshot


@pytest.fixture
def feed() -> FakeFeed:
    return FakeFeed()


class Browser:
    """A program that connects to a viser server as its web client does (the subprotocol
    ``viser-v<version>``) and reads, in a thread, everything the server sends it (counting the
    bytes), so that the server has one more client, as when a browser opens the page."""

    def __init__(self, port: int, origin: str | None = None, max_size: int | None = None):
        protocol = Subprotocol(f"viser-v{viser.__version__}")
        self.socket = connect(
            f"ws://127.0.0.1:{port}", subprotocols=[protocol], max_size=max_size,
            origin=None if origin is None else Origin(origin), open_timeout=20,
        )  # fmt: skip
        self.received = 0
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        # viser makes a client of a connection at its first camera pose, as a page sends it
        self.send(_messages.ViewerCameraMessage(
            wxyz=(1.0, 0.0, 0.0, 0.0), position=(0.0, 0.0, 10.0), fov=1.0, near=0.01, far=1000.0,
            image_height=480, image_width=640, look_at=(0.0, 0.0, 0.0),
            up_direction=(0.0, 1.0, 0.0),
        ))  # fmt: skip

    def send(self, message: Message) -> None:
        """A message as the web client writes it (msgpack of its fields and type)."""
        self.socket.send(msgspec.msgpack.encode(message.as_serializable_dict()))

    def send_raw(self, fields: dict[str, Any]) -> None:
        """A message of any content, as a page could forge it."""
        self.socket.send(msgspec.msgpack.encode(fields))

    def _read(self) -> None:
        with contextlib.suppress(ConnectionClosed, OSError):
            for message in self.socket:
                self.received += len(message)

    def close(self) -> None:
        self.socket.close()
        self._reader.join(timeout=10)


@pytest.fixture
def viewer(feed: FakeFeed) -> Iterator[Viewer]:
    """A viewer with one browser connected (its pump off: tests tick it)."""
    v = Viewer(feed, port=free_port())
    v.start(pump=False)
    browser = Browser(v.port)
    wait_until(lambda: len(v.views) == 1)
    yield v
    browser.close()
    v.stop()


def walk(
    domain: Domain,
    theta: np.ndarray,
    session_id: str,
    steps: int,
    rng: np.random.Generator,
    kappa: float = 0.5,
) -> SessionView:
    """A random walker advised by the core advisor, as the viewer would be told about it
    (on a building it rides too: six actions)."""
    advisor = Advisor(AdviceTables.paper(theta), kappa=kappa)
    s = domain.start
    decision = advisor.start(s)
    path, history, advice = [domain.cell(s)], [decision.p_normal], []
    for _ in range(steps):
        a = int(rng.integers(domain.n_actions))
        s2 = domain.step(s, a)
        decision = advisor.observe(s, a, s2)
        s = s2
        path.append(domain.cell(s))
        history.append(decision.p_normal)
        if decision.advice is not None:
            advice.append(AdviceGiven(decision.step, domain.cell(s), decision.advice))
    return SessionView(
        session_id=session_id,
        domain=domain.name,
        steps=advisor.steps,
        position=domain.cell(s),
        p_normal=decision.p_normal,
        advice_count=advisor.advice_count,
        total_cost=advisor.total_cost,
        kappa=kappa,
        path=path,
        p_normal_history=history,
        advice=advice,
    )
