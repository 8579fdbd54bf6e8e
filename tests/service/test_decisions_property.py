"""The service decides exactly as the core library does, for the same prior and events.

The reference prior is rebuilt independently from the trajectories in the database (the
core's ActionPrior.fit), and a core Advisor is fed the same moves. Events go over REST or the
websocket, in random batches and in all three event forms, and the prior changes mid-stream
(new expert trajectories), which live sessions must follow.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from hypothesis import given
from hypothesis import strategies as st

from app.advice.advisor import Advisor, Decision
from app.advice.models import AdviceTables
from app.advice.priors import ActionPrior
from app.domain.grid import ACTIONS
from app.domain.paths import expert_trajectory
from app.service.main import create_app
from app.service.state import ServiceState
from app.service.wire.encode import decision_dict
from tests.service.conftest import make_settings


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[TestClient, ServiceState]]:
    settings = make_settings(Path(tmp_path_factory.mktemp("data")))
    with TestClient(create_app(settings)) as client:
        yield client, client.app.state.service  # type: ignore[attr-defined]


def core_tables(service: ServiceState, name: str = "default") -> AdviceTables:
    state = service.catalog.get(name)
    trajs = [t.pairs for t in service.store.trajectories(name)]
    prior = ActionPrior(alpha0=state.view.alpha0, n_actions=state.domain.n_actions)
    return AdviceTables.paper(prior.fit(trajs, state.domain.n_states).theta())


def event_of(
    rng: np.random.Generator, cell: tuple[int, ...], a: int, nxt: tuple[int, ...]
) -> dict[str, Any]:
    form = int(rng.integers(3))
    if form == 2 and nxt != cell:
        return {"state": cell, "next_state": nxt}  # the action is inferred from the move
    if form == 1:
        return {"state": cell, "action": ACTIONS[a], "next_state": nxt}
    return {"state": cell, "action": int(a) if rng.random() < 0.3 else ACTIONS[a]}


def expected_json(d: Decision, service: ServiceState, name: str = "default") -> dict[str, Any]:
    out = decision_dict(d, service.catalog.get(name).domain)
    wire: dict[str, Any] = json.loads(json.dumps(out))  # tuples -> lists, as on the wire
    return wire


@given(
    seed=st.integers(0, 2**32 - 1),
    kappa=st.sampled_from([0.0, 0.2, 0.5, 1.0, 1.39]),
    window=st.sampled_from([1, 5, 40, 300]),
    over_websocket=st.booleans(),
)
def test_service_decisions_equal_core_decisions(
    live: tuple[TestClient, ServiceState],
    seed: int,
    kappa: float,
    window: int,
    over_websocket: bool,
) -> None:
    client, service = live
    domain = service.catalog.get("default").domain
    rng = np.random.default_rng(seed)
    start = int(rng.integers(domain.n_states))
    r = client.post(
        "/domains/default/sessions",
        json={"kappa": kappa, "window": window, "start": domain.cell(start)},
    )
    assert r.status_code == 201
    created = r.json()
    core = Advisor(core_tables(service), kappa=kappa, window=window)
    assert created["decision"] == expected_json(core.start(start), service)
    sid, token = created["session_id"], created["token"]
    auth = {"Authorization": f"Bearer {token}"}
    ws = (
        client.websocket_connect(f"/sessions/{sid}/stream?token={token}")
        if over_websocket
        else None
    )
    s = start
    with ws or _nothing():
        for _ in range(int(rng.integers(1, 6))):
            if rng.random() < 0.25:  # an expert trajectory arrives: the prior changes now
                goal = domain.goals[int(rng.integers(len(domain.goals)))]
                pairs = expert_trajectory(domain, int(rng.integers(domain.n_states)), goal, rng)
                steps = [{"state": domain.cell(p), "action": ACTIONS[q]} for p, q in pairs.tolist()]
                if steps:
                    body = {"trajectories": [{"steps": steps}]}
                    r = client.post(
                        "/domains/default/trajectories",
                        json=body,
                        headers={"X-API-Key": service.admin_key},
                    )
                    assert r.status_code == 201
                    core.tables = core_tables(service)
            events, expected = [], []
            for _ in range(int(rng.integers(0, 120))):
                a = int(rng.integers(4))
                s2 = int(domain.next_state[s, a])
                events.append(event_of(rng, domain.cell(s), a, domain.cell(s2)))
                expected.append(expected_json(core.observe(s, a, s2), service))
                s = s2
            single = len(events) == 1 and rng.random() < 0.5
            payload = events[0] if single else events
            if ws is not None:
                ws.send_text(json.dumps(payload))
                got = json.loads(ws.receive_text())
            else:
                r = client.post(f"/sessions/{sid}/events", json=payload, headers=auth)
                assert r.status_code == 200
                got = r.json()
            assert got == (expected[0] if single else expected)
    assert client.delete(f"/sessions/{sid}", headers=auth).status_code == 200


class _nothing:
    def __enter__(self) -> None:
        return None

    def __exit__(self, *exc: object) -> None:
        return None
