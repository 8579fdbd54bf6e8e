"""Ingestion racing a put of the same domain: nothing acknowledged is lost, nothing answers 404
while the domain exists; a put of another map refuses in-flight trajectories clearly (409)."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.domain.grid import ACTIONS, GridDomain
from app.domain.paths import expert_trajectories
from app.service.data.domains import DomainCatalog, DomainChanged, DomainNotFound
from app.service.data.store import POOLED, Store, Trajectory
from app.service.main import create_app
from tests.service.conftest import TINY, make_settings


@pytest.fixture
def catalog(tmp_path: Path) -> Iterator[DomainCatalog]:
    store = Store(f"sqlite:///{tmp_path / 'a.db'}")
    store.create_schema()
    yield DomainCatalog(store, 10_000)
    store.close()


def _items(grid: GridDomain, seed: int) -> list[Trajectory]:
    walks = expert_trajectories(grid, np.random.default_rng(seed), "anywhere", 1)
    return [Trajectory(None, w.pairs, w.goal) for w in walks if len(w.pairs)]


def test_trajectories_for_a_replaced_state_go_to_the_same_map_put_again(
    catalog: DomainCatalog,
) -> None:
    grid = GridDomain.from_strings(TINY, name="t")
    old, _, _ = catalog.put("t", grid, 1.0)
    new, _, kept = catalog.put("t", GridDomain.from_strings(TINY, name="t"), 0.5)
    assert kept and new is not old
    items = _items(grid, 1)
    went = catalog.add_trajectories(old, items)  # resolved before the put, added after it
    assert went is catalog.get("t") is new
    assert new.view.trajectories[POOLED] == len(items)
    assert catalog.store.counts("t")  # stored, not only counted


def test_trajectories_for_a_map_replaced_by_another_are_refused(catalog: DomainCatalog) -> None:
    grid = GridDomain.from_strings(TINY, name="t")
    old, _, _ = catalog.put("t", grid, 1.0)
    other = [*TINY[:3], "#.#.#.#", *TINY[4:]]  # a wall more
    other_grid = GridDomain.from_strings(other, name="t")
    assert other_grid.rows_text != grid.rows_text
    catalog.put("t", other_grid, 1.0)
    with pytest.raises(DomainChanged):
        catalog.add_trajectories(old, _items(grid, 2))
    assert catalog.get("t").view.trajectories.get(POOLED, 0) == 0
    catalog.delete("t")
    with pytest.raises(DomainNotFound):
        catalog.add_trajectories(old, _items(grid, 3))


def test_writers_racing_puts_of_the_same_map_lose_nothing(tmp_path: Path) -> None:
    """3 writers ingest while the same map is PUT again and again with other alpha0s: every
    ingest is acknowledged (no 404) and the stored count is every acknowledged one."""
    with TestClient(create_app(make_settings(tmp_path))) as client:
        service = client.app.state.service  # type: ignore[attr-defined]
        admin = {"X-API-Key": service.admin_key}
        assert client.put("/domains/r", json={"map": TINY}, headers=admin).status_code == 201
        grid = service.catalog.get("r").domain
        answers: list[int] = []
        lock = threading.Lock()

        def write(seed: int) -> None:
            rng = np.random.default_rng(seed)
            for _ in range(25):
                walk = _items(grid, int(rng.integers(1 << 30)))[0]
                steps = [{"state": list(grid.cell(s)), "action": ACTIONS[a]}
                         for s, a in walk.pairs.tolist()]  # fmt: skip
                r = client.post("/domains/r/trajectories", json={"trajectories": [
                    {"steps": steps}]}, headers=admin)  # fmt: skip
                with lock:
                    answers.append(r.status_code)

        def put() -> None:
            for k in range(40):
                alpha0 = 0.5 + (k % 3) / 2
                r = client.put("/domains/r", json={"map": TINY, "alpha0": alpha0}, headers=admin)
                assert r.status_code == 200, r.text

        threads = [threading.Thread(target=write, args=(i,)) for i in range(3)]
        threads.append(threading.Thread(target=put))
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert answers.count(201) == len(answers) == 75, sorted(set(answers))
        assert service.catalog.get("r").view.trajectories[POOLED] == 75
        assert len(service.store.trajectories("r")) == 75
