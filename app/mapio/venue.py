"""A building of several levels on one grid: what an IMDF archive is read into.

A :class:`Venue` is the intermediate form between an indoor map (:mod:`app.mapio.imdf`) and a
domain: every level rasterised on the same grid (the same shape, resolution and origin, so a
cell ``(row, col)`` is the same place on every level), the connections between levels, and the
named destinations. It is plain data, frozen; its arrays are read-only.

Positions. An indoor map is in longitude and latitude (WGS 84); the venue keeps a local metric
frame about a reference point (:class:`LocalProjection`): x metres to the east, y metres to the
north. The grid lies in that frame as a map file's header says (:class:`~app.domain.grid.Frame`:
the cell side, and the lower-left corner of the lower-left cell), so a position in metres, with
its level, snaps to a cell with :meth:`Venue.cell_at`, and a longitude and latitude with
:meth:`Venue.cell_of`.

The projection is equirectangular about the reference point (lon0, lat0), with the WGS 84
ellipsoid's radii of curvature there (``N0``, across the meridian, and ``M0``, along it)::

    x = N0 cos(lat0) (lon - lon0)        y = M0 (lat - lat0)        (angles in radians)

It is exact along the meridian and the parallel through the reference point; elsewhere east-west
lengths are scaled by cos(lat) / cos(lat0), about ``1 - tan(lat0) y / 6,370 km``: a length is off
by at most that fraction of itself, ``tan(lat0) |y| / 6,370 km`` for the largest ``|y|`` (metres
north or south of the reference) it spans. For a building within 250 m of its reference point
at 60 degrees of latitude, 6.8e-5: 3.4 cm over 500 m, a fifteenth of a 0.5 m cell (tested
against the straight-line distance between the points on the ellipsoid:
``tests/mapio/test_venue.py``). The reader refuses features more than
:data:`~app.mapio.imdf.build.MAX_OFFSET_M` from the reference point.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from app.arrays import BoolArray, KeyArray
from app.domain.grid import Frame

#: WGS 84: the semi-major axis (m) and the first eccentricity squared
WGS84_A = 6_378_137.0
WGS84_E2 = 6.694_379_990_14e-3

#: the storey height used for a level's elevation when the map gives none (IMDF gives none)
DEFAULT_STOREY_HEIGHT = 4.0

Cell = tuple[int, int]


@dataclass(frozen=True)
class LocalProjection:
    """Longitude and latitude (degrees) to metres east and north of (``lon0``, ``lat0``), and
    back; see the module docstring for the formula and its error."""

    lon0: float
    lat0: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.lon0) and -180.0 <= self.lon0 <= 180.0):
            raise ValueError(f"reference longitude must be in [-180, 180], got {self.lon0}")
        if not (math.isfinite(self.lat0) and -89.0 <= self.lat0 <= 89.0):
            raise ValueError(f"reference latitude must be in [-89, 89], got {self.lat0}")

    @property
    def metres_per_radian(self) -> tuple[float, float]:
        """(east, north) metres per radian of longitude and of latitude at the reference."""
        phi = math.radians(self.lat0)
        w = 1.0 - WGS84_E2 * math.sin(phi) ** 2
        n = WGS84_A / math.sqrt(w)  # across the meridian
        m = WGS84_A * (1.0 - WGS84_E2) / w**1.5  # along it
        return n * math.cos(phi), m

    def to_xy(self, lon: float, lat: float) -> tuple[float, float]:
        kx, ky = self.metres_per_radian
        dlon = (lon - self.lon0 + 180.0) % 360.0 - 180.0  # across the antimeridian too
        return kx * math.radians(dlon), ky * math.radians(lat - self.lat0)

    def to_lonlat(self, x: float, y: float) -> tuple[float, float]:
        kx, ky = self.metres_per_radian
        lon = self.lon0 + math.degrees(x / kx)
        return (lon + 180.0) % 360.0 - 180.0, self.lat0 + math.degrees(y / ky)

    def many_to_xy(self, lonlat: np.ndarray) -> np.ndarray:
        """An (n, 2) array of longitudes and latitudes as an (n, 2) array of metres."""
        kx, ky = self.metres_per_radian
        pts = np.asarray(lonlat, dtype=np.float64)
        dlon = (pts[:, 0] - self.lon0 + 180.0) % 360.0 - 180.0
        return np.column_stack((kx * np.radians(dlon), ky * np.radians(pts[:, 1] - self.lat0)))


def _frozen(a: np.ndarray) -> np.ndarray:
    """A read-only copy (the caller's array is left as it is)."""
    a = np.array(a)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class Level:
    """One floor: its IMDF level features of one ordinal, and its free cells.

    ``ordinal``: the IMDF ordinal (0 the ground or entrance level, negative below);
    ``elevation``: metres above ordinal 0's floor (``ordinal x`` the storey height: IMDF has no
    heights); ``free``: the walkable cells (row 0 at the top), read-only; ``ids``: the IMDF
    level features merged into it (one per building)."""

    ordinal: int
    name: str
    short_name: str
    elevation: float
    free: BoolArray = field(repr=False)
    ids: tuple[str, ...] = ()
    outdoor: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "free", _frozen(np.asarray(self.free, dtype=bool)))


@dataclass(frozen=True, eq=False)
class Stop:
    """Where a connection touches one level: its free ``cells`` there, an (n, 2) array of
    (row, col) (int32), read-only; ``ids``: the IMDF units or openings it is made of there."""

    ordinal: int
    cells: KeyArray = field(repr=False)
    ids: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        cells = np.asarray(self.cells, dtype=np.int32).reshape(-1, 2)
        object.__setattr__(self, "cells", _frozen(cells))


@dataclass(frozen=True, eq=False)
class Connection:
    """A way between levels: ``kind`` (``stairs``, ``elevator``, ``escalator``, ``ramp``,
    ``movingwalkway`` or ``traversal``), a name, and its stops, one per level it joins, in
    ordinal order. ``source``: how it was found (stacked units, relationships)."""

    kind: str
    name: str
    stops: tuple[Stop, ...]
    source: str = ""

    @property
    def ordinals(self) -> tuple[int, ...]:
        return tuple(s.ordinal for s in self.stops)


@dataclass(frozen=True)
class Destination:
    """A named place: ``cell`` (row, col) is a free cell of ``ordinal``'s level, in the unit
    the destination belongs to. ``source``: ``occupant``, ``amenity`` or ``unit``; ``feature``:
    the IMDF id it comes from; ``category``: its IMDF category."""

    name: str
    category: str
    ordinal: int
    cell: Cell
    source: str
    feature: str


@dataclass(frozen=True, eq=False)
class Venue:
    """A building on one grid of ``shape`` cells: ``projection`` (lon/lat <-> metres),
    ``frame`` (where the grid lies in those metres), ``levels`` by ordinal, ``connections``
    between them, named ``destinations``, and the reader's ``notes``."""

    name: str
    projection: LocalProjection
    frame: Frame
    shape: tuple[int, int]
    levels: tuple[Level, ...]
    connections: tuple[Connection, ...] = ()
    destinations: tuple[Destination, ...] = ()
    storey_height: float = DEFAULT_STOREY_HEIGHT
    notes: tuple[str, ...] = ()

    @property
    def ordinals(self) -> tuple[int, ...]:
        return tuple(level.ordinal for level in self.levels)

    def level(self, ordinal: int) -> Level:
        for level in self.levels:
            if level.ordinal == ordinal:
                return level
        raise KeyError(f"no level of ordinal {ordinal}: the levels are {self.ordinals}")

    def cell_at(self, x: float, y: float) -> Cell:
        """The cell holding the point (x, y), metres east and north of the reference point
        (it may lie off the grid: the caller checks)."""
        return self.frame.cell_at(x, y, self.shape[0])

    def cell_of(self, lon: float, lat: float) -> Cell:
        """The cell holding a longitude and latitude."""
        return self.cell_at(*self.projection.to_xy(lon, lat))

    def destinations_on(self, ordinal: int) -> tuple[Destination, ...]:
        return tuple(d for d in self.destinations if d.ordinal == ordinal)
