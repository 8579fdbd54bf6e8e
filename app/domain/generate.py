"""Seeded map generation: mazes (as in the paper's Figure 4) and buildings.

Mazes: corridors are one cell wide on a lattice of cells at even (row, col); the walls between
them sit at odd positions. A perfect maze has exactly one path between any two cells; ``braid``
is the probability of opening each dead end into a neighbouring corridor, which adds loops.
The start is the lower-left cell; goals go to the other three corners and then to dead ends
(corridor ends).

Buildings (:func:`generate_building`): a floor of rooms along corridors, as offices and wards
are laid out. The floor is split recursively along its longer side: a block with room for
rooms on both sides of a corridor gets a corridor across it (``corridor`` cells wide); a block
too large for one room is split by a wall; what remains is a room. Corridors meeting at a
junction are joined; then doors (one wall cell) join every room to the rest, a corridor door
preferred to a door into the next room, chosen as a random spanning tree over the rooms and
corridors; ``loops`` is the chance of a second door between two spaces already joined. The
start is the corridor cell nearest the lower-left corner (the entrance); the destinations are
picked in rooms and dead ends, spread out (:func:`app.domain.place.place`).
"""

from __future__ import annotations

import numpy as np

from app.arrays import BoolArray
from app.domain.grid import FREE, GOAL, START, WALL, GridDomain
from app.domain.place import components, place


def generate_maze(
    rows: int,
    cols: int,
    rng: np.random.Generator,
    *,
    braid: float = 0.0,
    n_goals: int = 8,
) -> list[str]:
    """An ASCII map of ``rows`` x ``cols`` (each at least 3), start lower-left, ``n_goals`` goals.

    ``braid`` in [0, 1]: 0 gives a perfect maze, 1 removes (almost) every dead end.
    """
    if rows < 3 or cols < 3:
        raise ValueError(f"a maze needs at least 3 rows and 3 columns, got {rows}x{cols}")
    if not 0.0 <= braid <= 1.0:
        raise ValueError(f"braid must be in [0, 1], got {braid}")
    if n_goals < 1:
        raise ValueError(f"n_goals must be at least 1, got {n_goals}")
    h, w = (rows + 1) // 2, (cols + 1) // 2
    free = np.zeros((rows, cols), dtype=bool)
    free[0 : 2 * h - 1 : 2, 0 : 2 * w - 1 : 2] = True
    _carve_spanning_tree(free, h, w, rng)
    if braid > 0:
        _braid(free, h, w, braid, rng)

    start = (2 * h - 2, 0)
    corners = [(0, 0), (0, 2 * w - 2), (2 * h - 2, 2 * w - 2)]
    dead = [c for c in _dead_ends(free, h, w) if c != start and c not in corners]
    rng.shuffle(dead)
    goals: list[tuple[int, int]] = [c for c in corners if c != start][:n_goals]
    goals += dead[: max(0, n_goals - len(goals))]
    if len(goals) < n_goals:
        rest = [
            (int(r), int(c))
            for r, c in np.argwhere(free)
            if (int(r), int(c)) != start and (int(r), int(c)) not in goals
        ]
        rng.shuffle(rest)
        goals += rest[: n_goals - len(goals)]
    if len(goals) < n_goals:
        raise ValueError(f"a {rows}x{cols} maze has room for only {len(goals)} goals")

    grid = np.where(free, FREE, WALL).astype("<U1")
    grid[start] = START
    for g in goals:
        grid[g] = GOAL
    return ["".join(r) for r in grid]


def generate_domain(
    rows: int, cols: int, seed: int, *, braid: float = 0.0, n_goals: int = 8
) -> GridDomain:
    """:func:`generate_maze` wrapped as a validated :class:`GridDomain`."""
    text = generate_maze(rows, cols, np.random.default_rng(seed), braid=braid, n_goals=n_goals)
    kind = "perfect" if braid == 0 else f"braid{braid:g}"
    return GridDomain.from_strings(text, name=f"gen-{rows}x{cols}-{kind}-s{seed}")


def generate_building(
    rows: int,
    cols: int,
    rng: np.random.Generator,
    *,
    n_goals: int = 8,
    corridor: int = 2,
    room: tuple[int, int] = (3, 7),
    loops: float = 0.1,
) -> list[str]:
    """An ASCII floor plan of ``rows`` x ``cols`` (each at least 3, outer wall included).

    ``corridor``: corridor width in cells (at least 1); ``room``: the least and largest room
    side in cells; ``loops`` in [0, 1]: the chance of an extra door between joined spaces."""
    if rows < 3 or cols < 3:
        raise ValueError(f"a building needs at least 3 rows and 3 columns, got {rows}x{cols}")
    lo, hi = room
    if corridor < 1:
        raise ValueError(f"corridor must be at least 1 cell wide, got {corridor}")
    if not 1 <= lo <= hi:
        raise ValueError(f"room sides must satisfy 1 <= least <= largest, got {lo}, {hi}")
    if not 0.0 <= loops <= 1.0:
        raise ValueError(f"loops must be in [0, 1], got {loops}")
    free, hall = building_layout(rows, cols, rng, corridor=corridor, room=room)
    doors(free, hall, loops, rng)
    cells = np.argwhere(hall if hall.any() else free)
    start = cells[np.argmin(cells[:, 1] - cells[:, 0])]  # nearest the lower-left corner
    return place(free, rng, start=(int(start[0]), int(start[1])), n_goals=n_goals)


def building_layout(
    rows: int, cols: int, rng: np.random.Generator, *, corridor: int, room: tuple[int, int]
) -> tuple[BoolArray, BoolArray]:
    """A floor's rooms and corridors, no door yet (the recursive split of the module
    docstring): (free cells, corridor cells). :func:`doors` joins them."""
    lo, hi = room
    free = np.zeros((rows, cols), dtype=bool)
    hall = np.zeros((rows, cols), dtype=bool)
    blocks = [(1, 1, rows - 2, cols - 2)]
    while blocks:
        r0, c0, r1, c1 = blocks.pop()
        h, w = r1 - r0 + 1, c1 - c0 + 1
        if h <= 0 or w <= 0:
            continue
        along_rows = h > w or (h == w and bool(rng.integers(2)))
        length = h if along_rows else w
        if length >= 2 * hi + corridor + 2:  # rooms on both sides of a corridor
            p = int(rng.integers(lo + 1, length - lo - corridor)) + (r0 if along_rows else c0)
            if along_rows:
                free[p : p + corridor, c0 : c1 + 1] = hall[p : p + corridor, c0 : c1 + 1] = True
                blocks += [(r0, c0, p - 2, c1), (p + corridor + 1, c0, r1, c1)]
            else:
                free[r0 : r1 + 1, p : p + corridor] = hall[r0 : r1 + 1, p : p + corridor] = True
                blocks += [(r0, c0, r1, p - 2), (r0, p + corridor + 1, r1, c1)]
        elif length > hi and length >= 2 * lo + 1:  # two rooms' worth: a wall between them
            p = int(rng.integers(lo, length - lo)) + (r0 if along_rows else c0)
            if along_rows:
                blocks += [(r0, c0, p - 1, c1), (p + 1, c0, r1, c1)]
            else:
                blocks += [(r0, c0, r1, p - 1), (r0, p + 1, r1, c1)]
        else:
            free[r0 : r1 + 1, c0 : c1 + 1] = True
    _join_corridors(free, hall)
    return free, hall


def generate_building_domain(
    rows: int, cols: int, seed: int, *, n_goals: int = 8, corridor: int = 2
) -> GridDomain:
    """:func:`generate_building` wrapped as a validated :class:`GridDomain`."""
    rng = np.random.default_rng(seed)
    text = generate_building(rows, cols, rng, n_goals=n_goals, corridor=corridor)
    return GridDomain.from_strings(text, name=f"building-{rows}x{cols}-s{seed}")


def _between(free: BoolArray) -> tuple[BoolArray, BoolArray]:
    """Wall cells with free cells on both sides: north and south, west and east."""
    wall = ~free
    ns = np.zeros_like(free)
    we = np.zeros_like(free)
    ns[1:-1, :] = wall[1:-1, :] & free[:-2, :] & free[2:, :]
    we[:, 1:-1] = wall[:, 1:-1] & free[:, :-2] & free[:, 2:]
    return ns, we


def _join_corridors(free: BoolArray, hall: BoolArray) -> None:
    """Open the wall cells that separate two corridors (where a corridor ends at another)."""
    ns, we = _between(free)
    join = np.zeros_like(free)
    join[1:-1, :] |= ns[1:-1, :] & hall[:-2, :] & hall[2:, :]
    join[:, 1:-1] |= we[:, 1:-1] & hall[:, :-2] & hall[:, 2:]
    free |= join
    hall |= join


def doors(free: BoolArray, hall: BoolArray, loops: float, rng: np.random.Generator) -> None:
    """Doors (``free`` changed in place): a random spanning tree over the spaces (corridor
    doors first), then extras, each with chance ``loops``."""
    label = components(free)
    ns, we = _between(free)
    ways: dict[tuple[int, int], list[tuple[int, int]]] = {}
    for mask, (dr, dc) in ((ns, (1, 0)), (we, (0, 1))):
        for r, c in np.argwhere(mask).tolist():
            a, b = int(label[r - dr, c - dc]), int(label[r + dr, c + dc])
            if a != b:
                ways.setdefault((min(a, b), max(a, b)), []).append((r, c))
    pairs = list(ways)
    order = rng.permutation(len(pairs))
    rank = [
        (0 if any(hall[r, c] for r, c in _sides(ways[pairs[i]][0], free)) else 1, k)
        for k, i in enumerate(order)
    ]
    parent = list(range(int(label.max()) + 1))

    def root(x: int) -> int:
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for _, k in sorted(rank):
        a, b = pairs[order[k]]
        ra, rb = root(a), root(b)
        joined = ra == rb
        if joined and rng.random() >= loops:
            continue
        parent[ra] = rb
        options = ways[(a, b)]
        r, c = options[int(rng.integers(len(options)))]
        free[r, c] = True


def _sides(cell: tuple[int, int], free: BoolArray) -> list[tuple[int, int]]:
    r, c = cell
    rows, cols = free.shape
    return [
        (r + dr, c + dc)
        for dr, dc in _STEPS
        if 0 <= r + dr < rows and 0 <= c + dc < cols and free[r + dr, c + dc]
    ]


_STEPS = ((-1, 0), (0, 1), (1, 0), (0, -1))


def _carve_spanning_tree(free: np.ndarray, h: int, w: int, rng: np.random.Generator) -> None:
    """Randomised depth-first search over the cell lattice (the 'recursive backtracker')."""
    visited = np.zeros((h, w), dtype=bool)
    stack = [(h - 1, 0)]
    visited[h - 1, 0] = True
    while stack:
        i, j = stack[-1]
        options = [
            (i + di, j + dj)
            for di, dj in _STEPS
            if 0 <= i + di < h and 0 <= j + dj < w and not visited[i + di, j + dj]
        ]
        if not options:
            stack.pop()
            continue
        ni, nj = options[int(rng.integers(len(options)))]
        free[i + ni, j + nj] = True  # the wall cell between (2i, 2j) and (2ni, 2nj)
        visited[ni, nj] = True
        stack.append((ni, nj))


def _dead_ends(free: np.ndarray, h: int, w: int) -> list[tuple[int, int]]:
    out = []
    for i in range(h):
        for j in range(w):
            if _open_count(free, 2 * i, 2 * j) == 1:
                out.append((2 * i, 2 * j))
    return out


def _open_count(free: np.ndarray, r: int, c: int) -> int:
    rows, cols = free.shape
    return sum(
        1 for dr, dc in _STEPS if 0 <= r + dr < rows and 0 <= c + dc < cols and free[r + dr, c + dc]
    )


def _braid(free: np.ndarray, h: int, w: int, braid: float, rng: np.random.Generator) -> None:
    order = _dead_ends(free, h, w)
    rng.shuffle(order)
    for r, c in order:
        if _open_count(free, r, c) != 1 or rng.random() >= braid:
            continue
        closed = [
            (dr, dc)
            for dr, dc in _STEPS
            if 0 <= r + 2 * dr < 2 * h - 1
            and 0 <= c + 2 * dc < 2 * w - 1
            and not free[r + dr, c + dc]
        ]
        if not closed:
            continue
        # prefer opening into another dead end: removes two at once, as braided mazes do
        ends = [d for d in closed if _open_count(free, r + 2 * d[0], c + 2 * d[1]) == 1]
        pick = ends or closed
        dr, dc = pick[int(rng.integers(len(pick)))]
        free[r + dr, c + dc] = True
