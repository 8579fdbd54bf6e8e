"""Polygons to cells: which cell centres a polygon holds, by scanlines (numpy only).

Coordinates here are the grid's: ``u`` in cells to the right of the grid's left edge, ``v`` in
cells up from its bottom edge; the cell ``(row, col)`` has its centre at ``(col + 0.5,
rows - 1 - row + 0.5)``. A cell belongs to a polygon when its centre is inside it by the
even-odd rule over all its rings (outer rings and holes, of one polygon or several), tested as
the classic crossing-number test (W. R. Franklin's PNPOLY) does: an edge from ``(ui, vi)`` to
``(uj, vj)`` is crossed by the ray from ``(u, v)`` to the right when ``(vi > v) != (vj > v)``
and ``u < (uj - ui) * (v - vi) / (vj - vi) + ui``. So a polygon's bottom and left edges hold
the centres on them, its top and right edges do not, and cells of polygons that share an edge
do not overlap. ``tests/mapio/test_polygons.py`` checks :func:`fill` against that test applied
cell by cell.

Each row of centres meets the edges at a few points; the cells between the first and second,
third and fourth, ... are inside. Rows are taken in blocks of at most :data:`BLOCK` (row, edge)
pairs, so the memory is bounded whatever the polygon's size.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from app.arrays import BoolArray, FloatArray

#: (rows x edges) and (rows x columns) pairs held at once while filling
BLOCK = 1 << 18

Window = tuple[int, int, BoolArray]  # first row, first column, the cells from there


def _edges(rings: Sequence[FloatArray]) -> FloatArray:
    """Every ring's edges as rows (u0, v0, u1, v1), each ring closed, level edges left out
    (a row of centres never crosses them)."""
    parts = []
    for ring in rings:
        pts = np.asarray(ring, dtype=np.float64).reshape(-1, 2)
        if len(pts) < 2:
            continue
        nxt = np.roll(pts, -1, axis=0)
        parts.append(np.hstack((pts, nxt)))
    if not parts:
        return np.empty((0, 4))
    e = np.vstack(parts)
    out: FloatArray = e[e[:, 1] != e[:, 3]]
    return out


def fill(rings: Sequence[FloatArray], shape: tuple[int, int]) -> Window | None:
    """The cells of a ``shape`` grid whose centre is inside ``rings`` (grid coordinates), as a
    window (first row, first column, mask) over the polygon's bounding box cut to the grid;
    ``None`` when no centre is inside."""
    rows, cols = shape
    e = _edges(rings)
    if len(e) == 0:
        return None
    u_lo = float(min(e[:, 0].min(), e[:, 2].min()))
    u_hi = float(max(e[:, 0].max(), e[:, 2].max()))
    v_lo = float(e[:, [1, 3]].min())
    v_hi = float(e[:, [1, 3]].max())
    # the rows (from the bottom) and columns whose centres may be inside
    b0 = max(0, int(np.ceil(v_lo - 0.5)))
    b1 = min(rows - 1, int(np.floor(v_hi - 0.5)))
    c0 = max(0, int(np.ceil(u_lo - 0.5)))
    c1 = min(cols - 1, int(np.floor(u_hi - 0.5)))
    if b0 > b1 or c0 > c1:
        return None
    width = c1 - c0 + 1
    inside = np.zeros((b1 - b0 + 1, width), dtype=bool)  # top row (b1) first
    u0, v0, u1, v1 = e[:, 0], e[:, 1], e[:, 2], e[:, 3]
    step = max(1, BLOCK // max(len(e), width + 1))
    for start in range(b0, b1 + 1, step):
        v = np.arange(start, min(b1 + 1, start + step), dtype=np.float64)[:, None] + 0.5
        crosses = (v0 > v) != (v1 > v)  # (block, edges)
        k, j = np.nonzero(crosses)
        # where each crossing meets the row, as PNPOLY computes it
        uc = (u1[j] - u0[j]) * (v[k, 0] - v0[j]) / (v1[j] - v0[j]) + u0[j]
        # a centre u = c + 0.5 is left of the crossing (crosses its ray) when c < uc - 0.5:
        # the crossings to the left of a centre toggle it, and a row's crossings are even
        first = np.clip(np.ceil(uc - 0.5), c0, c1 + 1).astype(np.int64) - c0
        toggles = np.zeros((len(v), width + 1), dtype=np.int64)
        np.add.at(toggles, (k, first), 1)
        block = (np.cumsum(toggles, axis=1)[:, :width] & 1) == 1
        first_row = b1 - (start + len(v) - 1)  # the block's top row, in the window
        inside[first_row : first_row + len(v)] = block[::-1]
    if not inside.any():
        return None
    return rows - 1 - b1, c0, inside


def fill_mask(rings: Sequence[FloatArray], shape: tuple[int, int]) -> BoolArray:
    """:func:`fill` as a whole ``shape`` mask."""
    out = np.zeros(shape, dtype=bool)
    got = fill(rings, shape)
    if got is not None:
        r, c, m = got
        out[r : r + m.shape[0], c : c + m.shape[1]] = m
    return out


def band(p: FloatArray, q: FloatArray, half_width: float, least_length: float) -> FloatArray:
    """The rectangle of ``half_width`` on each side of the segment ``p``-``q`` (lengthened
    about its middle to ``least_length`` when shorter), as a ring."""
    p, q = np.asarray(p, dtype=np.float64), np.asarray(q, dtype=np.float64)
    d = q - p
    length = float(np.hypot(*d))
    if length == 0.0:
        d, length = np.array([1.0, 0.0]), 0.0
    else:
        d = d / length
    if length < least_length:
        mid = (p + q) / 2
        p, q = mid - d * least_length / 2, mid + d * least_length / 2
    n = np.array([-d[1], d[0]]) * half_width
    return np.array([p - n, q - n, q + n, p + n])


def nearest(cells: np.ndarray, u: float, v: float, rows: int) -> tuple[int, int]:
    """The cell of ``cells`` ((n, 2) rows and columns, n >= 1) whose centre is nearest the
    point (u, v) in grid coordinates; ties: the first in ``cells``' order."""
    cu = cells[:, 1] + 0.5
    cv = rows - 1 - cells[:, 0] + 0.5
    i = int(np.argmin((cu - u) ** 2 + (cv - v) ** 2))
    return int(cells[i, 0]), int(cells[i, 1])
