"""Regions, placement of start and goals, generated buildings, the metric frame."""

from __future__ import annotations

import math
from collections import deque
from itertools import pairwise

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.domain.generate import generate_building
from app.domain.grid import Frame, GridDomain, MapError
from app.domain.place import components, largest_region, parse_cells, place, room_cells

grids = st.builds(
    lambda rows, cols, p, seed: np.random.default_rng(seed).random((rows, cols)) < p,
    st.integers(1, 14),
    st.integers(1, 14),
    st.floats(0.2, 0.9),
    st.integers(0, 2**31),
)


def slow_components(free: np.ndarray) -> list[set[tuple[int, int]]]:
    """Flood fill from each unvisited free cell (the obviously correct version)."""
    seen: set[tuple[int, int]] = set()
    out = []
    rows, cols = free.shape
    for r in range(rows):
        for c in range(cols):
            if not free[r, c] or (r, c) in seen:
                continue
            region = {(r, c)}
            queue = deque([(r, c)])
            while queue:
                i, j = queue.popleft()
                for di, dj in ((-1, 0), (1, 0), (0, -1), (0, 1)):
                    ni, nj = i + di, j + dj
                    ok = 0 <= ni < rows and 0 <= nj < cols and free[ni, nj]
                    if ok and (ni, nj) not in region:
                        region.add((ni, nj))
                        queue.append((ni, nj))
            seen |= region
            out.append(region)
    return out


@settings(max_examples=150, deadline=None)
@given(grids)
def test_components_match_flood_fill(free: np.ndarray) -> None:
    label = components(free)
    regions = slow_components(free)
    assert label.max() + 1 == len(regions)
    for k, region in enumerate(regions):  # numbered in row-major order of their first cell
        assert {tuple(map(int, x)) for x in np.argwhere(label == k)} == region
    assert (label[~free] == -1).all()


@settings(max_examples=100, deadline=None)
@given(grids)
def test_largest_region_keeps_the_largest_and_counts_the_rest(free: np.ndarray) -> None:
    if not free.any():
        with pytest.raises(MapError, match="no free cell"):
            largest_region(free)
        return
    kept, dropped = largest_region(free)
    sizes = [len(r) for r in slow_components(free)]
    assert int(kept.sum()) == max(sizes)
    assert dropped == sum(sizes) - max(sizes)
    assert (kept <= free).all()
    assert len(slow_components(kept)) == 1


@settings(max_examples=100, deadline=None)
@given(grids, st.integers(1, 6), st.integers(0, 1000))
def test_place_gives_a_valid_domain_with_spread_goals(
    free: np.ndarray, n_goals: int, seed: int
) -> None:
    if not free.any():
        return
    kept, _ = largest_region(free)
    if kept.sum() < n_goals + 1:
        with pytest.raises(MapError, match="do not fit"):
            place(kept, np.random.default_rng(seed), n_goals=n_goals)
        return
    rows = place(kept, np.random.default_rng(seed), n_goals=n_goals)
    d = GridDomain.from_strings(rows)
    assert len(d.goals) == n_goals
    assert d.n_states == kept.sum()
    assert rows == place(kept, np.random.default_rng(seed), n_goals=n_goals)


def test_place_picks_far_rooms_and_dead_ends_over_corridor_cells() -> None:
    # a corridor from the start to a room at its far end
    text = [
        "###########",
        "#.........#",
        "#.#####...#",
        "#.#####...#",
        "#.#####...#",
        "#.#########",
        "###########",
    ]
    free = np.array([[ch != "#" for ch in r] for r in text])
    rows = place(free, np.random.default_rng(0), start=(5, 1), n_goals=1)
    d = GridDomain.from_strings(rows)
    goal = d.cell(d.goals[0])
    assert goal == (3, 8)  # the room cell farthest from the start, not the room's corner
    assert room_cells(free)[3, 8] and not room_cells(free)[1, 3]


def test_place_uses_given_cells_and_names_bad_ones() -> None:
    free = np.ones((3, 4), dtype=bool)
    rows = place(free, np.random.default_rng(0), start=(0, 0), goals=[(2, 3), (1, 1)])
    assert rows == ["S...", ".G..", "...G"]
    for kwargs, message in [
        ({"start": (5, 0)}, r"start \[5, 0\] is off the 3x4 map"),
        ({"goals": [(0, 0)], "start": (0, 0)}, "is the start"),
        ({"goals": [(1, 1), (1, 1)]}, "given twice"),
        ({"goals": []}, "at least one goal"),
    ]:
        with pytest.raises(MapError, match=message):
            place(free, np.random.default_rng(0), **kwargs)  # type: ignore[arg-type]
    walled = free.copy()
    walled[1, 1] = False
    with pytest.raises(MapError, match=r"goal \[1, 1\] is a wall"):
        place(walled, np.random.default_rng(0), goals=[(1, 1)])


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 5), st.integers(2, 5), st.integers(0, 2**31))
def test_place_never_picks_a_given_goal_as_the_start(rows: int, cols: int, seed: int) -> None:
    """The start is picked among the cells that are not given goals, however many there are
    (the farthest cell from the first one is usually a goal here: a corner)."""
    free = np.ones((rows, cols), dtype=bool)
    rng = np.random.default_rng(seed)
    cells = [(r, c) for r in range(rows) for c in range(cols)]
    keep = int(rng.integers(len(cells)))  # the one cell left for the start
    goals = [x for k, x in enumerate(cells) if k != keep]
    grid = place(free, rng, goals=goals)
    assert grid[cells[keep][0]][cells[keep][1]] == "S"
    with pytest.raises(MapError, match="no cell is left for the start"):
        place(free, rng, goals=cells)


@pytest.mark.parametrize(("text", "cells"), [("3,7", [(3, 7)]), (" 1, 2 ; 3,4;", [(1, 2), (3, 4)])])
def test_parse_cells_reads_row_col_lists(text: str, cells: list[tuple[int, int]]) -> None:
    assert parse_cells(text, "--goal-cells") == cells


@pytest.mark.parametrize("text", ["", "3", "a,b", "1,2,3", ";;"])
def test_parse_cells_names_the_bad_item(text: str) -> None:
    with pytest.raises(ValueError, match="--goal-cells"):
        parse_cells(text, "--goal-cells")


@settings(max_examples=40, deadline=None)
@given(st.integers(5, 90), st.integers(5, 90), st.integers(0, 2**31), st.integers(1, 3))
def test_generated_building_is_valid_and_reproducible(
    rows: int, cols: int, seed: int, corridor: int
) -> None:
    text = generate_building(rows, cols, np.random.default_rng(seed), n_goals=2, corridor=corridor)
    assert text == generate_building(
        rows, cols, np.random.default_rng(seed), n_goals=2, corridor=corridor
    )
    d = GridDomain.from_strings(text)  # validates: one region, a start, goals
    assert d.shape == (rows, cols)
    assert len(d.goals) == 2
    grid = np.array([list(r) for r in text])
    assert (grid[0] == "#").all() and (grid[-1] == "#").all()  # the outer wall
    assert (grid[:, 0] == "#").all() and (grid[:, -1] == "#").all()


def test_generated_building_has_rooms_and_corridors() -> None:
    text = generate_building(64, 64, np.random.default_rng(0), n_goals=8)
    d = GridDomain.from_strings(text)
    free = np.array([[ch != "#" for ch in r] for r in text])
    assert d.n_states > 2000
    assert room_cells(free).sum() > 0.15 * d.n_states  # much of the floor is rooms
    assert text != generate_building(64, 64, np.random.default_rng(1), n_goals=8)
    # every goal is in a room (its 3x3 neighbourhood is free), not in a corridor
    rooms = room_cells(free)
    assert all(rooms[d.cell(g)] or len(d.open_moves[g].nonzero()[0]) == 1 for g in d.goals)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"rows": 2, "cols": 9}, "at least 3 rows"),
        ({"corridor": 0}, "corridor"),
        ({"room": (4, 2)}, "room sides"),
        ({"loops": 2.0}, "loops"),
    ],
)
def test_generate_building_rejects_bad_parameters(kwargs: dict[str, object], message: str) -> None:
    args: dict[str, object] = {"rows": 20, "cols": 20} | kwargs
    with pytest.raises(ValueError, match=message):
        generate_building(rng=np.random.default_rng(0), **args)  # type: ignore[arg-type]


@settings(max_examples=200, deadline=None)
@given(
    st.floats(0.01, 5.0),
    st.tuples(st.floats(-100, 100), st.floats(-100, 100), st.floats(-math.pi, math.pi)),
    st.integers(1, 50),
    st.integers(0, 49),
    st.integers(0, 49),
)
def test_frame_centre_of_a_cell_maps_back_to_it(
    res: float, origin: tuple[float, float, float], n_rows: int, row: int, col: int
) -> None:
    frame = Frame(res, origin)
    x, y = frame.centre(row, col, n_rows)
    assert frame.cell_at(x, y, n_rows) == (row, col)


def test_frame_follows_ros_convention() -> None:
    frame = Frame(0.5, (10.0, 20.0, 0.0))
    assert frame.cell_at(10.1, 20.1, 4) == (3, 0)  # the lower-left cell
    assert frame.cell_at(11.2, 21.9, 4) == (0, 2)  # y up: row 0 is the top
    turned = Frame(1.0, (0.0, 0.0, math.pi / 2))  # columns run north
    assert turned.cell_at(-0.5, 2.5, 3) == (2, 2)


def test_map_text_with_header_round_trips() -> None:
    text = "resolution: 0.25\norigin: -1.5 2 0.1\n#####\n#S.G#\n#####"
    d = GridDomain.from_text(text, name="x")
    assert d.frame == Frame(0.25, (-1.5, 2.0, 0.1))
    again = GridDomain.from_text(d.to_text())
    assert again.frame == d.frame and again.rows_text == d.rows_text
    plain = GridDomain.from_text("#####\n#S.G#\n#####")
    assert plain.frame is None and plain.to_text() == "#####\n#S.G#\n#####"
    x, y = d.frame.centre(1, 3, 3)
    assert d.state_at(x, y) == d.goals[0]
    with pytest.raises(ValueError, match="is a wall"):
        d.state_at(*d.frame.centre(0, 0, 3))
    with pytest.raises(ValueError, match="no resolution"):
        plain.state_at(0.0, 0.0)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("size: 3\n#####\n#S.G#\n#####", "line 1: unknown header 'size'"),
        ("origin: 1 2\n#####\n#S.G#\n#####", "origin without resolution"),
        ("resolution: fast\n#####\n#S.G#\n#####", "line 1: resolution 'fast' is not a number"),
        ("resolution: -1\n#####\n#S.G#\n#####", "line 1: resolution must be a positive number"),
        ("resolution: nan\n#####\n#S.G#\n#####", "resolution must be a positive number"),
        ("resolution: 1\norigin: 1\n#####\n#S.G#\n#####", "line 2: origin '1'"),
        ("resolution: 1\nresolution: 2\n#####\n#S.G#\n#####", "line 2: resolution given twice"),
        ("resolution: 1\n#####\n#S.G#\n##x##", "line 4, column 3: unknown character"),
    ],
)
def test_map_header_errors_name_the_line(text: str, message: str) -> None:
    with pytest.raises(MapError, match=message):
        GridDomain.from_text(text)


@settings(max_examples=100, deadline=None)
@given(st.integers(0, 2**31), st.integers(0, 12))
def test_path_within_is_a_shortest_path_or_none(seed: int, limit: int) -> None:
    from app.domain.generate import generate_maze
    from app.domain.paths import path_within

    rng = np.random.default_rng(seed)
    d = GridDomain.from_strings(generate_maze(11, 11, rng, braid=0.5, n_goals=1))
    a, b = (int(v) for v in rng.integers(d.n_states, size=2))
    dist = int(d.distances_to(b)[a])
    path = path_within(d, a, b, limit)
    if dist > limit:
        assert path is None
        return
    assert path is not None and path[0] == a and path[-1] == b and len(path) == dist + 1
    assert all(d.move_between(s, t) is not None for s, t in pairwise(path))
