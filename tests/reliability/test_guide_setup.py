"""The first guide session of a domain builds its guide map (a distance from every cell to
every destination) in a worker thread; on a map with many destinations that took about a
minute and held the domain's lock, so an admin's ingestion into it waited as long. Now the
distances are computed outside that lock, the searches of every destination advance
together, and the map built carries the counts of what was ingested meanwhile."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from app.advice.guide import GuideMap
from app.domain.grid import GridDomain, compass_detours
from app.domain.paths import expert_trajectories
from app.service.data.domains import DomainCatalog
from app.service.data.store import Store, Trajectory

#: a corridor with a destination in nearly every cell
CORRIDOR = ["#" * 42, "#S" + "G" * 38 + ".#", "#" * 42]


@pytest.fixture
def catalog(tmp_path: Path) -> Iterator[DomainCatalog]:
    store = Store(f"sqlite:///{tmp_path / 'a.db'}")
    store.create_schema()
    yield DomainCatalog(store, 10_000)
    store.close()


def test_ingestion_goes_on_while_a_guide_map_is_built(
    catalog: DomainCatalog, monkeypatch: pytest.MonkeyPatch
) -> None:
    grid = GridDomain.from_strings(CORRIDOR, name="c")
    state, _, _ = catalog.put("c", grid, 1.0)
    building, release = threading.Event(), threading.Event()
    plain_of = GuideMap.of

    def slow_of(
        domain: GridDomain, goal_priors: object = None, searches: Any = None,
        distances: Any = None, leads: Any = None,
    ) -> GuideMap:  # fmt: skip
        building.set()
        assert release.wait(60), "the test never released the build"
        return plain_of(domain, searches=searches, distances=distances, leads=leads)

    monkeypatch.setattr(GuideMap, "of", staticmethod(slow_of))
    built: list[GuideMap] = []
    builder = threading.Thread(target=lambda: built.append(catalog.guide_map(state)))
    builder.start()
    try:
        assert building.wait(30), "the guide map's build did not start"
        walks = expert_trajectories(grid, np.random.default_rng(0), "start", 3)
        items = [Trajectory(None, w.pairs, w.goal) for w in walks if len(w.pairs)]
        done = threading.Event()

        def ingest_them() -> None:
            catalog.add_trajectories(state, items)
            done.set()

        ingest = threading.Thread(target=ingest_them)
        ingest.start()
        # ingestion finishes while the build is still held: it no longer waits for it
        assert done.wait(30), "ingestion waited for the guide map's build"
        ingest.join()
    finally:
        release.set()
        builder.join(60)
    assert built and catalog.get("c").guide_map is built[0]
    # the map built reads the counts of what was ingested during its build
    assert built[0].counts.sum() > 0
    goal_counts = catalog.get("c").goal_priors
    assert goal_counts is not None
    assert np.array_equal(built[0].counts, goal_counts.goal_counts.reshape(len(grid.goals), -1))


def test_a_guide_map_of_many_destinations_equals_one_search_per_destination() -> None:
    grid = GridDomain.from_strings(CORRIDOR, name="c")
    guide = GuideMap.of(grid)
    for i, g in enumerate(grid.goals):
        assert np.array_equal(guide.dist[i], grid.distances_to(g))
        assert np.array_equal(guide.detour[i], compass_detours(grid.next_state, grid.cells, g))
