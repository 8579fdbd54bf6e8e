"""Properties over random small buildings: text -> building -> text is the same text, and the
precomputed moves, rides' times and time distances are a slow obvious version's."""

from __future__ import annotations

import heapq
from collections import deque
from dataclasses import dataclass

import numpy as np
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from app.domain.building import ACTIONS, Building, D, U
from app.domain.floors import Connection, Floor, FloorName
from app.domain.grid import Frame, NamedCell
from app.domain.paths import optimal_actions, optimal_policy

Cell = tuple[int, int, int]
COMPASS = {"N": (-1, 0), "E": (0, 1), "S": (1, 0), "W": (0, -1)}


@dataclass
class Parts:
    floors: list[Floor]
    connections: list[Connection]
    names: list[FloorName]
    frame: Frame | None


def slow_step(parts: Parts, cell: Cell, action: str) -> Cell:
    """Where ``action`` leads from ``cell``, read off the rows and the connections' stops."""
    f, r, c = cell
    rows = parts.floors[f].rows
    if action in COMPASS:
        dr, dc = COMPASS[action]
        nr, nc = r + dr, c + dc
        inside = 0 <= nr < len(rows) and 0 <= nc < len(rows[0])
        return (f, nr, nc) if inside and rows[nr][nc] != "#" else cell
    for conn in parts.connections:
        if cell in conn.stops:
            up = [s for s in conn.stops if s[0] > f]
            down = [s for s in conn.stops if s[0] < f]
            if action == "U" and up:
                return min(up)
            if action == "D" and down:
                return max(down)
    return cell


def slow_time(parts: Parts, cell: Cell, action: str) -> int:
    end = slow_step(parts, cell, action)
    if end[0] == cell[0]:
        return 1
    conn = next(c for c in parts.connections if cell in c.stops)
    return conn.cost * abs(parts.floors[end[0]].ordinal - parts.floors[cell[0]].ordinal)


def free_cells(parts: Parts) -> list[Cell]:
    return [
        (f, r, c)
        for f, floor in enumerate(parts.floors)
        for r, row in enumerate(floor.rows)
        for c, ch in enumerate(row)
        if ch != "#"
    ]


@st.composite
def buildings(draw: st.DrawFn) -> Parts:
    """Valid parts: random walls, stops and goals; what the start cannot reach walled up."""
    n, rows, cols = draw(st.integers(2, 4)), draw(st.integers(1, 4)), draw(st.integers(1, 5))
    first = draw(st.integers(-3, 2))
    ordinals = [first]
    for _ in range(n - 1):
        ordinals.append(ordinals[-1] + draw(st.integers(1, 2)))
    walls = np.array(draw(st.lists(st.booleans(), min_size=n * rows * cols,
                                   max_size=n * rows * cols))).reshape(n, rows, cols)  # fmt: skip
    free: list[Cell] = [(int(f), int(r), int(c)) for f, r, c in np.argwhere(~walls)]
    assume(len(free) >= 2)
    start = free[draw(st.integers(0, len(free) - 1))]
    connections: list[Connection] = []
    taken: set[Cell] = set()
    kinds = st.sampled_from(["stairs", "lift", "escalator", "ramp"])
    for k in range(draw(st.integers(0, 4))):
        stops = []
        for f in draw(st.lists(st.integers(0, n - 1), min_size=2, max_size=n, unique=True)):
            options = [x for x in free if x[0] == f and x not in taken]
            if options:
                stops.append(options[draw(st.integers(0, len(options) - 1))])
        if len(stops) >= 2:
            taken |= set(stops)
            connections.append(Connection(draw(kinds), draw(st.integers(1, 9)), tuple(stops),
                                          f"Way {k}"))  # fmt: skip
    parts = Parts([], connections, [], None)
    grid = np.where(walls, "#", ".")
    parts.floors = [Floor(o, f"F{o}", tuple("".join(r) for r in grid[i]))
                    for i, o in enumerate(ordinals)]  # fmt: skip
    seen = {start}
    queue = deque([start])
    while queue:  # what the start reaches, by every action
        cell = queue.popleft()
        for a in ACTIONS:
            nxt = slow_step(parts, cell, a)
            if nxt not in seen:
                seen.add(nxt)
                queue.append(nxt)
    for f, r, c in free:
        if (f, r, c) not in seen:
            grid[f, r, c] = "#"
    reached = sorted(seen - {start})
    assume(reached)
    goals = draw(st.lists(st.sampled_from(reached), min_size=1, max_size=4, unique=True))
    grid[start] = "S"
    for g in goals:
        grid[g] = "G"
    elevation = draw(st.sampled_from([None, 3.5]))
    parts.floors = [
        Floor(o, f"Floor {o}", tuple("".join(r) for r in grid[i]),
              o * elevation if elevation is not None else None)
        for i, o in enumerate(ordinals)
    ]  # fmt: skip
    # a connection the start cannot reach is out of the building: all its stops went
    parts.connections = [c for c in connections if c.stops[0] in seen]
    named = draw(st.lists(st.sampled_from(goals), unique=True, max_size=len(goals)))
    parts.names = [FloorName(f, NamedCell(r, c, f"Room {i}")) for i, (f, r, c) in enumerate(named)]
    if draw(st.booleans()):
        parts.frame = Frame(draw(st.sampled_from([0.25, 0.5, 1.0])), (1.5, -2.0, 0.0))
    return parts


def build(parts: Parts) -> Building:
    return Building.from_parts(parts.floors, parts.connections, parts.names, parts.frame)


@settings(max_examples=150, deadline=None)
@given(buildings())
def test_building_text_round_trip_over_random_buildings(parts: Parts) -> None:
    b = build(parts)
    text = b.to_text()
    again = Building.from_text(text)
    assert again.to_text() == text
    assert again.floors == b.floors and again.connections == b.connections
    assert again.goal_names == b.goal_names and again.frame == b.frame
    for name in ("cells", "next_state", "rides", "connection_of", "state_of"):
        assert np.array_equal(getattr(again, name), getattr(b, name)), name
    assert (again.start, again.goals) == (b.start, b.goals)


@settings(max_examples=150, deadline=None)
@given(buildings())
def test_building_moves_and_times_are_the_slow_versions(parts: Parts) -> None:
    b = build(parts)
    cells = free_cells(parts)
    assert [b.cell(s) for s in range(b.n_states)] == cells  # floor by floor, row-major
    for s, cell in enumerate(cells):
        for a, name in enumerate(ACTIONS):
            assert b.cell(b.step(s, a)) == slow_step(parts, cell, name), (cell, name)
            assert b.durations[s, a] == slow_time(parts, cell, name), (cell, name)
    # U and D undo each other where they move
    moved = np.flatnonzero(b.next_state[:, U] != np.arange(b.n_states))
    assert np.array_equal(b.next_state[b.next_state[moved, U], D], moved)


@settings(max_examples=100, deadline=None)
@given(buildings(), st.data())
def test_building_times_to_is_dijkstra(parts: Parts, data: st.DataObject) -> None:
    b = build(parts)
    target = data.draw(st.integers(0, b.n_states - 1))
    # Dijkstra from every state towards the target, over the actions' times
    dist = {target: 0}
    heap = [(0, target)]
    while heap:  # moves are reversible at the same time: search out from the target
        t, s = heapq.heappop(heap)
        if t > dist[s]:
            continue
        for a in range(6):
            nxt, w = b.step(s, a), int(b.durations[s, a])
            if t + w < dist.get(nxt, 1 << 60):
                dist[nxt] = t + w
                heapq.heappush(heap, (t + w, nxt))
    expected = [dist.get(s, -1) for s in range(b.n_states)]
    assert b.times_to(target).tolist() == expected
    assert (b.distances_to(target) >= 0).all()  # every state reaches every other


@settings(max_examples=100, deadline=None)
@given(buildings(), st.data())
def test_experts_optimal_actions_are_every_first_action_of_a_quickest_route(
    parts: Parts, data: st.DataObject
) -> None:
    """``optimal_actions`` in a building: an action is optimal at s exactly when some route
    that starts with it reaches the goal in the fewest moves of time (the action's time plus
    the quickest time from where it leads: ``times_to``, Dijkstra's by the test above); none
    at the goal, and no action that stays."""
    b = build(parts)
    goal = data.draw(st.sampled_from(b.goals))
    opt = optimal_actions(b, goal)
    best = b.times_to(goal)
    for s in range(b.n_states):
        for a in range(6):
            nxt = b.step(s, a)
            quickest = nxt != s and int(b.durations[s, a]) + int(best[nxt]) == best[s]
            assert bool(opt[s, a]) == (quickest and s != goal), (b.cell(s), ACTIONS[a])
    policy = optimal_policy(b, goal)
    assert np.allclose(policy.sum(axis=1), (np.arange(b.n_states) != goal).astype(float))
