"""A :class:`~app.mapio.venue.Venue` as a map of several floors (``maze import`` of an IMDF
archive without ``--level``): :func:`venue_building`.

* Floors: every level, in ordinal order, with its name (made plain as a destination's,
  ``Level N`` when it has none) and elevation; they share the venue's grid and frame.
* Connections: each of the venue's, of kind :data:`KIND_OF` its kind (an IMDF elevator is a
  ``lift``; a moving walkway or a traversal a ``ramp``), at
  :func:`~app.domain.floors.default_cost` for the grid's resolution, named as the venue names it
  (``Stairs 2`` when it has no name). A stop is one cell of the venue's stop on that level: a
  cell that every stop has, when there is one (stacked lifts and stairwells), the one nearest
  the middle of those, else on each level the cell nearest the middle of its stop; never a
  cell another connection has taken, nor a destination's when another is free.
* The kept region: the largest set of free cells joined by moves on a level and by the
  connections (regions of each level, joined where a connection stops in both), as a
  one-floor import keeps its largest region; what is left out is noted (cells, whole levels,
  connections, destinations). When the kept region lies on one level, the import is that
  level's one-floor map.
* Destinations: the venue's named ones in the kept region are the goals (several at one cell
  named together, ``A / B``), their names made plain and each once in the building
  (:func:`~app.domain.grid.plain_unique`: ``Restrooms 2``). A venue with none in the kept region
  gets ``n_goals`` picked on each floor (:func:`~app.domain.place.place`).
* The start: on the floor of ordinal 0 (else the lowest kept), the cell
  :func:`~app.domain.place.place` would pick (the farthest from the floor's first cell), not a
  stop or a destination.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from app.arrays import BoolArray
from app.domain.building import MAX_CELLS, Building
from app.domain.floors import Connection, Floor, FloorName, default_cost
from app.domain.grid import FREE, GOAL, START, WALL, NamedCell, plain_unique
from app.domain.place import components, edge_cell, place
from app.mapio import MapImportError
from app.mapio.imdf.build import names
from app.mapio.venue import Connection as VenueConnection
from app.mapio.venue import Venue

#: the map's kind of each kind of venue connection
KIND_OF = {
    "stairs": "stairs",
    "elevator": "lift",
    "escalator": "escalator",
    "ramp": "ramp",
    "movingwalkway": "ramp",
    "traversal": "ramp",
}
Cell3 = tuple[int, int, int]  # (level index, row, col)


@dataclass
class Stacked:
    """What :func:`venue_building` made: the building, or (``building`` None) the ordinal of
    the one level the kept region lies on; and notes on what was read and left out."""

    building: Building | None
    ordinal: int | None = None
    notes: list[str] = field(default_factory=list)


def venue_building(
    venue: Venue, rng: np.random.Generator, *, n_goals: int = 8, name: str = "building"
) -> Stacked:
    """The venue as a map of several floors (the module docstring)."""
    n, (rows, cols) = len(venue.levels), venue.shape
    if n * rows * cols > MAX_CELLS:
        raise MapImportError(
            f"{n} level(s) of {rows:,} x {cols:,} cells at {venue.frame.resolution:g} m a cell: "
            f"a map of several floors holds at most {MAX_CELLS:,} cells: give a coarser "
            "--resolution, or --level ORDINAL for one level"
        )
    index = {lv.ordinal: i for i, lv in enumerate(venue.levels)}
    free = np.stack([lv.free for lv in venue.levels]) if n else np.zeros((0, rows, cols), bool)
    named = [(index[d.ordinal], *d.cell) for d in venue.destinations]
    notes: list[str] = []
    stops = _stops(venue, index, free, set(named), notes)
    kept = _kept(free, [s for _, s in stops])
    levels = [i for i in range(n) if kept[i].any()]
    if len(levels) < 2:
        ordinal = venue.levels[levels[0]].ordinal if levels else venue.levels[0].ordinal
        notes.append(
            f"the largest region joined by the connections lies on level {ordinal} alone: a "
            "one-floor map of it"
        )
        return Stacked(None, ordinal, notes)
    total, dropped = int(free.sum()), int(free.sum() - kept.sum())
    notes.append(
        f"kept the largest region joined by the connections: {total - dropped} of {total} free "
        f"cells on {len(levels)} of {n} level(s) ({dropped} dropped)"
    )
    if len(levels) < n:
        left = [f"{lv.ordinal} {lv.name}" for i, lv in enumerate(venue.levels) if i not in levels]
        notes.append(f"{len(left)} level(s) not joined to the kept region, left out: {names(left)}")
    floor_of = {i: k for k, i in enumerate(levels)}
    ways = [(conn, cells) for conn, cells in stops if kept[cells[0]]]
    if len(ways) < len(stops):
        notes.append(f"{len(stops) - len(ways)} connection(s) outside the kept region, left out")
    goals = _goals(venue, index, kept, notes)
    if not goals:
        notes.append(f"no named destination in the kept region: {n_goals} goal(s) picked a floor")
    grid = np.where(kept, FREE, WALL).astype("<U1")
    taken = {cell for _, cells in ways for cell in cells}
    if not goals:
        _pick_goals(grid, levels, taken, n_goals, rng)
    ground = next((i for i in levels if venue.levels[i].ordinal >= 0), levels[0])
    avoid = [(r, c) for f, r, c in taken if f == ground]
    avoid += [(int(r), int(c)) for r, c in np.argwhere(grid[ground] == GOAL)]
    avoid += [(r, c) for f, r, c in goals if f == ground]
    grid[(ground, *edge_cell(kept[ground], rng, avoid))] = START
    for f, r, c in goals:
        grid[f, r, c] = GOAL
    floor_names = plain_unique(venue.levels[i].name for i in levels)
    floors = [
        Floor(venue.levels[i].ordinal, floor_names[k] or f"Level {venue.levels[i].ordinal}",
              tuple("".join(row) for row in grid[i]), venue.levels[i].elevation)
        for k, i in enumerate(levels)
    ]  # fmt: skip
    labels = plain_unique(conn.name for conn, _ in ways)
    connections = []
    for k, (conn, cells) in enumerate(ways):
        kind = KIND_OF.get(conn.kind, "ramp")
        at = tuple((floor_of[f], r, c) for f, r, c in cells)
        label = labels[k] or f"{kind.capitalize()} {k + 1}"
        connections.append(Connection(kind, default_cost(kind, venue.frame.resolution), at, label))
    texts = plain_unique(goals.values())
    given = [
        FloorName(floor_of[f], NamedCell(r, c, text))
        for (f, r, c), text in zip(goals, texts, strict=True)
        if text
    ]
    for (f, r, c), original, text in zip(goals, goals.values(), texts, strict=True):
        if original != text:
            how = f"as {text!r}" if text else "without a name"
            notes.append(f"destination [{floor_of[f]}, {r}, {c}] {original!r} written {how}")
    b = Building.from_parts(floors, connections, given, venue.frame, name)
    return Stacked(b, None, notes)


def _stops(
    venue: Venue, index: dict[int, int], free: BoolArray, named: set[Cell3], notes: list[str]
) -> list[tuple[VenueConnection, list[Cell3]]]:
    """Each connection with a cell a level (the module docstring), in the venue's order; one
    left with fewer than two stops is left out (noted)."""
    taken: set[Cell3] = set()
    out: list[tuple[VenueConnection, list[Cell3]]] = []
    short = []
    for conn in venue.connections:
        options = []
        for stop in conn.stops:
            f = index[stop.ordinal]
            own = [(int(r), int(c)) for r, c in stop.cells if free[f, r, c]]
            own = [x for x in own if (f, *x) not in taken]
            if own:
                options.append((f, own))
        common = set.intersection(*(set(cells) for _, cells in options)) if options else set()
        cells: list[Cell3] = []
        for f, own in options:
            pool = sorted(common) if common else own
            spare = [x for x in pool if (f, *x) not in named] or pool
            cells.append((f, *_middle(spare)))
        if len(cells) < 2:
            short.append(conn.name or conn.kind)
            continue
        taken.update(cells)
        out.append((conn, cells))
    if short:
        notes.append(
            f"{len(short)} connection(s) with fewer than two stops on free cells, left out: "
            + names(short)
        )
    return out


def _middle(cells: list[tuple[int, int]]) -> tuple[int, int]:
    """The cell nearest the cells' mean (the first in row-major order on a tie)."""
    a = np.array(sorted(cells))
    d = ((a - a.mean(axis=0)) ** 2).sum(axis=1)
    r, c = a[int(np.argmin(d))]
    return int(r), int(c)


def _kept(free: BoolArray, joins: list[list[Cell3]]) -> BoolArray:
    """The largest set of free cells joined on their level or by a connection's stops."""
    labels = [components(level) for level in free]
    base = np.cumsum([0] + [int(lab.max()) + 1 for lab in labels])
    parent = list(range(int(base[-1])))

    def root(x: int) -> int:
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for cells in joins:
        ids = [int(base[f] + labels[f][r, c]) for f, r, c in cells]
        for other in ids[1:]:
            parent[root(other)] = root(ids[0])
    sizes = np.zeros(len(parent), dtype=np.int64)
    for f, lab in enumerate(labels):
        counts = np.bincount(lab[lab >= 0], minlength=int(lab.max()) + 1)
        for k, count in enumerate(counts.tolist()):
            sizes[root(int(base[f]) + k)] += count
    best = int(np.argmax(sizes))
    out = np.zeros_like(free)
    for f, lab in enumerate(labels):
        roots = np.array([root(int(base[f]) + k) for k in range(int(lab.max()) + 1)] or [-1])
        out[f] = (lab >= 0) & (roots[np.maximum(lab, 0)] == best)
    return out


def _goals(
    venue: Venue, index: dict[int, int], kept: BoolArray, notes: list[str]
) -> dict[Cell3, str]:
    """The named destinations in the kept region (names of one cell joined with " / "), in
    cell order; those outside it noted."""
    named: dict[Cell3, str] = {}
    outside = []
    for d in venue.destinations:
        cell = (index[d.ordinal], *d.cell)
        if not kept[cell]:
            outside.append(d.name)
        else:
            named[cell] = f"{named[cell]} / {d.name}" if cell in named else d.name
    if outside:
        notes.append(
            f"{len(outside)} destination(s) outside the kept region, left out: {names(outside)}"
        )
    return dict(sorted(named.items()))


def _pick_goals(
    grid: np.ndarray, levels: list[int], taken: set[Cell3], n_goals: int, rng: np.random.Generator
) -> None:
    """``n_goals`` goals on each kept level, spread out from one of its stops."""
    for f in levels:
        free = grid[f] != WALL
        stops = [(r, c) for g, r, c in taken if g == f]
        anchor = stops[0] if stops else edge_cell(free, rng)
        most = min(n_goals, int(free.sum()) - len(stops) - 1)
        if most < 1:
            continue
        rows = place(free, rng, start=anchor, n_goals=most, avoid=stops)
        for r, row in enumerate(rows):
            for c, ch in enumerate(row):
                if ch == GOAL:
                    grid[f, r, c] = GOAL
