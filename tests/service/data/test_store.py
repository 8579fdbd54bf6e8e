"""The repository on SQLite and PostgreSQL: domains, trajectories, counts == recount."""

from __future__ import annotations

import threading
from collections.abc import Iterator

import numpy as np
import pytest

from app.advice.priors import trajectory_counts
from app.domain.grid import GridDomain
from app.domain.paths import expert_trajectories
from app.service.data.store import POOLED, Store, Trajectory
from tests.service.conftest import TINY

DOMAIN = GridDomain.from_strings(TINY, name="tiny")
MAP = "\n".join(TINY)


@pytest.fixture
def store(db_url: str) -> Iterator[Store]:
    s = Store(db_url)
    s.create_schema()
    yield s
    s.close()


def _items(seed: int, agent_type: str | None = None, per_goal: int = 2) -> list[Trajectory]:
    rng = np.random.default_rng(seed)
    experts = expert_trajectories(DOMAIN, rng, "anywhere", per_goal)
    return [Trajectory(agent_type, e.pairs, DOMAIN.goals[0]) for e in experts]


def _assert_counts_equal(a: dict, b: dict) -> None:  # type: ignore[type-arg]
    assert sorted(a) == sorted(b)
    for key in a:
        assert a[key].n_trajectories == b[key].n_trajectories
        np.testing.assert_array_equal(a[key].counts, b[key].counts)


def test_store_put_list_delete_domain(store: Store) -> None:
    rec, created, kept = store.put_domain("tiny", MAP, 1.0)
    assert (created, kept) == (True, False)
    assert [d.name for d in store.domains()] == ["tiny"]
    assert store.domains()[0].map_text == MAP and rec.created_at.tzinfo is not None
    assert store.delete_domain("tiny") is True
    assert store.delete_domain("tiny") is False
    assert store.domains() == []


def test_store_counts_equal_recount_per_table(store: Store) -> None:
    store.put_domain("tiny", MAP, 1.0)
    plain, staff = _items(1), _items(2, "staff")
    store.add_trajectories("tiny", plain, DOMAIN.n_states)
    store.add_trajectories("tiny", staff, DOMAIN.n_states)
    counts = store.counts("tiny")
    _assert_counts_equal(counts, store.recount("tiny", DOMAIN.n_states))
    assert counts[POOLED].n_trajectories == len(plain) + len(staff)
    assert counts["staff"].n_trajectories == len(staff)
    expected = trajectory_counts([t.pairs for t in plain + staff], DOMAIN.n_states)
    np.testing.assert_array_equal(counts[POOLED].counts, expected)
    stored = store.trajectories("tiny")
    assert [t.agent_type for t in stored] == [None] * len(plain) + ["staff"] * len(staff)
    np.testing.assert_array_equal(stored[0].pairs, plain[0].pairs)
    assert stored[0].goal == DOMAIN.goals[0]


def test_store_same_map_keeps_data_new_map_drops_it(store: Store) -> None:
    store.put_domain("tiny", MAP, 1.0)
    store.add_trajectories("tiny", _items(3), DOMAIN.n_states)
    _, created, kept = store.put_domain("tiny", MAP, 2.0)
    assert (created, kept) == (False, True)
    assert store.domains()[0].alpha0 == 2.0
    assert store.counts("tiny")[POOLED].n_trajectories > 0
    _, created, kept = store.put_domain("tiny", MAP.replace("G", ".", 1), 2.0)
    assert (created, kept) == (False, False)
    assert store.counts("tiny") == {} and store.trajectories("tiny") == []


def test_store_adding_to_a_missing_domain_raises(store: Store) -> None:
    with pytest.raises(KeyError):
        store.add_trajectories("nope", _items(4), DOMAIN.n_states)


def test_store_concurrent_writers_lose_no_count(store: Store) -> None:
    store.put_domain("tiny", MAP, 1.0)
    errors: list[BaseException] = []

    def write(seed: int) -> None:
        try:
            for k in range(5):
                store.add_trajectories("tiny", _items(seed * 10 + k, "visitor", 1), DOMAIN.n_states)
        except BaseException as exc:  # surfaced below
            errors.append(exc)

    threads = [threading.Thread(target=write, args=(i,)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []
    counts = store.counts("tiny")
    assert counts[POOLED].n_trajectories == 4 * 5 * len(DOMAIN.goals)
    _assert_counts_equal(counts, store.recount("tiny", DOMAIN.n_states))


def test_store_meta_round_trip(store: Store) -> None:
    assert store.get_meta("k") is None
    store.set_meta("k", "v1")
    store.set_meta("k", "v2")
    assert store.get_meta("k") == "v2"
