"""From a passability grid to a domain: the largest connected region, a start and destinations.

Imported maps (Moving AI, ROS map_server, floor plans) and generated buildings arrive as a
boolean grid of free cells. :func:`largest_region` keeps the largest 4-connected region (an
explorer cannot walk between regions) and :func:`place` marks the start and the goals, either
where asked or picked:

* the start, if not given: the cell farthest (by BFS) from the region's first cell in row-major
  order (a given goal excepted), a cell at the region's edge, as a building's entrance usually
  is;
* goals, if not given: ``n_goals`` cells spread out by BFS distance (farthest-point sampling:
  each next goal is the candidate farthest from the start and the goals already placed), the
  candidates being dead ends and cells inside rooms (cells whose 3x3 neighbourhood is all
  free), so that destinations are rooms and corridor ends rather than corridor cells.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from app.arrays import BoolArray, IntArray
from app.domain.grid import FREE, GOAL, MOVES, START, WALL, MapError

Cell = tuple[int, int]


def _neighbours(free: BoolArray) -> IntArray:
    """``nbr[i, a]``: the index (into ``np.argwhere(free)``) of free cell i's neighbour in
    direction ``a``, or ``i`` itself if that is a wall or off the grid."""
    cells = np.argwhere(free)
    index = np.full(free.shape, -1, dtype=np.int64)
    index[cells[:, 0], cells[:, 1]] = np.arange(len(cells))
    target = cells[:, None, :] + MOVES[None, :, :]
    rows, cols = free.shape
    inside = (
        (target[..., 0] >= 0)
        & (target[..., 0] < rows)
        & (target[..., 1] >= 0)
        & (target[..., 1] < cols)
    )
    hit = index[np.clip(target[..., 0], 0, rows - 1), np.clip(target[..., 1], 0, cols - 1)]
    own = np.arange(len(cells))[:, None]
    out: IntArray = np.where(inside & (hit >= 0), hit, own)
    return out


def _bfs(nbr: IntArray, source: int) -> IntArray:
    dist = np.full(nbr.shape[0], -1, dtype=np.int64)
    dist[source] = 0
    frontier = np.array([source], dtype=np.int64)
    d = 0
    while frontier.size:
        d += 1
        nxt = np.unique(nbr[frontier].ravel())
        frontier = nxt[dist[nxt] < 0]
        dist[frontier] = d
    return dist


def components(free: BoolArray) -> IntArray:
    """A label per cell: ``-1`` for walls, else the number of its 4-connected region (regions
    numbered in the row-major order of their first cell)."""
    nbr = _neighbours(free)
    label = np.full(nbr.shape[0], -1, dtype=np.int64)
    n = 0
    seed = 0
    while seed < len(label):
        if label[seed] < 0:  # a breadth-first sweep labels the seed's whole region
            label[seed] = n
            frontier = np.array([seed], dtype=np.int64)
            while frontier.size:
                nxt = np.unique(nbr[frontier].ravel())
                frontier = nxt[label[nxt] < 0]
                label[frontier] = n
            n += 1
        seed += 1
    out = np.full(free.shape, -1, dtype=np.int64)
    cells = np.argwhere(free)
    out[cells[:, 0], cells[:, 1]] = label
    return out


def largest_region(free: BoolArray) -> tuple[BoolArray, int]:
    """``free`` with every region but the largest walled up, and how many cells that dropped
    (ties: the region holding the first free cell in row-major order)."""
    free = np.asarray(free, dtype=bool)
    if not free.any():
        raise MapError("the map has no free cell")
    label = components(free)
    sizes = np.bincount(label[free])
    keep = label == int(np.argmax(sizes))
    return keep, int(free.sum() - keep.sum())


def room_cells(free: BoolArray) -> BoolArray:
    """Cells whose eight neighbours are all free (inside a room or hall, not a corridor)."""
    padded = np.pad(free, 1, constant_values=False)
    rows, cols = free.shape
    out = free.copy()
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            out &= padded[1 + dr : 1 + dr + rows, 1 + dc : 1 + dc + cols]
    return out


def _check_cell(free: BoolArray, cell: Cell, what: str) -> None:
    rows, cols = free.shape
    r, c = cell
    if not (0 <= r < rows and 0 <= c < cols):
        raise MapError(f"{what} [{r}, {c}] is off the {rows}x{cols} map")
    if not free[r, c]:
        raise MapError(f"{what} [{r}, {c}] is a wall or outside the kept region")


def place(
    free: BoolArray,
    rng: np.random.Generator,
    *,
    start: Cell | None = None,
    goals: Sequence[Cell] | None = None,
    n_goals: int = 8,
    avoid: Sequence[Cell] = (),
) -> list[str]:
    """The rows of a map: ``free`` (one connected region) with its start and goals marked.

    ``start`` and ``goals`` are used as given (each checked to be a free cell); otherwise they
    are picked as the module docstring says, ties broken by ``rng``, no picked goal on a cell
    of ``avoid`` (a building's stairs and lifts)."""
    free = np.asarray(free, dtype=bool)
    cells = np.argwhere(free)
    if len(cells) == 0:
        raise MapError("the map has no free cell")
    index = np.full(free.shape, -1, dtype=np.int64)
    index[cells[:, 0], cells[:, 1]] = np.arange(len(cells))
    nbr = _neighbours(free)
    chosen: list[int] = []
    if goals is not None:
        if not goals:
            raise MapError("give at least one goal cell")
        for g in goals:
            _check_cell(free, g, "goal")
            gi = int(index[g])
            if gi in chosen:
                raise MapError(f"goal [{g[0]}, {g[1]}] given twice")
            chosen.append(gi)
    if start is None:
        if len(chosen) >= len(cells):
            raise MapError(f"no cell is left for the start: {len(chosen)} goals fill the map")
        start_i = _edge(nbr, rng, chosen)  # a picked start is never a given goal
    else:
        _check_cell(free, start, "start")
        start_i = int(index[start])
        for gi in chosen:
            if gi == start_i:
                raise MapError(f"goal [{start[0]}, {start[1]}] is the start")
    if goals is None:
        if n_goals < 1:
            raise MapError(f"the number of goals must be at least 1, got {n_goals}")
        if n_goals > len(cells) - 1:
            raise MapError(f"a start and {n_goals} goals do not fit in {len(cells)} free cells")
        kept = sorted({int(index[c]) for c in avoid if index[c] >= 0})
        if n_goals > len(cells) - 1 - len(set(kept) - {start_i}):
            raise MapError(
                f"a start and {n_goals} goals do not fit in {len(cells)} free cells beside "
                f"{len(kept)} kept for stairs and lifts"
            )
        chosen = _spread(nbr, free, cells, start_i, n_goals, rng, kept)
    grid = np.where(free, FREE, WALL).astype("<U1")
    grid[tuple(cells[start_i])] = START
    for gi in chosen:
        grid[tuple(cells[gi])] = GOAL
    return ["".join(r) for r in grid]


def _edge(nbr: IntArray, rng: np.random.Generator, avoid: Sequence[int]) -> int:
    """The index of the cell farthest (BFS) from the first free cell in row-major order, not
    one of ``avoid`` (ties broken by ``rng``)."""
    among = np.ones(nbr.shape[0], dtype=bool)
    among[list(avoid)] = False
    return _pick(_bfs(nbr, 0), rng, among)


def edge_cell(free: BoolArray, rng: np.random.Generator, avoid: Sequence[Cell] = ()) -> Cell:
    """The start :func:`place` picks in ``free`` (one connected region): the cell farthest
    from its first cell in row-major order, none of ``avoid``."""
    free = np.asarray(free, dtype=bool)
    cells = np.argwhere(free)
    index = np.full(free.shape, -1, dtype=np.int64)
    index[cells[:, 0], cells[:, 1]] = np.arange(len(cells))
    kept = sorted({int(index[c]) for c in avoid if index[c] >= 0})
    if len(kept) >= len(cells):
        raise MapError("no free cell is left for the start")
    r, c = cells[_edge(_neighbours(free), rng, kept)]
    return int(r), int(c)


def _pick(score: IntArray, rng: np.random.Generator, among: BoolArray | None = None) -> int:
    """An index of the largest ``score`` (over ``among``), ties broken by ``rng``."""
    s = score if among is None else np.where(among, score, -1)
    best = np.flatnonzero(s == s.max())
    return int(best[int(rng.integers(len(best)))])


def _spread(
    nbr: IntArray,
    free: BoolArray,
    cells: IntArray,
    start: int,
    n_goals: int,
    rng: np.random.Generator,
    avoid: Sequence[int] = (),
) -> list[int]:
    """Farthest-point sampling over BFS distance, preferring dead ends and room cells (never
    the cells ``avoid``)."""
    open_count = (nbr != np.arange(len(cells))[:, None]).sum(axis=1)
    rooms = room_cells(free)[cells[:, 0], cells[:, 1]]
    candidate = (open_count == 1) | rooms
    candidate[start] = False
    candidate[list(avoid)] = False
    nearest = _bfs(nbr, start)
    chosen: list[int] = []
    for _ in range(n_goals):
        pool = candidate.copy()
        pool[chosen] = False
        if not pool.any():  # fewer candidates than goals: any free cell will do
            pool = np.ones(len(cells), dtype=bool)
            pool[[start, *chosen, *avoid]] = False
        g = _pick(nearest, rng, pool)
        chosen.append(g)
        nearest = np.minimum(nearest, _bfs(nbr, g))
    return chosen


def parse_cells(text: str, what: str) -> list[Cell]:
    """``"R,C;R,C"`` -> ``[(R, C), (R, C)]``; :class:`ValueError` names a bad item."""
    out: list[Cell] = []
    for item in text.split(";"):
        item = item.strip()
        if not item:
            continue
        parts = item.replace(" ", "").split(",")
        if len(parts) != 2 or not all(p.lstrip("-").isdigit() for p in parts):
            raise ValueError(f"{what} {item!r}: write a cell as ROW,COL (for example 3,7)")
        out.append((int(parts[0]), int(parts[1])))
    if not out:
        raise ValueError(f"{what}: no cell given (write ROW,COL;ROW,COL)")
    return out
