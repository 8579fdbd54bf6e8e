"""IMDF records to a :class:`~app.mapio.venue.Venue`: the frame, each level's cells, walls
between units, doors from openings (the rules are :mod:`app.mapio.imdf`'s docstring)."""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from itertools import pairwise

import numpy as np

from app.arrays import BoolArray, FloatArray, KeyArray
from app.domain.grid import Frame
from app.mapio import MapImportError, shorten
from app.mapio.budget import MemoryBudget
from app.mapio.imdf.features import Rings
from app.mapio.imdf.records import Records, UnitRec
from app.mapio.polygons import BLOCK, Window, band, fill
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


Box = tuple[int, int, int, int]  # first row, first column, end row, end column


@dataclass
class Drawn:
    """A level drawn: the owner of each cell (an index into ``units``, -1 none), the cells of
    walkable units, the free cells; each unit's bounding box (no masks are kept: the owner
    grid says which cells are a unit's), the units openings enter, and each opening's line in
    grid coordinates (its cells are found again when a connection needs them)."""

    ordinal: int
    label: KeyArray  # int32
    walkable: BoolArray
    free: BoolArray
    units: list[UnitRec]
    boxes: list[Box | None]
    entered: set[int] = field(default_factory=set)
    lines: dict[str, FloatArray] = field(default_factory=dict)

    def cells(self, units: Sequence[int], openings: Sequence[str] = ()) -> KeyArray:
        """The free cells (rows, cols; int32, row-major) the ``units`` own and the
        ``openings`` carve."""
        windows: list[Window] = []
        for i in units:
            box = self.boxes[i]
            if box is not None:
                r0, c0, r1, c1 = box
                windows.append((r0, c0, self.label[r0:r1, c0:c1] == i))
        for fid in openings:
            for r, c, m in _bands(self.lines.get(fid, np.empty((0, 2))), self.label.shape):
                h, w = m.shape
                windows.append((r, c, m & self.walkable[r : r + h, c : c + w]))
        if not windows:
            return np.empty((0, 2), dtype=np.int32)
        r0 = min(w[0] for w in windows)
        c0 = min(w[1] for w in windows)
        r1 = max(w[0] + w[2].shape[0] for w in windows)
        c1 = max(w[1] + w[2].shape[1] for w in windows)
        mask = np.zeros((r1 - r0, c1 - c0), dtype=bool)
        for r, c, m in windows:
            mask[r - r0 : r - r0 + m.shape[0], c - c0 : c - c0 + m.shape[1]] |= m
        del windows
        mask &= self.free[r0:r1, c0:c1]
        return cells_of(mask, r0, c0)


def cells_of(mask: BoolArray, r0: int = 0, c0: int = 0) -> KeyArray:
    """The true cells of ``mask`` as (row + r0, col + c0) rows of int32, row-major, found a
    band of rows at a time (no int64 array of them all)."""
    parts = [np.empty((0, 2), dtype=np.int32)]
    step = max(1, BLOCK // max(1, mask.shape[1]))
    for r in range(0, mask.shape[0], step):
        rr, cc = np.nonzero(mask[r : r + step])
        parts.append(np.column_stack((rr + (r + r0), cc + c0)).astype(np.int32))
    out: KeyArray = np.concatenate(parts)
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
    boxes: list[Box | None] = [None] * len(units)
    order = sorted(range(len(units)), key=lambda i: units[i].category in BLOCKED)
    for i in order:
        w = fill([grid.uv(r) for r in unit_xy[units[i].id]], grid.shape)
        if w is not None:
            r, c, m = w
            label[r : r + m.shape[0], c : c + m.shape[1]][m] = i
            boxes[i] = (r, c, r + m.shape[0], c + m.shape[1])
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
    return Drawn(ordinal, label, walk, free, units, boxes)


def carve(grid: Grid, drawn: Drawn, fid: str, line_xy: FloatArray) -> None:
    """An opening: the walkable cells within :data:`DOOR_HALF_WIDTH` cells of each of its
    segments (beside it, not past its ends) become free."""
    uv = grid.uv(line_xy)
    drawn.lines[fid] = uv
    for r, c, m in _bands(uv, grid.shape):
        h, w = m.shape
        cut = m & drawn.walkable[r : r + h, c : c + w]
        drawn.free[r : r + h, c : c + w] |= cut
        drawn.entered.update(np.unique(drawn.label[r : r + h, c : c + w][cut]).tolist())


def _bands(uv: FloatArray, shape: tuple[int, int]) -> Iterator[Window]:
    """The cells of the band around each segment of a line (grid coordinates)."""
    for p, q in pairwise(uv):
        w = fill([band(p, q, DOOR_HALF_WIDTH, DOOR_LEAST_LENGTH)], shape)
        if w is not None:
            yield w


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
