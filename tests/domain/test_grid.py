from __future__ import annotations

import heapq
from collections import deque

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from app.domain.generate import generate_building, generate_maze
from app.domain.grid import (
    ACTIONS,
    MOVES,
    GridDomain,
    MapError,
    action_index,
    compass_detours,
    compass_detours_each,
    compass_moves,
    validate_map,
)
from app.domain.maps import DEFAULT_MAP

SMALL = ["S..#", ".#..", "...G"]


def slow_next_state(rows: list[str], r: int, c: int, a: int) -> tuple[int, int]:
    dr, dc = MOVES[a]
    nr, nc = r + dr, c + dc
    if 0 <= nr < len(rows) and 0 <= nc < len(rows[0]) and rows[nr][nc] != "#":
        return nr, nc
    return r, c


def slow_bfs(rows: list[str], target: tuple[int, int]) -> dict[tuple[int, int], int]:
    dist = {target: 0}
    q = deque([target])
    while q:
        r, c = q.popleft()
        for a in range(4):
            n = slow_next_state(rows, r, c, a)
            if n not in dist:
                dist[n] = dist[(r, c)] + 1
                q.append(n)
    return dist


maps = st.builds(
    lambda rows, cols, seed, braid: generate_maze(
        rows, cols, np.random.default_rng(seed), braid=braid, n_goals=3
    ),
    st.integers(3, 25),
    st.integers(3, 25),
    st.integers(0, 10_000),
    st.sampled_from([0.0, 0.3, 1.0]),
)


def test_grid_small_map_states_and_moves() -> None:
    d = GridDomain.from_strings(SMALL)
    assert d.shape == (3, 4)
    assert d.n_states == 10
    assert d.cell(d.start) == (0, 0)
    assert [d.cell(g) for g in d.goals] == [(2, 3)]
    s = d.start
    assert d.step(s, action_index("N")) == s  # off the map
    assert d.cell(d.step(s, action_index("E"))) == (0, 1)
    assert d.cell(d.step(d.state(0, 2), action_index("E"))) == (0, 2)  # into a wall
    assert d.move_between(s, d.state(1, 0)) == action_index("S")
    assert d.move_between(s, s) is None
    assert d.move_between(s, d.state(2, 2)) is None  # not adjacent


@given(maps)
def test_grid_transition_table_matches_slow_version(rows: list[str]) -> None:
    d = GridDomain.from_strings(rows)
    for s in range(d.n_states):
        r, c = d.cell(s)
        for a in range(4):
            assert d.cell(d.step(s, a)) == slow_next_state(rows, r, c, a)


@given(maps)
def test_grid_bfs_distances_match_slow_version(rows: list[str]) -> None:
    d = GridDomain.from_strings(rows)
    for i, g in enumerate(d.goals):
        slow = slow_bfs(rows, d.cell(g))
        fast = d.distances_to(g)
        together = d.goal_distances[i]  # every goal's search at once
        assert all(fast[s] == slow[d.cell(s)] for s in range(d.n_states))
        assert all(together[s] == slow[d.cell(s)] for s in range(d.n_states))


def slow_compass_moves(rows: list[str], r: int, c: int, target: tuple[int, int]) -> set[int]:
    """Someone heading for ``target`` as the crow flies (the paper's bug, spelled out): the
    axis of the larger difference first if open, else the other if open; both on a tie."""
    dr, dc = target[0] - r, target[1] - c
    vertical = [2 if dr > 0 else 0] if dr != 0 else []
    horizontal = [1 if dc > 0 else 3] if dc != 0 else []
    open_ = [a for a in vertical + horizontal if slow_next_state(rows, r, c, a) != (r, c)]
    if abs(dr) == abs(dc):
        return set(open_)
    order = vertical + horizontal if abs(dr) > abs(dc) else horizontal + vertical
    return {next(a for a in order if a in open_)} if open_ else set()


def slow_detours(rows: list[str], target: tuple[int, int]) -> dict[tuple[int, int], int]:
    """Dijkstra over cells: a move costs 0 if it is one of the mover's own compass moves."""
    free = [(r, c) for r, row in enumerate(rows) for c, ch in enumerate(row) if ch != "#"]
    into: dict[tuple[int, int], list[tuple[tuple[int, int], int]]] = {}
    for cell in free:
        for a in range(4):
            nxt = slow_next_state(rows, *cell, a)
            if nxt != cell:
                into.setdefault(nxt, []).append((cell, a))
    best = {target: 0}
    queue = [(0, target)]
    while queue:
        cost, v = heapq.heappop(queue)
        if cost > best[v]:
            continue
        for u, a in into.get(v, []):
            c = cost + (0 if a in slow_compass_moves(rows, *u, target) else 1)
            if c < best.get(u, 1 << 30):
                best[u] = c
                heapq.heappush(queue, (c, u))
    return best


buildings = st.builds(
    lambda rows, cols, seed: generate_building(rows, cols, np.random.default_rng(seed), n_goals=3),
    st.integers(16, 30),
    st.integers(16, 30),
    st.integers(0, 10_000),
)


@given(st.one_of(maps, buildings), st.data())
def test_compass_moves_and_detours_match_slow_versions(
    rows: list[str], data: st.DataObject
) -> None:
    d = GridDomain.from_strings(rows)
    # every goal, and any free cells as targets, several at once (repeats allowed)
    extra = data.draw(st.lists(st.integers(0, d.n_states - 1), max_size=4))
    targets = [*d.goals, *extra]
    together = compass_detours_each(d.next_state, d.cells, targets)
    for i, g in enumerate(targets):
        target = d.cell(g)
        own = compass_moves(d.next_state, d.cells, g)
        slow = slow_detours(rows, target)
        fast = compass_detours(d.next_state, d.cells, g)
        for s in range(d.n_states):
            assert set(np.flatnonzero(own[s])) == slow_compass_moves(rows, *d.cell(s), target)
            assert fast[s] == slow[d.cell(s)]
            assert together[i, s] == slow[d.cell(s)]


@given(maps)
def test_grid_dead_ends_have_one_open_move(rows: list[str]) -> None:
    d = GridDomain.from_strings(rows)
    open_count = [
        sum(slow_next_state(rows, *d.cell(s), a) != d.cell(s) for a in range(4))
        for s in range(d.n_states)
    ]
    assert sorted(d.dead_ends.tolist()) == [s for s, k in enumerate(open_count) if k == 1]


@pytest.mark.parametrize(
    ("rows", "message"),
    [
        ([], "the map is empty"),
        (["S.G", "..", "..."], "line 2: ragged row: 2 characters where row 1 has 3"),
        (["S.G", ".x."], "line 2, column 2: unknown character 'x'"),
        (["..G", "..."], "no start"),
        (["S.G", "..S"], "2 starts (line 1 column 1, line 2 column 3)"),
        (["S..", "..."], "no goal"),
        (["S.#G", "..#."], "line 1, column 4: goal unreachable from the start"),
        (["S.#.", "G.#."], "line 1, column 4: free cell unreachable from the start"),
    ],
)
def test_grid_loader_rejects_bad_map_with_message(rows: list[str], message: str) -> None:
    with pytest.raises(MapError) as err:
        GridDomain.from_strings(rows)
    assert message in str(err.value)


def test_grid_loader_rejects_single_string() -> None:
    with pytest.raises(MapError, match="list of row strings"):
        validate_map("S.G")


def test_grid_loader_reports_line_and_column_attributes() -> None:
    with pytest.raises(MapError) as err:
        GridDomain.from_strings(["S.G", ".?."])
    assert (err.value.line, err.value.column) == (2, 2)


def test_grid_from_file_ignores_trailing_newlines_and_cr(tmp_path) -> None:  # type: ignore[no-untyped-def]
    p = tmp_path / "m.txt"
    p.write_bytes(b"S.G\r\n...\r\n\r\n")
    d = GridDomain.from_file(p)
    assert d.shape == (2, 3)
    assert d.name == "m"


def test_grid_from_missing_file_is_map_error(tmp_path) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(MapError, match="cannot read map file"):
        GridDomain.from_file(tmp_path / "nope.txt")


def test_grid_state_rejects_wall_and_off_map() -> None:
    d = GridDomain.from_strings(SMALL)
    with pytest.raises(ValueError, match="is a wall"):
        d.state(0, 3)
    with pytest.raises(ValueError, match="off the 3x4 map"):
        d.state(3, 0)


@pytest.mark.parametrize(("given_", "index"), [("N", 0), ("e", 1), (" S ", 2), (3, 3)])
def test_action_index_accepts_names_and_numbers(given_: str | int, index: int) -> None:
    assert action_index(given_) == index
    assert ACTIONS[index] == ACTIONS[action_index(ACTIONS[index])]


@pytest.mark.parametrize("bad", ["X", "", 4, -1, True, 1.0, None])
def test_action_index_rejects_unknown(bad: object) -> None:
    with pytest.raises(ValueError, match="use one of N, E, S, W or 0-3"):
        action_index(bad)  # type: ignore[arg-type]


def _edges(d: GridDomain) -> int:
    return int(d.open_moves.sum()) // 2


@given(st.integers(3, 31), st.integers(3, 31), st.integers(0, 10_000))
def test_generate_perfect_maze_is_a_spanning_tree(rows: int, cols: int, seed: int) -> None:
    d = GridDomain.from_strings(generate_maze(rows, cols, np.random.default_rng(seed), n_goals=1))
    assert _edges(d) == d.n_states - 1  # connected (validated) with n-1 edges: a tree


@given(st.integers(9, 31), st.integers(9, 31), st.integers(0, 10_000))
def test_generate_braided_maze_is_valid_and_has_loops(rows: int, cols: int, seed: int) -> None:
    text = generate_maze(rows, cols, np.random.default_rng(seed), braid=1.0, n_goals=4)
    d = GridDomain.from_strings(text)  # validates: one S, goals, all reachable
    assert _edges(d) > d.n_states - 1
    assert d.cell(d.start) == (2 * ((rows + 1) // 2) - 2, 0)
    assert len(d.goals) == 4


def test_generate_is_reproducible_and_seed_dependent() -> None:
    a = generate_maze(21, 21, np.random.default_rng(5), braid=0.2)
    assert a == generate_maze(21, 21, np.random.default_rng(5), braid=0.2)
    assert a != generate_maze(21, 21, np.random.default_rng(6), braid=0.2)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"rows": 2, "cols": 5}, "at least 3 rows"),
        ({"rows": 5, "cols": 5, "braid": 1.5}, "braid must be in"),
        ({"rows": 5, "cols": 5, "n_goals": 0}, "n_goals must be"),
        ({"rows": 3, "cols": 3, "n_goals": 50}, "room for only"),
    ],
)
def test_generate_rejects_bad_parameters(kwargs: dict[str, float], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        generate_maze(rng=np.random.default_rng(0), **kwargs)  # type: ignore[arg-type]


def _left_hand_reaches(d: GridDomain, goal: int, steps: int = 5000) -> bool:
    s, heading = d.start, 0
    for _ in range(steps):
        if s == goal:
            return True
        for turn in (-1, 0, 1, 2):
            a = (heading + turn) % 4
            if d.next_state[s, a] != s:
                heading, s = a, int(d.next_state[s, a])
                break
    return s == goal


def test_default_map_is_the_paper_like_maze() -> None:
    d = GridDomain.from_file(DEFAULT_MAP)
    assert d.shape == (30, 30)
    rows, _ = d.shape
    assert d.cell(d.start) == (rows - 2, 0)  # lower-left free corner (bottom row is wall)
    assert len(d.goals) == 8
    assert _edges(d) > d.n_states - 1  # it has loops
    corners = {(0, 0), (0, 28), (28, 28)}
    at_ends = [d.cell(g) in corners or g in set(d.dead_ends.tolist()) for g in d.goals]
    assert all(at_ends)
    # loops make the left-hand rule fail for some goals
    assert not all(_left_hand_reaches(d, g) for g in d.goals)
