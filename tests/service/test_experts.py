"""PUT /domains/{name} with simulated experts: a new domain advises at once."""

from __future__ import annotations

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.agents.experts import train_prior
from app.domain.generate import generate_building
from app.domain.grid import GridDomain
from app.service.state import ServiceState
from tests.service.conftest import TINY, open_session


def theta(client: TestClient, name: str) -> np.ndarray:
    rows = client.get(f"/domains/{name}/prior").json()["theta"]
    return np.array([[v if v is not None else [np.nan] * 4 for v in row] for row in rows])


@pytest.mark.parametrize("source", ["start", "anywhere"])
def test_put_with_experts_learns_the_prior_train_learns(
    client: TestClient, admin: dict[str, str], service: ServiceState, source: str
) -> None:
    rows = generate_building(24, 30, np.random.default_rng(2), n_goals=4)
    experts = {"source": source, "per_goal": 3, "seed": 11}
    r = client.put("/domains/b", json={"map": rows, "alpha0": 0.5, "experts": experts},
                   headers=admin)  # fmt: skip
    assert r.status_code == 201, r.text
    assert r.json()["trajectories"] == 12
    grid = GridDomain.from_strings(rows)
    want = train_prior(grid, np.random.default_rng(11), source, 3, alpha0=0.5)  # type: ignore[arg-type]
    got = theta(client, "b")[grid.cells[:, 0], grid.cells[:, 1]]
    np.testing.assert_allclose(got, want.theta(), rtol=0, atol=1e-15)
    # stored as trajectories with their goals: a recount gives the counts, goal_aware works
    state = service.catalog.get("b")
    recount = service.store.recount("b", grid.n_states)
    assert {k: v.counts.tolist() for k, v in recount.items()} == {
        k: v.counts.tolist() for k, v in service.store.counts("b").items()
    }
    goals = {t.goal for t in service.store.trajectories("b")}
    assert goals == set(grid.goals)
    _, _, created = open_session(client, "b", strategy="goal_aware", kappa=0.0)
    assert created["decision"]["advise"]
    assert state.view.trajectories["*"] == 12


def test_put_with_experts_is_idempotent_and_a_new_map_learns_again(
    client: TestClient, admin: dict[str, str]
) -> None:
    body = {"map": TINY, "experts": {"per_goal": 2}}
    assert client.put("/domains/t", json=body, headers=admin).json()["trajectories"] == 4
    again = client.put("/domains/t", json=body, headers=admin)
    assert again.status_code == 200 and again.json()["trajectories"] == 4
    other = [*TINY[:-2], "#S...G#", TINY[-1]]
    r = client.put("/domains/t", json={"map": other, "experts": {"per_goal": 2}}, headers=admin)
    assert r.json()["trajectories"] == 6  # three goals now


@pytest.mark.parametrize(
    ("experts", "message"),
    [
        ({"per_goal": 0}, "greater than or equal to 1"),
        ({"source": "policy"}, "'start' or 'anywhere'"),
        ({"seed": -1}, "greater than or equal to 0"),
        ({"per_goal": 2, "extra": 1}, "Extra inputs are not permitted"),
    ],
)
def test_bad_experts_are_refused(
    client: TestClient, admin: dict[str, str], experts: dict[str, object], message: str
) -> None:
    r = client.put("/domains/t", json={"map": TINY, "experts": experts}, headers=admin)
    assert r.status_code == 422 and message in r.json()["detail"]
    assert client.get("/domains/t").status_code == 404


def test_experts_beyond_the_bound_are_refused_before_anything_changes(
    client: TestClient, admin: dict[str, str], service: ServiceState
) -> None:
    service.settings.max_expert_pairs = 50
    r = client.put("/domains/t", json={"map": TINY, "experts": {"per_goal": 10}}, headers=admin)
    assert r.status_code == 422
    assert "at most 50" in r.json()["detail"]
    assert client.get("/domains/t").status_code == 404
