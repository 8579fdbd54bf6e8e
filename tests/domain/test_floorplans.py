"""Generated buildings of several floors: every one is a map ``maze check`` accepts, its lifts
and stairs at the same cells on every floor, named destinations on every floor, reproducible."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.domain.building import Building, load_map
from app.domain.floorplans import NAMES, generate_floors


@settings(max_examples=40, deadline=None)
@given(
    rows=st.integers(20, 48),
    cols=st.integers(20, 48),
    n_floors=st.integers(2, 4),
    seed=st.integers(0, 2**32 - 1),
    purpose=st.sampled_from(["hospital", "office"]),
    n_goals=st.integers(1, 12),
)
def test_every_generated_building_is_a_map_maze_check_accepts(
    rows: int, cols: int, n_floors: int, seed: int, purpose: str, n_goals: int
) -> None:
    rng = np.random.default_rng(seed)
    b = generate_floors(rows, cols, n_floors, rng, purpose=purpose, n_goals=n_goals)
    again = load_map(b.to_text())  # what `maze check` does
    assert isinstance(again, Building) and again.to_text() == b.to_text()
    assert b.shape == (n_floors, rows, cols)
    assert [f.ordinal for f in b.floors] == list(range(n_floors))
    lifts = [c for c in b.connections if c.kind == "lift"]
    stairs = [c for c in b.connections if c.kind == "stairs"]
    assert lifts and len(stairs) == 2
    for conn in b.connections:  # every floor, one (row, col): each ride one floor up or down
        assert conn.floors == tuple(range(n_floors))
        assert len({(r, c) for _, r, c in conn.stops}) == 1
    (_, ra, ca), (_, rb, cb) = stairs[0].stops[0], stairs[1].stops[0]
    assert abs(ra - rb) + abs(ca - cb) >= (rows + cols) // 4  # far apart
    # destinations on every floor, every one named, none on a stair or lift
    per_floor = np.bincount(b.cells[list(b.goals), 0], minlength=n_floors)
    assert (per_floor == n_goals).all()
    assert b.goal_names is not None and None not in b.goal_names
    assert len({n.casefold() for n in b.goal_names if n}) == len(b.goals)
    assert (b.connection_of[list(b.goals)] == -1).all()
    assert b.cell(b.start)[0] == 0


def test_a_generated_building_is_the_same_from_the_same_seed_and_names_its_purpose() -> None:
    def text(seed: int, purpose: str) -> str:
        rng = np.random.default_rng(seed)
        return generate_floors(30, 40, 3, rng, purpose=purpose).to_text()

    assert text(5, "hospital") == text(5, "hospital") != text(6, "hospital")
    b = Building.from_text(text(5, "hospital"))
    assert b.goal_names is not None
    assert set(b.goal_names) <= set(NAMES["hospital"])  # 24 destinations, 40 names
    office = Building.from_text(text(5, "office"))
    assert office.goal_names is not None and set(office.goal_names) <= set(NAMES["office"])
    many = generate_floors(48, 48, 4, np.random.default_rng(0), n_goals=12)  # 48 > 40 names
    assert many.goal_names is not None and "Room 3.12" in many.goal_names


def test_generated_rides_take_the_default_costs_and_floors_stack_by_storey() -> None:
    b = generate_floors(30, 40, 3, np.random.default_rng(1))
    assert {(c.kind, c.cost) for c in b.connections} == {("lift", 12), ("stairs", 18)}
    assert [f.elevation for f in b.floors] == [0.0, 4.0, 8.0]
    assert [f.name for f in b.floors] == ["Ground floor", "Floor 1", "Floor 2"]


@pytest.mark.parametrize(
    ("args", "said"),
    [
        ((30, 30, 1), "a building of several floors has 2 to 256, got 1"),
        (
            (19, 19, 2),
            "a 19x19 plan has no corridor for the stairs and lifts: rooms on both sides of "
            "a corridor need 20 rows or columns",
        ),
        ((1024, 1024, 3), "3 floors of 1024 x 1024 cells: a building holds at most 2,097,152"),
    ],
)
def test_generate_floors_says_what_cannot_be_made(args: tuple[int, int, int], said: str) -> None:
    with pytest.raises(ValueError, match=said):
        generate_floors(*args, np.random.default_rng(0))
    with pytest.raises(ValueError, match="unknown purpose 'zoo'"):
        generate_floors(30, 30, 2, np.random.default_rng(0), purpose="zoo")


@pytest.mark.parametrize("size", [64, 128])
@pytest.mark.parametrize("seed", [0, 1])
def test_generated_buildings_of_large_floors_are_maps(size: int, seed: int) -> None:
    b = generate_floors(size, size, 4, np.random.default_rng(seed), purpose="hospital")
    again = load_map(b.to_text())
    assert isinstance(again, Building) and again.shape == (4, size, size)
    assert (again.distances_to(again.start) >= 0).all()
