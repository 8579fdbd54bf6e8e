"""IMDF records to a :class:`~app.mapio.venue.Venue`: the frame, each level's cells, walls
between units, doors from openings (the rules are :mod:`app.mapio.imdf`'s docstring)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from itertools import pairwise

import numpy as np

from app.arrays import BoolArray, FloatArray, IntArray, KeyArray
from app.domain.grid import Frame
from app.mapio import MapImportError, shorten
from app.mapio.budget import MemoryBudget
from app.mapio.imdf.features import Rings
from app.mapio.imdf.records import Records, UnitRec
from app.mapio.polygons import Window, band, fill
from app.mapio.venue import LocalProjection

#: the farthest a feature may lie from the venue's reference point (the projection's error
#: grows with it: :mod:`app.mapio.venue`)
MAX_OFFSET_M = 2_000.0

#: unit categories never walked: solid, a void, not open to the public, an island in a walkway
BLOCKED = frozenset(
    {
        "brick",
        "column",
        "concrete",
        "drywall",
        "glass",
        "wood",
        "structure",
        "opentobelow",
        "vegetation",
        "nonpublic",
        "walkway.island",
    }
)
#: unit categories open to their neighbours: no wall between them and a unit next to them
#: (every other walkable category is a room, walled except where an opening is)
OPEN = frozenset(
    {
        "walkway",
        "lobby",
        "unenclosedarea",
        "footbridge",
        "ramp",
        "steps",
        "platform",
        "movingwalkway",
        "escalator",
        "fieldofplay",
        "terrace",
        "parking",
        "road",
    }
)
#: an opening carves the cells within this many cells of its line, beside it
DOOR_HALF_WIDTH = 1.0
#: an opening shorter than this many cells is lengthened to it about its middle
DOOR_LEAST_LENGTH = 1.5


@dataclass
class Grid:
    """Where the grid lies: the projection, the frame, the shape, and metres to grid units."""

    projection: LocalProjection
    frame: Frame
    shape: tuple[int, int]

    def uv(self, xy: FloatArray) -> FloatArray:
        """Metres (east, north of the reference point) to grid coordinates (cells right of
        the left edge, up from the bottom edge)."""
        ox, oy, _ = self.frame.origin
        out: FloatArray = (np.asarray(xy, dtype=np.float64) - (ox, oy)) / self.frame.resolution
        return out


@dataclass
class Drawn:
    """A level drawn: the owner of each cell (an index into ``units``, -1 none), the cells of
    walkable units, the free cells, each unit's window, each opening's carved window."""

    ordinal: int
    label: KeyArray  # int32
    walkable: BoolArray
    free: BoolArray
    units: list[UnitRec]
    windows: list[Window | None]
    openings: dict[str, Window] = field(default_factory=dict)

    def unit_cells(self, i: int, free_only: bool = True) -> IntArray:
        """The cells (rows, cols) unit ``i`` owns (and that are free)."""
        w = self.windows[i]
        if w is None:
            return np.empty((0, 2), dtype=np.int64)
        r, c, m = w
        h, wd = m.shape
        mine = m & (self.label[r : r + h, c : c + wd] == i)
        if free_only:
            mine &= self.free[r : r + h, c : c + wd]
        out: IntArray = np.argwhere(mine) + np.array([r, c])
        return out

    def opening_cells(self, fid: str) -> IntArray:
        w = self.openings.get(fid)
        if w is None:
            return np.empty((0, 2), dtype=np.int64)
        r, c, m = w
        h, wd = m.shape
        out: IntArray = np.argwhere(m & self.free[r : r + h, c : c + wd]) + np.array([r, c])
        return out


def reference(rec: Records, where: str) -> LocalProjection:
    """The venue's display point, else the middle of its outline's bounding box."""
    v = rec.venue
    if v.display_point is not None:
        lon, lat = float(v.display_point[0]), float(v.display_point[1])
    else:
        pts = np.vstack(v.rings)
        lon = float((pts[:, 0].min() + pts[:, 0].max()) / 2)
        lat = float((pts[:, 1].min() + pts[:, 1].max()) / 2)
    try:
        return LocalProjection(lon, lat)
    except ValueError as exc:
        raise MapImportError(f"{where}: venue.geojson: {exc}") from None


def project_rings(p: LocalProjection, rings: Rings) -> list[FloatArray]:
    return [p.many_to_xy(r) for r in rings]


def make_grid(
    p: LocalProjection,
    extent: FloatArray,
    resolution: float,
    levels: int,
    budget: MemoryBudget,
    where: str,
    json_bytes: int = 0,
) -> Grid:
    """The grid covering ``extent`` (every projected point, (n, 2) metres) with a cell of
    margin, its origin on a multiple of ``resolution`` from the reference point; refused past
    ``budget`` before anything is drawn."""
    far = float(np.abs(extent).max())
    if far > MAX_OFFSET_M:
        raise MapImportError(
            f"{where}: a feature lies {far:,.0f} m from the venue's reference point (its "
            f"display_point): at most {MAX_OFFSET_M:,.0f} m are read (the local projection's "
            "error grows with the distance)"
        )
    lo, hi = extent.min(axis=0), extent.max(axis=0)
    width, height = float(hi[0] - lo[0]), float(hi[1] - lo[1])
    budget.check_venue(where, width, height, levels, resolution, json_bytes)
    i0, j0 = math.floor(lo[0] / resolution) - 1, math.floor(lo[1] / resolution) - 1
    cols = math.ceil(hi[0] / resolution) + 1 - i0
    rows = math.ceil(hi[1] / resolution) + 1 - j0
    frame = Frame(resolution, (i0 * resolution, j0 * resolution, 0.0))
    return Grid(p, frame, (rows, cols))


def draw_level(
    grid: Grid, ordinal: int, units: list[UnitRec], unit_xy: dict[str, list[FloatArray]]
) -> Drawn:
    """Units drawn (walkable ones in file order, then blocked ones over them), rooms walled
    where they touch another walkable unit."""
    rows, cols = grid.shape
    label = np.full(grid.shape, -1, dtype=np.int32)
    windows: list[Window | None] = [None] * len(units)
    order = sorted(range(len(units)), key=lambda i: units[i].category in BLOCKED)
    for i in order:
        w = fill([grid.uv(r) for r in unit_xy[units[i].id]], grid.shape)
        windows[i] = w
        if w is not None:
            r, c, m = w
            label[r : r + m.shape[0], c : c + m.shape[1]][m] = i
    walkable = np.array([u.category not in BLOCKED for u in units] + [False])
    room = np.array([u.category not in BLOCKED | OPEN for u in units] + [False])
    walk = walkable[label]  # label -1 picks the extra False
    # a room's cell is a wall when a 4-neighbour belongs to another walkable unit
    pad = np.pad(label, 1, constant_values=-1)
    rim = np.zeros(grid.shape, dtype=bool)
    for dr, dc in ((-1, 0), (1, 0), (0, -1), (0, 1)):
        nb = pad[1 + dr : 1 + dr + rows, 1 + dc : 1 + dc + cols]
        rim |= (nb != label) & walkable[nb]
    free = walk & ~(rim & room[label])
    return Drawn(ordinal, label, walk, free, units, windows)


def carve(grid: Grid, drawn: Drawn, fid: str, line_xy: FloatArray) -> None:
    """An opening: the walkable cells within :data:`DOOR_HALF_WIDTH` cells of each of its
    segments (beside it, not past its ends) become free."""
    uv = grid.uv(line_xy)
    walkable = drawn.walkable
    for p, q in pairwise(uv):
        w = fill([band(p, q, DOOR_HALF_WIDTH, DOOR_LEAST_LENGTH)], grid.shape)
        if w is None:
            continue
        r, c, m = w
        h, wd = m.shape
        cut = m & walkable[r : r + h, c : c + wd]
        drawn.free[r : r + h, c : c + wd] |= cut
        old = drawn.openings.get(fid)
        drawn.openings[fid] = _union(old, (r, c, cut))


def _union(a: Window | None, b: Window) -> Window:
    if a is None:
        return b
    r0, c0 = min(a[0], b[0]), min(a[1], b[1])
    r1 = max(a[0] + a[2].shape[0], b[0] + b[2].shape[0])
    c1 = max(a[1] + a[2].shape[1], b[1] + b[2].shape[1])
    m = np.zeros((r1 - r0, c1 - c0), dtype=bool)
    for r, c, x in (a, b):
        m[r - r0 : r - r0 + x.shape[0], c - c0 : c - c0 + x.shape[1]] |= x
    return r0, c0, m


def too_far(where: str, what: str, xy: FloatArray) -> None:
    if float(np.abs(xy).max()) > MAX_OFFSET_M:
        raise MapImportError(
            f"{where}: {what} lies more than {MAX_OFFSET_M:,.0f} m from the venue's reference "
            "point: not read"
        )


def names(items: list[str], limit: int = 5) -> str:
    """A few names for a note, quoted and cut short."""
    shown = ", ".join(shorten(n, 30) for n in items[:limit])
    return shown + (f" and {len(items) - limit} more" if len(items) > limit else "")
