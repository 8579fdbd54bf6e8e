"""Polygons to cells: the scanline fill against the crossing-number test applied cell by cell."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.mapio import polygons
from app.mapio.polygons import band, fill, fill_mask, nearest


def pnpoly(rings: list[np.ndarray], u: float, v: float) -> bool:
    """W. R. Franklin's crossing-number test over every ring (even-odd), written plainly."""
    inside = False
    for ring in rings:
        n = len(ring)
        for i in range(n):
            ui, vi = float(ring[i][0]), float(ring[i][1])
            uj, vj = float(ring[(i + 1) % n][0]), float(ring[(i + 1) % n][1])
            if (vi > v) != (vj > v) and u < (uj - ui) * (v - vi) / (vj - vi) + ui:
                inside = not inside
    return inside


def slow_fill(rings: list[np.ndarray], shape: tuple[int, int]) -> np.ndarray:
    rows, cols = shape
    out = np.zeros(shape, dtype=bool)
    for r in range(rows):
        for c in range(cols):
            out[r, c] = pnpoly(rings, c + 0.5, rows - 1 - r + 0.5)
    return out


coordinate = st.one_of(
    st.floats(-3.0, 15.0, allow_nan=False),
    st.integers(-6, 30).map(lambda k: k / 2),  # on cell edges and centres
)
point = st.tuples(coordinate, coordinate)
rings_st = st.lists(st.lists(point, min_size=3, max_size=9), min_size=1, max_size=3)


@settings(max_examples=300, deadline=None)
@given(rings_st, st.integers(1, 12), st.integers(1, 12))
def test_fill_is_the_crossing_number_test_at_every_cell_centre(
    rings: list[list[tuple[float, float]]], rows: int, cols: int
) -> None:
    arrays = [np.array(r, dtype=np.float64) for r in rings]
    assert (fill_mask(arrays, (rows, cols)) == slow_fill(arrays, (rows, cols))).all()


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.tuples(coordinate, coordinate, coordinate, coordinate), min_size=1, max_size=4),
    st.integers(1, 12),
    st.integers(1, 12),
)
def test_fill_of_rectangles_holds_the_centres_in_their_half_open_boxes(
    boxes: list[tuple[float, float, float, float]], rows: int, cols: int
) -> None:
    """Axis-aligned rectangles (their union, even-odd where they overlap): a centre is inside
    a rectangle when u0 <= u < u1 and v0 <= v < v1."""
    rings, want = [], np.zeros((rows, cols), dtype=bool)
    for a, b, c, d in boxes:
        u0, u1, v0, v1 = min(a, c), max(a, c), min(b, d), max(b, d)
        rings.append(np.array([(u0, v0), (u1, v0), (u1, v1), (u0, v1)]))
        for r in range(rows):
            for col in range(cols):
                u, v = col + 0.5, rows - 1 - r + 0.5
                want[r, col] ^= u0 <= u < u1 and v0 <= v < v1
    assert (fill_mask(rings, (rows, cols)) == want).all()


def test_fill_in_small_blocks_is_the_same(monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(3)
    rings = [rng.uniform(-2, 40, size=(25, 2)) for _ in range(2)]
    whole = fill_mask(rings, (40, 37))
    monkeypatch.setattr(polygons, "BLOCK", 7)  # one row of centres at a time
    assert (fill_mask(rings, (40, 37)) == whole).all()
    assert (whole == slow_fill(rings, (40, 37))).all()


def test_fill_window_is_cut_to_the_grid_and_none_when_empty() -> None:
    square = [np.array([(-5.0, -5.0), (3.0, -5.0), (3.0, 2.0), (-5.0, 2.0)])]
    got = fill(square, (4, 6))
    assert got is not None
    top, left, mask = got
    assert (top, left) == (2, 0) and mask.shape == (2, 3) and mask.all()
    assert fill([np.array([(10.0, 10.0), (11.0, 10.0), (11.0, 11.0)])], (4, 4)) is None
    assert fill([np.array([(0.6, 0.6), (0.9, 0.6), (0.9, 0.9)])], (4, 4)) is None  # no centre


def test_a_band_is_beside_its_segment_and_at_least_its_least_length() -> None:
    ring = band(np.array([2.0, 3.0]), np.array([6.0, 3.0]), 1.0, 1.5)
    assert sorted(map(tuple, ring.tolist())) == [(2, 2), (2, 4), (6, 2), (6, 4)]
    short = band(np.array([2.0, 3.0]), np.array([2.0, 3.5]), 1.0, 1.5)  # lengthened
    assert np.isclose(np.ptp(short[:, 1]), 1.5) and np.isclose(np.ptp(short[:, 0]), 2.0)
    dot = band(np.array([1.0, 1.0]), np.array([1.0, 1.0]), 1.0, 1.5)  # a point: still a band
    assert np.isclose(np.ptp(dot[:, 0]), 1.5)


def test_nearest_is_the_closest_centre_first_on_ties() -> None:
    cells = np.array([[0, 0], [0, 2], [2, 0]])
    # grid of 3 rows: centres (0.5, 2.5), (2.5, 2.5), (0.5, 0.5)
    assert nearest(cells, 2.4, 2.4, 3) == (0, 2)
    assert nearest(cells, 1.5, 2.5, 3) == (0, 0)  # a tie: the first
