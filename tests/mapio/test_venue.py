"""The venue's local projection: round trips, and its error against the ellipsoid's geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.domain.grid import Frame
from app.mapio.venue import WGS84_A, WGS84_E2, Level, LocalProjection, Stop, Venue

lon0_st = st.floats(-179.0, 179.0)
lat0_st = st.floats(-70.0, 70.0)
offset = st.floats(-250.0, 250.0)


def ecef(lon: float, lat: float) -> np.ndarray:
    """A point of the WGS 84 ellipsoid in Earth-centred metres (the textbook formula)."""
    phi, lam = math.radians(lat), math.radians(lon)
    n = WGS84_A / math.sqrt(1 - WGS84_E2 * math.sin(phi) ** 2)
    return np.array(
        [
            n * math.cos(phi) * math.cos(lam),
            n * math.cos(phi) * math.sin(lam),
            n * (1 - WGS84_E2) * math.sin(phi),
        ]
    )


@settings(max_examples=200, deadline=None)
@given(lon0_st, lat0_st, offset, offset)
def test_projection_round_trips(lon0: float, lat0: float, x: float, y: float) -> None:
    p = LocalProjection(lon0, lat0)
    lon, lat = p.to_lonlat(x, y)
    x2, y2 = p.to_xy(lon, lat)
    assert abs(x2 - x) < 1e-6 and abs(y2 - y) < 1e-6
    assert np.allclose(p.many_to_xy(np.array([[lon, lat]])), [[x2, y2]], atol=1e-9)


@settings(max_examples=300, deadline=None)
@given(lon0_st, lat0_st, offset, offset, offset, offset)
def test_projected_lengths_are_within_the_documented_error(
    lon0: float, lat0: float, x1: float, y1: float, x2: float, y2: float
) -> None:
    """|projected length - true length| <= tan|lat0| * max|y| / 6,370 km of the length (the
    true length: the straight line between the points on the ellipsoid, which differs from the
    path along the surface by less than a micrometre over 500 m)."""
    p = LocalProjection(lon0, lat0)
    a, b = p.to_lonlat(x1, y1), p.to_lonlat(x2, y2)
    true = float(np.linalg.norm(ecef(*a) - ecef(*b)))
    projected = math.hypot(x2 - x1, y2 - y1)
    bound = math.tan(math.radians(abs(lat0))) * max(abs(y1), abs(y2)) / 6_370_000
    assert abs(projected - true) <= bound * true * 1.02 + 1e-6


def test_the_documented_example_holds() -> None:
    """250 m from the reference at 60 degrees: 3.4 cm over 500 m at most."""
    p = LocalProjection(0.0, 60.0)
    a, b = p.to_lonlat(-250.0, 250.0), p.to_lonlat(250.0, 250.0)
    error = abs(500.0 - float(np.linalg.norm(ecef(*a) - ecef(*b))))
    assert 0.02 < error <= 0.034


def test_projection_crosses_the_antimeridian() -> None:
    p = LocalProjection(179.9999, 0.0)
    x, _ = p.to_xy(-179.9999, 0.0)
    assert 20 < x < 25  # 0.0002 degrees east, about 22 m
    assert p.to_lonlat(x, 0.0)[0] == pytest.approx(-179.9999)


def test_reference_outside_the_globe_is_refused() -> None:
    with pytest.raises(ValueError, match="latitude"):
        LocalProjection(0.0, 95.0)
    with pytest.raises(ValueError, match="longitude"):
        LocalProjection(float("nan"), 0.0)


def test_venue_arrays_are_read_only_and_positions_snap_to_cells() -> None:
    free = np.ones((4, 6), dtype=bool)
    p = LocalProjection(10.0, 50.0)
    v = Venue("v", p, Frame(0.5, (-1.5, -1.0, 0.0)), (4, 6), (Level(0, "G", "G", 0.0, free),))
    with pytest.raises(ValueError):
        v.levels[0].free[0, 0] = False
    assert free.flags.writeable  # a copy was frozen, not the caller's array
    stop = Stop(1, np.array([[0, 1], [2, 3]]))
    with pytest.raises(ValueError):
        stop.cells[0, 0] = 5
    # (x, y) = (0.1, 0.1): column floor((0.1 + 1.5) / 0.5) = 3, row 3 - floor(1.1 / 0.5) = 1
    assert v.cell_at(0.1, 0.1) == (1, 3)
    assert v.cell_of(*p.to_lonlat(0.1, 0.1)) == (1, 3)
    with pytest.raises(KeyError, match="no level of ordinal 2"):
        v.level(2)
