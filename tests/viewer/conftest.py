"""Fixtures for the viewer: a small maze, a prior, and a real viser server on a free port."""

from __future__ import annotations

import socket
import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest
import viser

from app.advice.advisor import Advisor
from app.advice.models import AdviceTables
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


@pytest.fixture
def viewer(feed: FakeFeed) -> Iterator[Viewer]:
    v = Viewer(feed, port=free_port())
    v.start(pump=False)
    yield v
    v.stop()


def walk(
    domain: GridDomain,
    theta: np.ndarray,
    session_id: str,
    steps: int,
    rng: np.random.Generator,
    kappa: float = 0.5,
) -> SessionView:
    """A random walker advised by the core advisor, as the viewer would be told about it."""
    advisor = Advisor(AdviceTables.paper(theta), kappa=kappa)
    s = domain.start
    decision = advisor.start(s)
    path, history, advice = [domain.cell(s)], [decision.p_normal], []
    for _ in range(steps):
        a = int(rng.integers(4))
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
