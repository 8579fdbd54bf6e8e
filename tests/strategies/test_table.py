"""A strategy is one entry of the table: a toy registered here (a readable advisor, no compiled
form) is served over REST, listed by ``GET /strategies``, kept through the codec like the
others, and runs in an experiment through the readable loop."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app import strategies
from app.advice.advisor import Advisor, Decision
from app.advice.params import StrategyParams
from app.domain.grid import N_ACTIONS
from app.experiments import strategies as strategies_experiment
from app.experiments import strategy_suite
from app.experiments.output import RunDir
from app.service.live.codec import dump, load
from app.service.live.registry import Limits, SessionRegistry, SessionSettings
from app.service.state import ServiceState
from app.strategies import AdvisorSettings, DomainData, Level, Strategy
from tests.service.conftest import open_session
from tests.service.test_decisions_property import core_tables, expected_json


class QuietAdvisor(Advisor):
    """The paper's posterior; advises theta_s only while P(M1 | H) is below ``threshold``."""

    strategy: ClassVar[str] = "quiet"
    __slots__ = ("threshold",)

    def __init__(self, tables: object, kappa: float, window: int, threshold: float):
        self.threshold = threshold
        super().__init__(tables, kappa, window)  # type: ignore[arg-type]

    def params(self) -> dict[str, int | float]:
        return {"threshold": self.threshold}

    def decide(self, state: int) -> Decision:
        kl, p_normal = self.divergence(state)
        th = self.tables.theta_flat
        row = tuple(th[state * N_ACTIONS + a] for a in range(N_ACTIONS))
        return self.record(state, p_normal < self.threshold, row, kl, p_normal)


def _quiet(data: DomainData, s: AdvisorSettings) -> Advisor:
    return QuietAdvisor(data.tables, s.kappa, s.window, s.params.threshold)


QUIET = Strategy(
    "quiet", "Advise theta_s while the explorer looks lost, P(M1|H) < threshold.",
    readable=_quiet, reads=("threshold",), level=Level("threshold", (0.3, 0.6)),
)  # fmt: skip


@pytest.fixture
def quiet() -> Iterator[Strategy]:
    strategies.register(QUIET)
    try:
        yield QUIET
    finally:
        strategies.unregister(QUIET.name)


def test_a_name_is_registered_once(quiet: Strategy) -> None:
    with pytest.raises(ValueError, match="registered already"):
        strategies.register(QUIET)


def test_a_registered_strategy_is_served_over_rest_per_event(
    quiet: Strategy, client: TestClient, service: ServiceState
) -> None:
    listed = {s["name"]: s for s in client.get("/strategies").json()}
    assert listed["quiet"]["compiled"] is False and listed["paper"]["compiled"] is True
    assert [p["name"] for p in listed["quiet"]["params"]] == ["threshold"]
    enum = client.get("/openapi.json").json()["components"]["schemas"]["SessionCreate"]
    assert "quiet" in enum["properties"]["strategy"]["enum"]
    r = client.post("/domains/default/sessions", json={"strategy": "quiet", "params": {"rate": 1}})
    assert r.status_code == 422 and "quiet does not read rate" in r.text
    sid, auth, created = open_session(
        client, strategy="quiet", kappa=0.2, window=30, params={"threshold": 0.7}
    )
    assert created["strategy"] == "quiet" and created["params"] == {"threshold": 0.7}
    core = strategies.make_advisor(
        "quiet", core_tables(service), 0.2, 30, StrategyParams(threshold=0.7)
    )
    assert created["decision"] == expected_json(
        core.start(service.catalog.get("default").domain.start), service
    )
    grid = service.catalog.get("default").domain
    rng = np.random.default_rng(5)
    s = grid.start
    events, expected = [], []
    theta = core.tables.theta
    for i in range(60):  # first as the experts move (it looks normal), then at random (lost)
        a = int(np.argmax(theta[s])) if i < 30 else int(rng.integers(4))
        s2 = int(grid.next_state[s, a])
        events.append({"state": list(grid.cell(s)), "action": "NESW"[a]})
        expected.append(expected_json(core.observe(s, a, s2), service))
        s = s2
    one = client.post(f"/sessions/{sid}/events", json=events[0], headers=auth)
    assert one.status_code == 200 and one.json() == expected[0]
    batch = client.post(f"/sessions/{sid}/events", json=events[1:], headers=auth)
    assert batch.status_code == 200 and batch.json() == expected[1:]
    assert any(d["advise"] for d in expected) and not all(d["advise"] for d in expected)


def test_a_registered_strategy_s_session_is_kept_and_loaded_exactly(
    quiet: Strategy, service: ServiceState
) -> None:
    """Its readable advisor's window (lists of floats) goes through the codec as the compiled
    forms' windows do: the loaded session decides as the one that stayed."""
    domain = service.catalog.get("default")
    reg = SessionRegistry(Limits(10), 3600.0)
    asked = SessionSettings.of("quiet", 0.3, 7, {"threshold": 0.6})
    stayed, _ = reg.create(domain, asked)
    moved, _ = reg.create(domain, asked)
    grid = domain.domain
    rng = np.random.default_rng(9)
    s = grid.start
    for i, a in enumerate(rng.integers(0, 4, 40).tolist()):
        if i % 9 == 0:
            moved = load(dump(moved), domain, 32)
        s2 = int(grid.next_state[s, a])
        assert reg.observe_one(stayed, s, a, s2) == reg.observe_one(moved, s, a, s2)
        s = s2


def test_a_registered_strategy_runs_in_an_experiment(
    quiet: Strategy, tmp_path: Path, small_maze: Path
) -> None:
    args = strategy_suite.Args(
        maze=small_maze,
        tasks=2,
        maps=1,
        map_size=9,
        steps=120,
        workers=1,
        progress=False,
        strategies=("paper", "quiet"),
        candidate="quiet",
        variants=(),
    )  # the strategies' options are fields made from the table
    result = strategies_experiment.run(args, RunDir(tmp_path))
    keys = {c["key"] for c in result["configs"]}
    assert {"quiet@0.3", "quiet@0.5", "quiet@0.6"} <= keys  # its levels and the default
    rows = [r for r in result["rows"] if r["scope"] == "suite" and r["curve"] == "quiet"]
    assert rows and all(0 <= r["success"] <= 1 for r in rows)
    assert any(r["advice_per_task"] > 0 for r in rows)
