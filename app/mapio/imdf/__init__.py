"""IMDF archives (Apple's Indoor Mapping Data Format, OGC 20-094) read into a
:class:`~app.mapio.venue.Venue`.

An archive is a folder or a .zip of GeoJSON files (:mod:`app.mapio.imdf.archive` says how a zip
is bounded; :mod:`app.mapio.imdf.features` what is read of each file). The rules:

Frame. The venue's ``display_point`` is the reference point (else the middle of its outline);
every position is projected to metres east and north of it (equirectangular:
:class:`~app.mapio.venue.LocalProjection`, its error in :mod:`app.mapio.venue`). The grid's
columns run east and its rows north (no yaw), cells of ``resolution`` metres, the origin (lower-left
corner) on a multiple of the resolution from the reference point, one cell of margin around
every level and unit. Every level uses the same grid. The memory an import will take is checked
before anything is drawn: the GeoJSON's bytes, then the cells (levels x rows x columns).

Levels. Level features of one ordinal (one per building) make one level; their names joined
with `` / `` when they differ. IMDF has no heights: a level's elevation is its ordinal times
the storey height (:data:`~app.mapio.venue.DEFAULT_STOREY_HEIGHT`, 4 m, an option).

Cells. A unit holds the cells whose centre is inside it (:mod:`app.mapio.polygons`); where units
overlap, a blocked unit wins, else the later in the file. Unit categories are of three kinds:

* blocked (:data:`~app.mapio.imdf.build.BLOCKED`: structure, column, walls' materials,
  opentobelow, vegetation, nonpublic, walkway.island): never walked;
* open (:data:`~app.mapio.imdf.build.OPEN`: walkway, lobby, escalator, ramp, steps, platform,
  parking, ...): walked, no wall between one and its neighbours (a corridor split into several
  walkway units stays one corridor);
* rooms (every other category: room, office, restroom, elevator, stairs, unspecified, ...):
  walked, but a room's cell is a wall when one of its four neighbours belongs to another
  walkable unit. So rooms are closed wherever they touch another walkable unit (one cell of
  wall between a room and a corridor, two between two rooms), and a cell outside every unit is
  a wall; a room needs three cells across to keep a free cell.

Openings are the doors: an opening frees the walkable cells within one cell of its line,
beside it (:func:`~app.mapio.polygons.band`, the line lengthened to 1.5 cells when shorter).
A room is entered only where an opening lies on its boundary (within a cell of it); one with
no opening is walled off (the import's notes name such rooms). An opening that reaches a corner
where a third walkable unit meets may open onto it too.

Connections (:class:`~app.mapio.venue.Connection`) are found two ways and merged where they
share a unit: stairs, elevator and escalator units of the same category on consecutive levels
that overlap by a cell ("stacked"); and relationships of category elevator, stairs, escalator,
ramp, movingwalkway or traversal whose units and openings lie on two levels or more (origin,
intermediaries, destination all joined). Each stop is the free cells of the connection's units
(or of its openings' doors) on one level. Relationships within one level are not read: the
level's openings already join its units.

Destinations (:class:`~app.mapio.venue.Destination`): occupants at their anchor's point;
amenities at their point (named by their name, else their category); named units that hold
neither and are not passages (walkways, stairs, elevators, ...), at their display point, else
the middle of their free cells. Each is at the cell holding its point when that is a free
cell of its unit (an amenity: of its units on the first one's level), else at the unit's free
cell nearest the point; one whose unit has no free cell is left out (a note says so).

Not read: fixtures, sections, kiosks, details, geofences, footprints, buildings and
addresses; restrictions, accessibility and opening hours; the grid is not turned to the
building's axes (a building turned from north gets stepped walls).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from app.mapio import Imported, MapImportError
from app.mapio.budget import MemoryBudget
from app.mapio.imdf.archive import open_archive
from app.mapio.imdf.build import (
    BLOCKED,
    OPEN,
    Drawn,
    carve,
    draw_level,
    make_grid,
    names,
    project_rings,
    reference,
    too_far,
)
from app.mapio.imdf.places import connections, destinations
from app.mapio.imdf.records import Records, read_records
from app.mapio.venue import DEFAULT_STOREY_HEIGHT, Level, Venue

#: the default cell side of an IMDF import, in metres
DEFAULT_RESOLUTION = 0.5


@dataclass
class Source:
    """An archive's features, read and checked; nothing drawn yet."""

    where: str
    records: Records

    def listed(self, most: int = 12) -> str:
        """The levels for a message: ``0 (Ground floor), 1 (First floor), ...``, at most
        ``most`` of them."""
        levels = self.levels
        text = ", ".join(f"{o} ({name})" for o, name in levels[:most])
        return text + (f" and {len(levels) - most} more" if len(levels) > most else "")

    @property
    def levels(self) -> list[tuple[int, str]]:
        """(ordinal, name) of every level, by ordinal."""
        by: dict[int, list[str]] = {}
        for lv in self.records.levels:
            by.setdefault(lv.ordinal, [])
            if lv.name not in by[lv.ordinal]:
                by[lv.ordinal].append(lv.name)
        return [(o, " / ".join(by[o])) for o in sorted(by)]

    def places_on(self, ordinal: int) -> int:
        """The most destinations level ``ordinal`` can have: its occupants, amenities and named
        units."""
        rec = self.records
        level = {lv.id: lv.ordinal for lv in rec.levels}
        on = {u.id for u in rec.units if level[u.level_id] == ordinal}
        anchors = {a.id: a.unit_id for a in rec.anchors}
        return (
            sum(anchors[o.anchor_id] in on for o in rec.occupants)
            + sum(a.unit_ids[0] in on for a in rec.amenities)
            + sum(1 for u in rec.units if u.name and u.id in on)
        )

    def venue(
        self,
        resolution: float = DEFAULT_RESOLUTION,
        *,
        storey_height: float = DEFAULT_STOREY_HEIGHT,
        budget: MemoryBudget | None = None,
    ) -> Venue:
        return build_venue(self, resolution, storey_height, budget or MemoryBudget())


def open_imdf(path: Path, budget: MemoryBudget | None = None) -> Source:
    """Read and check the archive at ``path`` (a folder or a .zip)."""
    budget = budget or MemoryBudget()
    with open_archive(path) as archive:
        records = read_records(archive, budget)
    return Source(str(path), records)


def read_imdf(
    path: Path,
    resolution: float = DEFAULT_RESOLUTION,
    *,
    storey_height: float = DEFAULT_STOREY_HEIGHT,
    budget: MemoryBudget | None = None,
) -> Venue:
    """The venue of the IMDF archive at ``path``, its levels in cells of ``resolution`` m."""
    return open_imdf(path, budget).venue(resolution, storey_height=storey_height, budget=budget)


def build_venue(
    source: Source, resolution: float, storey_height: float, budget: MemoryBudget
) -> Venue:
    where, rec = source.where, source.records
    if not (math.isfinite(resolution) and resolution > 0):
        raise MapImportError(f"resolution must be a positive number of metres, got {resolution}")
    if not (math.isfinite(storey_height) and storey_height > 0):
        raise MapImportError(
            f"storey height must be a positive number of metres, got {storey_height}"
        )
    p = reference(rec, where)
    level_of = {lv.id: lv.ordinal for lv in rec.levels}
    unit_xy = {u.id: project_rings(p, u.rings) for u in rec.units}
    opening_xy = {o.id: p.many_to_xy(o.line) for o in rec.openings}
    parts = [r for lv in rec.levels for r in project_rings(p, lv.rings)]
    parts += [r for rings in unit_xy.values() for r in rings] + list(opening_xy.values())
    extent = np.vstack(parts)
    points = [a.point for a in rec.anchors] + [a.point for a in rec.amenities]
    points += [u.display_point for u in rec.units if u.display_point is not None]
    if points:
        too_far(where, "an anchor, amenity or display point", p.many_to_xy(np.vstack(points)))
    ordinals = sorted(set(level_of.values()))
    grid = make_grid(p, extent, resolution, len(ordinals), budget, where, rec.n_bytes)
    drawn: dict[int, Drawn] = {}
    for o in ordinals:
        d = draw_level(grid, o, [u for u in rec.units if level_of[u.level_id] == o], unit_xy)
        for op in rec.openings:
            if level_of[op.level_id] == o:
                carve(grid, d, op.id, opening_xy[op.id])
        drawn[o] = d
    notes = _unit_notes(drawn, resolution)
    found, more = connections(rec, drawn, level_of)
    notes += more
    unit_level = {u.id: level_of[u.level_id] for u in rec.units}
    dests, more = destinations(rec, drawn, grid, unit_level)
    notes += more
    levels = []
    for o, name in source.levels:
        group = [lv for lv in rec.levels if lv.ordinal == o]
        short = " / ".join(dict.fromkeys(lv.short_name for lv in group))
        ids = tuple(lv.id for lv in group)
        outdoor = all(lv.outdoor for lv in group)
        levels.append(Level(o, name, short, o * storey_height, drawn[o].free, ids, outdoor))
    return Venue(
        name=rec.venue.name or Path(where).stem,
        projection=p,
        frame=grid.frame,
        shape=grid.shape,
        levels=tuple(levels),
        connections=tuple(found),
        destinations=tuple(dests),
        storey_height=storey_height,
        notes=tuple(notes),
    )


def _unit_notes(drawn: dict[int, Drawn], resolution: float) -> list[str]:
    """Walkable units with no cell or no free cell, and rooms no opening enters."""
    empty: list[str] = []
    closed: list[str] = []
    for o, d in drawn.items():
        free = np.bincount(d.label[d.free], minlength=len(d.units))  # free cells per unit
        for i, u in enumerate(d.units):
            if u.category in BLOCKED:
                continue
            label = u.name or f"{u.category} {u.id[:8]}"
            if not free[i]:
                empty.append(f"{label} (level {o})")
            elif u.category not in OPEN and i not in d.entered:
                closed.append(f"{label} (level {o})")
    notes = []
    if empty:
        notes.append(
            f"{len(empty)} walkable unit(s) hold no free cell at {resolution:g} m a cell "
            f"(too narrow for a cell inside their walls): {names(empty)}"
        )
    if closed:
        notes.append(f"{len(closed)} room(s) with no opening, walled off: {names(closed)}")
    return notes


def one_floor(venue: Venue, ordinal: int) -> Imported:
    """One level of ``venue`` as a one-floor import: its free cells, the venue's frame, its
    destinations as named goals, and notes on the venue."""
    level = venue.level(ordinal)
    p = venue.projection
    listed = ", ".join(f"{lv.ordinal} {lv.name!r}" for lv in venue.levels[:12])
    listed += f" and {len(venue.levels) - 12} more" if len(venue.levels) > 12 else ""
    rows, cols = venue.shape
    notes = [
        f"IMDF venue {venue.name!r}: {len(venue.levels)} level(s) ({listed}); level {ordinal} "
        f"{level.name!r}: {int(level.free.sum())} free cells of {rows}x{cols}",
        f"frame: x metres east and y metres north of longitude {p.lon0:.7f}, latitude "
        f"{p.lat0:.7f} (local equirectangular projection), cells of {venue.frame.resolution:g} m",
        *venue.notes,
    ]
    for c in venue.connections:
        if ordinal in c.ordinals:
            others = ", ".join(str(o) for o in c.ordinals if o != ordinal)
            stop = next(s for s in c.stops if s.ordinal == ordinal)
            r, col = (int(v) for v in stop.cells[0])
            notes.append(
                f"{c.kind} {c.name!r} to level(s) {others} from {len(stop.cells)} cell(s) "
                f"here, such as [{r}, {col}] (not in a one-floor map)"
            )
    goals = [(d.cell, d.name) for d in venue.destinations_on(ordinal)]
    return Imported(level.free.copy(), venue.frame, notes, goals)
