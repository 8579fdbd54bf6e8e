"""Seeded maze generation: perfect mazes (a spanning tree of corridors) and braided ones.

Corridors are one cell wide on a lattice of cells at even (row, col); the walls between them
sit at odd positions. A perfect maze has exactly one path between any two cells; ``braid``
is the probability of opening each dead end into a neighbouring corridor, which adds loops.
The start is the lower-left cell; goals go to the other three corners and then to dead ends
(corridor ends), as in the paper's Figure 4.
"""

from __future__ import annotations

import numpy as np

from app.domain.grid import FREE, GOAL, START, WALL, GridDomain


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
