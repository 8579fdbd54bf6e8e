"""What the strategies need of a domain (goal priors, a guide map) is built when an admin makes
or changes it, off the event loop, and never on a session's request.

Before, a re-PUT of a 500 x 500 domain changing only alpha0 held the event loop for over a
second, and the first guide session on such a domain, opened by anyone, built its guide map
(37 s). These tests check where the work runs, never how long it takes: every builder records
whether it ran on a thread with a running event loop; a probe task on the loop must keep
running while a guide map is built; a session on a domain not yet prepared is answered 503 at
once while the build goes on elsewhere.
"""

from __future__ import annotations

import asyncio
import threading
import time
import weakref
from collections.abc import Callable, Iterator
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import orjson
import pytest
from fastapi.testclient import TestClient
from hypothesis import given, settings
from hypothesis import strategies as st

from app import kernels
from app.advice import guide as guide_module
from app.advice.guide import GuideMap
from app.advice.models import AdviceTables
from app.advice.priors import GoalPriors
from app.domain import grid as grid_module
from app.domain.building import Building
from app.domain.floorplans import generate_floors
from app.domain.generate import generate_building, generate_maze
from app.domain.grid import GridDomain, bfs_distances_each, compass_detours_each, compass_takes
from app.service.data import domains as domains_module
from app.service.data.domains import DomainCatalog, needed, preparation_bytes
from app.service.data.store import Store
from app.service.main import create_app
from app.service.ops import unprepared
from app.service.state import ServiceState
from app.service.wire import encode as encode_module
from app.service.wire import events as events_module
from app.strategies import Need, compiled_leads, names
from tests.domain.test_building_property import build
from tests.domain.test_building_property import buildings as generated_buildings
from tests.service.conftest import REDIS_URL, TINY, drop_redis_keys, make_settings, redis_problem

#: a maze of 3 destinations, small enough to build in a moment
MAZE = generate_maze(21, 21, np.random.default_rng(7), braid=0.3, n_goals=3)
MAZE_GRID = GridDomain.from_strings(MAZE)
MAZE_START = list(MAZE_GRID.cell(MAZE_GRID.start))
MAZE_GOAL = list(MAZE_GRID.cell(MAZE_GRID.goals[0]))
#: a move that stays at the start (into the map's edge): any number of them is a valid batch
STAY = "NESW"[[int(t) for t in MAZE_GRID.next_state[MAZE_GRID.start]].index(MAZE_GRID.start)]


def on_loop() -> bool:
    """Whether the calling thread is running an event loop (a request's handler, not a
    worker thread)."""
    try:
        asyncio.get_running_loop()
    except RuntimeError:
        return False
    return True


Calls = list[tuple[str, bool]]


@pytest.fixture
def calls(monkeypatch: pytest.MonkeyPatch) -> Calls:
    """Every costly build from now on, as (what, whether it ran on an event loop's thread):
    the guide map and its searches, the goal priors and their tables, a prior's tables, a
    map's parse, the grid's and the event reader's lists, theta's answer text."""
    seen: Calls = []

    def spy(owner: Any, name: str, label: str, when: Callable[..., bool] | None = None) -> None:
        real = getattr(owner, name)

        def wrapped(*args: Any, **kwargs: Any) -> Any:
            if when is None or when(*args):
                seen.append((label, on_loop()))
            return real(*args, **kwargs)

        static = isinstance(owner, type) and isinstance(owner.__dict__.get(name), classmethod)
        monkeypatch.setattr(owner, name, staticmethod(wrapped) if static else wrapped)

    spy(GuideMap, "of", "guide map")
    spy(domains_module, "compiled_searches", "guide searches")
    spy(DomainCatalog, "goal_priors", "goal priors", lambda _c, s: s.goal_priors is None)
    spy(GoalPriors, "arrays", "goal tables", lambda p: p._arrays is None)
    spy(AdviceTables, "__post_init__", "prior tables")
    spy(GridDomain, "from_strings", "map parse")
    spy(grid_module, "packed", "grid lists")
    spy(events_module, "packed", "event lists")
    spy(encode_module, "numbers_text", "theta text")
    return seen


def every_strategy_once(client: TestClient, domain: str) -> None:
    """A session of every strategy on ``domain``, then one event and a batch each."""
    for strategy in names():
        r = client.post(f"/domains/{domain}/sessions", json={"strategy": strategy})
        assert r.status_code == 201, r.text
        created = r.json()
        auth = {"Authorization": f"Bearer {created['token']}"}
        one = {"state": MAZE_START, "action": STAY}
        url = f"/sessions/{created['session_id']}/events"
        assert client.post(url, json=one, headers=auth).status_code == 200
        assert client.post(url, json=[one, one], headers=auth).status_code == 200


def test_puts_ingestion_and_sessions_build_nothing_on_the_event_loop(
    client: TestClient, admin: dict[str, str], calls: Calls
) -> None:
    r = client.put("/domains/maze", json={"map": MAZE}, headers=admin)
    assert r.status_code == 201, r.text
    made = {what for what, _ in calls}
    # the admin's PUT built what every strategy needs, and the event paths' texts and lists
    assert {"guide map", "guide searches", "goal priors", "goal tables", "prior tables",
            "map parse", "grid lists", "event lists", "theta text"} <= made  # fmt: skip
    for body in ({"map": MAZE, "alpha0": 2.0}, {"map": MAZE, "alpha0": 2.0, "resolution": 0.5}):
        assert client.put("/domains/maze", json=body, headers=admin).status_code == 200
    steps = [{"state": MAZE_START, "action": STAY}]
    body = {"trajectories": [{"steps": steps, "goal": MAZE_GOAL}]}
    r = client.post("/domains/maze/trajectories", json=body, headers=admin)
    assert r.status_code == 201, r.text
    built = len(calls)
    every_strategy_once(client, "maze")
    # sessions of every strategy and their first events built nothing at all
    assert calls[built:] == []
    on_the_loop = [what for what, loop in calls if loop]
    assert on_the_loop == [], f"built on the event loop: {on_the_loop}"


def test_a_same_map_put_reads_the_map_once_and_keeps_what_was_built(
    client: TestClient, admin: dict[str, str], service: ServiceState, calls: Calls
) -> None:
    assert client.put("/domains/maze", json={"map": MAZE}, headers=admin).status_code == 201
    before = service.catalog.get("maze")
    calls.clear()
    body = {"map": MAZE, "alpha0": 2.0, "resolution": 0.5}
    assert client.put("/domains/maze", json=body, headers=admin).status_code == 200
    after = service.catalog.get("maze")
    made = [what for what, _ in calls]
    # the same map in another frame: not parsed again, no search, no list made again; the
    # prior's tables are new (another alpha0), the goal priors' tables too
    assert "map parse" not in made and "guide searches" not in made
    assert "grid lists" not in made and "event lists" not in made
    assert after.domain is not before.domain and after.domain.frame is not None
    assert after.domain.next_state is before.domain.next_state
    assert after.guide_map is not None and before.guide_map is not None
    assert after.guide_map.dist is before.guide_map.dist
    assert after.goal_priors is not None and after.goal_priors.alpha0 == 2.0


def test_the_event_loop_runs_while_a_guide_map_is_built(
    client: TestClient, admin: dict[str, str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The searches wait for a probe task on the event loop to tick three times: were they
    run on the loop, the probe could not tick and they would give up waiting."""
    ticks = [0]
    stop = threading.Event()

    async def probe() -> None:
        while not stop.is_set():
            ticks[0] += 1
            await asyncio.sleep(0.001)

    real = domains_module.compiled_searches
    kept_running: list[bool] = []

    def waiting(*args: Any) -> Any:
        first = ticks[0]
        deadline = time.monotonic() + 30  # a guard: the probe normally ticks within ms
        while ticks[0] < first + 3 and time.monotonic() < deadline:
            time.sleep(0.001)
        kept_running.append(ticks[0] >= first + 3)
        return real(*args)

    monkeypatch.setattr(domains_module, "compiled_searches", waiting)
    portal = client.portal
    assert portal is not None
    portal.start_task_soon(probe)
    try:
        assert client.put("/domains/maze", json={"map": MAZE}, headers=admin).status_code == 201
    finally:
        stop.set()
    assert kept_running == [True]


def test_a_replaced_or_deleted_domain_is_freed_in_a_worker_thread(
    client: TestClient, admin: dict[str, str], service: ServiceState
) -> None:
    """A large map's state (its tables, lists and guide map) takes as long to free as to
    make: once its sessions have gone it is let go in a worker thread, not on the loop."""
    freed: list[bool] = []
    other = generate_maze(21, 21, np.random.default_rng(8), braid=0.3, n_goals=3)
    for body in ({"map": MAZE}, {"map": other}):
        assert client.put("/domains/maze", json=body, headers=admin).status_code in (200, 201)
        weakref.finalize(service.catalog.get("maze"), lambda: freed.append(on_loop()))
        for strategy in ("guide", "goal_aware"):
            r = client.post("/domains/maze/sessions", json={"strategy": strategy})
            assert r.status_code == 201, r.text
    assert freed == [False]  # the first map's state, its sessions ended by the second's PUT
    assert client.delete("/domains/maze", headers=admin).status_code == 204
    assert freed == [False, False]


def test_a_session_on_a_domain_being_prepared_is_503_and_builds_nothing_on_its_request(
    client: TestClient, service: ServiceState, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A domain stored and published but not prepared (as during its PUT's preparation): a
    guide session is answered at once, 503 with Retry-After, while one preparation goes on in
    a worker thread; a second request starts no other; once built, sessions open."""
    grid = GridDomain.from_strings(MAZE, name="raw")
    state, _, _ = service.catalog.put("raw", grid, 1.0)  # nothing prepared
    building, release = threading.Event(), threading.Event()
    builds: list[bool] = []
    real = DomainCatalog.guide_map

    def held(catalog: DomainCatalog, s: Any) -> GuideMap:
        builds.append(on_loop())
        building.set()
        assert release.wait(60), "the test never released the build"
        return real(catalog, s)

    monkeypatch.setattr(DomainCatalog, "guide_map", held)
    try:
        r = client.post("/domains/raw/sessions", json={"strategy": "guide"})
        assert r.status_code == 503, r.text
        assert "being prepared" in r.json()["detail"]
        assert int(r.headers["Retry-After"]) > 0
        assert building.wait(30), "no preparation started"
        again = client.post("/domains/raw/sessions", json={"strategy": "guide"})
        assert again.status_code == 503
        # a strategy that needs nothing of it opens meanwhile
        assert client.post("/domains/raw/sessions", json={}).status_code == 201
    finally:
        release.set()
    deadline = time.monotonic() + 60
    while state.guide_map is None and time.monotonic() < deadline:
        time.sleep(0.01)
    assert builds == [False]  # one build, in a worker thread
    r = client.post("/domains/raw/sessions", json={"strategy": "guide"})
    assert r.status_code == 201, r.text


def test_a_map_whose_preparation_would_pass_the_domain_memory_limit_is_refused(
    tmp_path: Path,
) -> None:
    settings = make_settings(tmp_path / "data", max_domain_memory=1024 * 1024)
    wide = ["#" * 102, *["#" + "." * 100 + "#" for _ in range(100)], "#" * 102]
    wide[1] = "#SG" + wide[1][3:]
    wide[-2] = wide[-2][:-2] + "G#"
    grid = GridDomain.from_strings(wide)
    estimate = preparation_bytes(len(grid.goals), grid.n_states, needed())
    assert estimate > 1024 * 1024
    with TestClient(create_app(settings)) as c:
        admin = {"X-API-Key": c.app.state.service.admin_key}  # type: ignore[attr-defined]
        r = c.put("/domains/wide", json={"map": wide}, headers=admin)
        assert r.status_code == 422, r.text
        detail = r.json()["detail"]
        assert "ADVISOR_MAX_DOMAIN_MEMORY" in detail and str(estimate) in detail
        assert c.get("/domains/wide").status_code == 404  # nothing stored
        assert c.put("/domains/tiny", json={"map": TINY}, headers=admin).status_code == 201


def test_a_stored_domain_over_a_lowered_limit_refuses_the_sessions_that_need_it(
    tmp_path: Path,
) -> None:
    data = tmp_path / "data"
    with TestClient(create_app(make_settings(data))) as c:
        admin = {"X-API-Key": c.app.state.service.admin_key}  # type: ignore[attr-defined]
        assert c.put("/domains/maze", json={"map": MAZE}, headers=admin).status_code == 201
    store = Store(make_settings(data).db_url)
    catalog = DomainCatalog(store, 250_000, max_memory=1000)  # a start: load prepares
    catalog.load()
    state = catalog.get("maze")
    with pytest.raises(ValueError, match="ADVISOR_MAX_DOMAIN_MEMORY"):
        catalog.prepare(state, [Need.GUIDE_MAP])  # nor built by one that asks for it
    store.close()
    assert state.goal_priors is None and state.guide_map is None
    assert set(state.refused) == {Need.GOAL_PRIORS, Need.GUIDE_MAP}
    assert all("ADVISOR_MAX_DOMAIN_MEMORY" in why for why in state.refused.values())
    refusal = unprepared(None, state, "goal_aware", [Need.GOAL_PRIORS])  # type: ignore[arg-type]
    assert refusal.status == 422 and "ADVISOR_MAX_DOMAIN_MEMORY" in refusal.detail


def test_a_map_that_cannot_be_guided_is_put_and_its_guide_sessions_refused_saying_why(
    client: TestClient, admin: dict[str, str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(guide_module, "MAX_GUIDE_CELLS", 10)
    assert client.put("/domains/maze", json={"map": MAZE}, headers=admin).status_code == 201
    r = client.post("/domains/maze/sessions", json={"strategy": "guide"})
    assert r.status_code == 422, r.text
    assert "guide advice holds a distance per destination and cell" in r.json()["detail"]
    r = client.post("/domains/maze/sessions", json={"strategy": "goal_aware"})
    assert r.status_code == 201, r.text


def test_the_memory_estimate_covers_what_is_built(
    client: TestClient, admin: dict[str, str], service: ServiceState
) -> None:
    assert client.put("/domains/maze", json={"map": MAZE}, headers=admin).status_code == 201
    state = service.catalog.get("maze")
    goals, gmap = state.goal_priors, state.guide_map
    assert goals is not None and gmap is not None
    arrays = goals.arrays()
    kept = [goals.goal_counts, goals.unknown_counts, arrays[0], arrays[4].base,
            gmap.dist, gmap.detour, gmap.marks, gmap.n_open, gmap.goal_of_state, gmap.compass_of,
            gmap.lead,
            state.domain.open_moves]  # fmt: skip
    built = sum(a.nbytes for a in kept if a is not None)
    estimate = preparation_bytes(len(state.domain.goals), state.domain.n_states, needed())
    assert built <= estimate
    assert built >= 0.9 * estimate


@pytest.mark.parametrize("lead_cells", [0, 3 * 243 - 1, 3 * 243, 10**9])
def test_lead_cells_decides_which_maps_get_lead_values(tmp_path: Path, lead_cells: int) -> None:
    """``ADVISOR_LEAD_CELLS``: a map of at most that many destinations x free cells gets
    guide's lead values when prepared (the compiled sweeps, the simulator's values), a larger
    one none; the memory estimate counts them only when they are made."""
    store = Store(f"sqlite:///{tmp_path / 'a.db'}")
    store.create_schema()
    catalog = DomainCatalog(store, 250_000, lead_cells=lead_cells)
    state, _, _ = catalog.put("maze", MAZE_GRID, 1.0)
    gmap = catalog.guide_map(state)
    store.close()
    gs = len(MAZE_GRID.goals) * MAZE_GRID.n_states
    assert gs == 3 * 243  # the bounds above sit on either side of it
    if gs <= lead_cells:
        expected = compiled_leads(gmap.next_state, gmap.n_open, gmap.dist)
        assert np.array_equal(gmap.lead, expected)
    else:
        assert gmap.lead.shape == (0, 0, 4)
    estimate = preparation_bytes(3, MAZE_GRID.n_states, [Need.GUIDE_MAP], lead_cells=lead_cells)
    without = preparation_bytes(3, MAZE_GRID.n_states, [Need.GUIDE_MAP], lead_cells=0)
    assert estimate - without == (16 * gs if gs <= lead_cells else 0)


def test_the_service_makes_lead_values_up_to_its_setting(tmp_path: Path) -> None:
    """The service's catalog takes ``ADVISOR_LEAD_CELLS``: with 0, a map PUT is guided
    without lead values."""
    with TestClient(create_app(make_settings(tmp_path / "data", lead_cells=0))) as c:
        service: ServiceState = c.app.state.service  # type: ignore[attr-defined]
        admin = {"X-API-Key": service.admin_key}
        assert c.put("/domains/maze", json={"map": MAZE}, headers=admin).status_code == 201
        gmap = service.catalog.get("maze").guide_map
        assert service.catalog.lead_cells == 0
        assert gmap is not None and gmap.lead.shape == (0, 0, 4)


def test_the_memory_estimate_of_a_building_s_guide_map_counts_its_landmarks() -> None:
    """A building's guide map holds MARKS landmarks a floor (``marks_for``): the estimate
    counts them, and the floors and nearest stops."""
    tower = generate_floors(32, 32, 3, np.random.default_rng(1), purpose="hospital", n_goals=2)
    gmap = GuideMap.of(tower, leads=compiled_leads)
    assert gmap.marks.shape[0] == 3 * guide_module.MARKS
    assert gmap.floor is not None and gmap.stops is not None
    kept: list[np.ndarray[Any, Any]] = [
        gmap.dist, gmap.detour, gmap.compass_of, gmap.marks, gmap.n_open, gmap.goal_of_state,
        gmap.floor, gmap.stops, tower.open_moves, gmap.lead,
    ]  # fmt: skip
    built = sum(a.nbytes for a in kept)
    estimate = preparation_bytes(len(tower.goals), tower.n_states, [Need.GUIDE_MAP], 6, 3)
    assert 0.9 * estimate <= built <= estimate


SEARCHED = st.one_of(
    st.builds(
        lambda rows, cols, seed, braid: generate_maze(
            rows, cols, np.random.default_rng(seed), braid=braid, n_goals=3
        ),
        st.integers(3, 25), st.integers(3, 25), st.integers(0, 10_000),
        st.sampled_from([0.0, 0.3, 1.0]),
    ),
    st.builds(
        lambda rows, cols, seed: generate_building(
            rows, cols, np.random.default_rng(seed), n_goals=3
        ),
        st.integers(16, 30), st.integers(16, 30), st.integers(0, 10_000),
    ),
)  # fmt: skip


@given(SEARCHED, st.data())
def test_the_compiled_searches_are_the_numpy_ones(rows: list[str], data: st.DataObject) -> None:
    grid = GridDomain.from_strings(rows)
    extra = data.draw(st.lists(st.integers(0, grid.n_states - 1), max_size=4))
    targets = (*grid.goals, *extra)
    dist, detour, compass = domains_module.compiled_searches(grid.next_state, grid.cells, targets)
    assert np.array_equal(dist, bfs_distances_each(grid.next_state, targets))
    assert np.array_equal(detour, compass_detours_each(grid.next_state, grid.cells, targets))
    takes = partial(compass_takes, grid.next_state, grid.cells)
    want = guide_module.compass_table(grid.n_states, 4, targets, takes)
    assert compass.dtype == want.dtype and np.array_equal(compass, want)
    compiled = GuideMap.of(grid, searches=domains_module.compiled_searches)
    plain = GuideMap.of(grid)
    for a, b in zip(compiled.arrays[:10], plain.arrays[:10], strict=True):  # the arrays
        assert isinstance(a, np.ndarray) and isinstance(b, np.ndarray)
        assert a.dtype == b.dtype and np.array_equal(a, b)
    assert compiled.cells_bound and plain.cells_bound
    assert compiled.ride_spread == plain.ride_spread == 0  # one floor


BUILDINGS = st.one_of(
    generated_buildings().map(build),
    st.builds(
        lambda side, floors, seed, goals: generate_floors(
            side, side, floors, np.random.default_rng(seed), purpose="hospital",
            n_goals=goals, name="h",
        ),
        st.integers(32, 40), st.integers(2, 3), st.integers(0, 10_000), st.integers(1, 3),
    ),
)  # fmt: skip


@settings(max_examples=60, deadline=None)
@given(BUILDINGS, st.data())
def test_the_compiled_searches_of_a_building_are_the_numpy_ones(
    tower: Building, data: st.DataObject
) -> None:
    """A building's guide map in the service (compiled searches, without the GIL) is the
    experiments' (numpy's, the building's compass), compass table and landmarks included
    (their distances cross floors: a search over the compass moves alone left them -1 on
    other floors)."""
    extra = data.draw(st.lists(st.integers(0, tower.n_states - 1), max_size=4))
    targets = (*tower.goals, *extra)
    dist, detour, compass = domains_module.compiled_searches(
        tower.next_state, tower.cells, targets, tower.nearest_stops
    )
    assert np.array_equal(dist, bfs_distances_each(tower.next_state, targets))
    want = compass_detours_each(tower.next_state, tower.cells, targets, takes=tower.compass_takes)
    assert np.array_equal(detour, want)
    table = guide_module.compass_table(tower.n_states, 6, targets, tower.compass_takes)
    assert np.array_equal(compass, table)
    compiled = GuideMap.of(
        tower, searches=domains_module.compiled_searches, distances=kernels.guide_distances
    )
    plain = GuideMap.of(tower)
    for a, b in zip(compiled.arrays, plain.arrays, strict=True):
        if isinstance(a, np.ndarray):
            assert isinstance(b, np.ndarray) and a.dtype == b.dtype and np.array_equal(a, b)
    assert compiled.cells_bound == plain.cells_bound
    assert compiled.ride_spread == plain.ride_spread


# ---- workers sharing Redis: the other worker prepares when it reads the change ----------------
REDIS = redis_problem()


@pytest.fixture
def two_workers(tmp_path: Path) -> Iterator[tuple[TestClient, TestClient, ServiceState]]:
    from tests.service.test_workers import start_workers

    clients, prefix = start_workers(tmp_path, 2)
    try:
        a, b = clients
        yield a, b, b.app.state.service  # type: ignore[attr-defined]
    finally:
        for c in clients:
            c.__exit__(None, None, None)
        drop_redis_keys(prefix)


@pytest.mark.skipif(REDIS is not None, reason=f"Redis at {REDIS_URL}: {REDIS}")
def test_another_worker_prepares_a_changed_domain_off_its_loop_when_it_reads_it(
    two_workers: tuple[TestClient, TestClient, ServiceState], calls: Calls
) -> None:
    a, b, other = two_workers
    admin = {"X-API-Key": other.admin_key}
    assert a.put("/domains/maze", json={"map": MAZE}, headers=admin).status_code == 201
    searched = sum(what == "guide searches" for what, _ in calls)
    # worker b reads the new domain on its next request that uses it, and prepares it there
    # (its refresh, in a worker thread) before the session opens: no 503
    r = b.post("/domains/maze/sessions", json={"strategy": "guide"})
    assert r.status_code == 201, r.text
    state = other.catalog.get("maze")
    assert state.guide_map is not None and state.goal_priors is not None
    assert sum(what == "guide searches" for what, _ in calls) == searched + 1
    # the same map put again by a: b carries what it built over, with the new alpha0
    body = {"map": MAZE, "alpha0": 2.0}
    assert a.put("/domains/maze", json=body, headers=admin).status_code == 200
    r = b.post("/domains/maze/sessions", json={"strategy": "goal_aware"})
    assert r.status_code == 201, r.text
    assert sum(what == "guide searches" for what, _ in calls) == searched + 1
    goals = other.catalog.get("maze").goal_priors
    assert goals is not None and goals.alpha0 == 2.0
    on_the_loop = [what for what, loop in calls if loop]
    assert on_the_loop == [], f"built on an event loop: {on_the_loop}"


@pytest.mark.parametrize("n", [0, 1, 7, 65_536, 65_537, 131_073, 300_001])
def test_what_is_made_a_slice_at_a_time_is_what_one_call_makes(n: int) -> None:
    """theta's answer text and the Python sequences the single-event forms index, made in
    slices so that other threads run between them, are the same bytes and numbers."""
    values = np.random.default_rng(n).random(n)
    assert encode_module.numbers_text(values) == orjson.dumps(values, option=encode_module.NUMPY)
    assert grid_module.packed(values, "d").tolist() == values.tolist()
    ints = np.arange(n, dtype=np.int64).reshape(-1, 1) * 3 - 5
    assert grid_module.packed(ints, "q").tolist() == ints.reshape(-1).tolist()
