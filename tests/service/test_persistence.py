"""What survives a restart, on SQLite and on PostgreSQL (configured by URL alone)."""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.service.main import create_app
from app.service.security import ADMIN_KEY_FILE
from app.service.state import ServiceState
from tests.service.conftest import TINY, make_settings, open_session

STEPS = [
    {"state": [5, 1], "action": "E"},
    {"state": [5, 2], "action": "E"},
    {"state": [5, 3], "action": "N"},
]


def _start(data_dir: Path, db_url: str) -> TestClient:
    return TestClient(create_app(make_settings(data_dir, database_url=db_url)))


def test_domains_trajectories_and_counts_survive_a_restart(tmp_path: Path, db_url: str) -> None:
    data = tmp_path / "data"
    with _start(data, db_url) as client:
        service: ServiceState = client.app.state.service  # type: ignore[attr-defined]
        assert service.store.dialect in db_url.split(":")[0]
        key = {"X-API-Key": service.admin_key}
        assert (
            client.put("/domains/tiny", json={"map": TINY, "alpha0": 0.5}, headers=key).status_code
            == 201
        )
        body = {"trajectories": [{"steps": STEPS}, {"steps": STEPS[:2], "agent_type": "staff"}]}
        assert client.post("/domains/tiny/trajectories", json=body, headers=key).status_code == 201
        prior = client.get("/domains/tiny/prior").json()
        staff = client.get("/domains/tiny/prior", params={"agent_type": "staff"}).json()
        domains = client.get("/domains").json()
        sid, auth, _ = open_session(client, "tiny")
    with _start(data, db_url) as client:
        service = client.app.state.service  # type: ignore[attr-defined]
        assert service.admin_key == key["X-API-Key"]
        assert client.get("/domains").json() == domains
        assert client.get("/domains/tiny/prior").json() == prior
        assert client.get("/domains/tiny/prior", params={"agent_type": "staff"}).json() == staff
        for name in ("tiny", "default"):
            counts = service.store.counts(name)
            recount = service.store.recount(name, service.catalog.get(name).domain.n_states)
            assert sorted(counts) == sorted(recount)
            for k in counts:
                np.testing.assert_array_equal(counts[k].counts, recount[k].counts)
        # a graceful restart keeps the live sessions (saved at shutdown, read back at start)
        assert client.get(f"/sessions/{sid}", headers=auth).status_code == 200


def _walk(grid_rows: list[str], n: int, seed: int) -> list[dict[str, object]]:
    from app.domain.grid import ACTIONS, GridDomain

    grid = GridDomain.from_strings(grid_rows)
    rng = np.random.default_rng(seed)
    s, out = grid.start, []
    for a in rng.integers(0, 4, n).tolist():
        out.append({"state": list(grid.cell(s)), "action": ACTIONS[a]})
        s = grid.step(s, a)
    return out


@pytest.mark.parametrize(
    "options",
    [
        {"kappa": 0.3, "window": 25},
        {"strategy": "goal_aware", "params": {"beta": 0.5}, "window": 30},
        {"strategy": "guide", "kappa": 0.2},
        {"strategy": "random", "params": {"rate": 0.4, "seed": 3}},
    ],
)
def test_a_graceful_restart_keeps_live_sessions_exactly(
    tmp_path: Path, options: dict[str, Any]
) -> None:
    """Windows, steps, costs, a random rule's draws: the session after a restart answers as
    one in a service that never stopped (the same bootstrap prior), decision for decision."""
    url_a = f"sqlite:///{tmp_path / 'a.db'}"
    url_b = f"sqlite:///{tmp_path / 'b.db'}"
    with _start(tmp_path / "b", url_b) as steady:
        rows = steady.get("/domains/default").json()["map"]
        events = _walk(rows, 120, seed=5)
        _, auth_b, created_b = open_session(steady, **options)
        sid_b = created_b["session_id"]
        want = [
            steady.post(f"/sessions/{sid_b}/events", json=events[i : i + 20], headers=auth_b).json()
            for i in range(0, 120, 20)
        ]
        figures_b = steady.get(f"/sessions/{sid_b}", headers=auth_b).json()
    with _start(tmp_path / "a", url_a) as client:
        sid, auth, created = open_session(client, **options)
        assert created["decision"] == created_b["decision"]
        got = [client.post(f"/sessions/{sid}/events", json=events[:60], headers=auth).json()]
    with _start(tmp_path / "a", url_a) as client:  # the same data directory: a restart
        got.append(client.post(f"/sessions/{sid}/events", json=events[60:], headers=auth).json())
        figures = client.get(f"/sessions/{sid}", headers=auth).json()
    assert [d for part in got for d in part] == [d for part in want for d in part]
    for key in ("steps", "advice_count", "total_cost", "benefit", "p_normal", "position", "goals"):
        assert figures[key] == figures_b[key], key


def test_first_start_happens_once(tmp_path: Path, db_url: str) -> None:
    data = tmp_path / "data"
    with _start(data, db_url) as client:
        service: ServiceState = client.app.state.service  # type: ignore[attr-defined]
        default = client.get("/domains/default").json()
        assert default["trajectories"] == 2 * len(default["goals"])
        trajs = service.store.trajectories("default")
        assert [t.goal for t in trajs] == [
            g for g in service.catalog.get("default").domain.goals for _ in range(2)
        ]
        assert (
            client.delete("/domains/default", headers={"X-API-Key": service.admin_key}).status_code
            == 204
        )
    with _start(data, db_url) as client:  # deleted on purpose: not created again
        assert client.get("/domains").json() == []


def test_admin_key_is_generated_once_with_mode_0600(tmp_path: Path) -> None:
    data = tmp_path / "data"
    db = f"sqlite:///{tmp_path / 'a.db'}"
    with _start(data, db) as client:
        key = client.app.state.service.admin_key  # type: ignore[attr-defined]
    path = data / ADMIN_KEY_FILE
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    assert path.read_text().strip() == key
    os.chmod(path, 0o644)  # someone opened it up: the next start closes it again
    with _start(data, db) as client:
        assert client.app.state.service.admin_key == key  # type: ignore[attr-defined]
    assert stat.S_IMODE(path.stat().st_mode) == 0o600


def test_a_configured_admin_key_is_used_and_nothing_is_written(tmp_path: Path) -> None:
    settings = make_settings(tmp_path / "data", admin_key="s3cret-key")
    with TestClient(create_app(settings)) as client:
        r = client.put("/domains/tiny", json={"map": TINY}, headers={"X-API-Key": "s3cret-key"})
        assert r.status_code == 201
    assert not (tmp_path / "data" / ADMIN_KEY_FILE).exists()
