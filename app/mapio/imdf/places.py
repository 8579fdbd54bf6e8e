"""Connections between levels and named destinations, from drawn levels (the rules are
:mod:`app.mapio.imdf`'s docstring)."""

from __future__ import annotations

from collections import defaultdict
from itertools import pairwise

import numpy as np

from app.arrays import FloatArray
from app.mapio.imdf.build import BLOCKED, Drawn, Grid, names
from app.mapio.imdf.features import clean_name
from app.mapio.imdf.records import Records
from app.mapio.polygons import BLOCK, nearest
from app.mapio.venue import Connection, Destination, Stop

#: unit categories stacked across levels to make connections
VERTICAL = frozenset({"elevator", "stairs", "escalator"})
#: relationship categories that join levels (``traversal.path`` read as ``traversal``)
JOINING = frozenset(
    {"elevator", "stairs", "escalator", "ramp", "movingwalkway", "traversal", "traversal.path"}
)
#: walkable unit categories not named as destinations (passages, not places)
PASSAGES = VERTICAL | {"walkway", "movingwalkway", "ramp", "steps", "road", "footbridge"}

Place = tuple[str, str]  # ("unit" or "opening", id)


class _Sets:
    """Union-find over places."""

    def __init__(self) -> None:
        self.parent: dict[Place, Place] = {}

    def find(self, a: Place) -> Place:
        self.parent.setdefault(a, a)
        while self.parent[a] != a:
            self.parent[a] = self.parent[self.parent[a]]
            a = self.parent[a]
        return a

    def join(self, a: Place, b: Place) -> None:
        self.parent[self.find(a)] = self.find(b)


def connections(
    rec: Records, drawn: dict[int, Drawn], level_of: dict[str, int]
) -> tuple[list[Connection], list[str]]:
    """Stacked stairs, elevator and escalator units (the same category on consecutive levels,
    overlapping by a cell), and relationships whose units and openings lie on two levels or
    more, joined where they share a place; one connection each, with its free cells on every
    level it reaches."""
    notes: list[str] = []
    where_unit: dict[str, tuple[int, int]] = {}  # id -> (ordinal, index in that level's units)
    for ordinal, d in drawn.items():
        for i, u in enumerate(d.units):
            where_unit[u.id] = (ordinal, i)
    opening_level = {o.id: level_of[o.level_id] for o in rec.openings}
    sets = _Sets()
    stacked: set[Place] = set()
    for below, above in pairwise(sorted(drawn)):
        a, b = drawn[below], drawn[above]
        for i, j in _stacked(a, b):
            sets.join(("unit", a.units[i].id), ("unit", b.units[j].id))
            stacked |= {("unit", a.units[i].id), ("unit", b.units[j].id)}
    kind_of: dict[Place, str] = {}
    same_level = 0
    for rel in rec.relationships:
        if rel.category not in JOINING or len(rel.refs) < 2:
            continue
        levels = {
            where_unit[fid][0] if kind == "unit" else opening_level[fid] for kind, fid in rel.refs
        }
        if len(levels) < 2:
            same_level += 1
            continue
        for ref in rel.refs[1:]:
            sets.join(rel.refs[0], ref)
        for ref in rel.refs:
            kind_of.setdefault(ref, rel.category.replace("traversal.path", "traversal"))
    if same_level:
        notes.append(
            f"{same_level} relationship(s) within one level not read (openings join the units "
            "of a level)"
        )
    groups: dict[Place, list[Place]] = defaultdict(list)
    for place in sets.parent:
        groups[sets.find(place)].append(place)
    order = {("unit", u.id): k for k, u in enumerate(rec.units)}
    order |= {("opening", o.id): len(order) + k for k, o in enumerate(rec.openings)}
    out: list[Connection] = []
    counts: dict[str, int] = defaultdict(int)
    thin: list[str] = []
    for members in sorted(groups.values(), key=lambda m: min(order[p] for p in m)):
        members.sort(key=lambda p: order[p])
        units = [rec.units[order[p]] for p in members if p[0] == "unit"]
        kind = next((kind_of[p] for p in members if p in kind_of), None)
        kind = kind or (units[0].category if units else "traversal")
        units_on: dict[int, list[int]] = defaultdict(list)
        openings_on: dict[int, list[str]] = defaultdict(list)
        ids: dict[int, list[str]] = defaultdict(list)
        for kind_, fid in members:
            if kind_ == "unit":
                ordinal, i = where_unit[fid]
                units_on[ordinal].append(i)
            else:
                ordinal = opening_level[fid]
                openings_on[ordinal].append(fid)
            ids[ordinal].append(fid)
        counts[kind] += 1
        name = next((u.name for u in units if u.name), f"{kind} {counts[kind]}")
        stops = []
        for ordinal in sorted(ids):
            cells = drawn[ordinal].cells(units_on[ordinal], openings_on[ordinal])
            if len(cells):
                stops.append(Stop(ordinal, cells, tuple(ids[ordinal])))
            else:
                thin.append(f"{name} on level {ordinal}")
        if len(stops) < 2:
            continue
        how = [
            w
            for w, yes in (
                ("stacked units", any(p in stacked for p in members)),
                ("relationships", any(p in kind_of for p in members)),
            )
            if yes
        ]
        out.append(Connection(kind, name, tuple(stops), " and ".join(how)))
    if thin:
        notes.append(f"connections with no free cell on a level (too narrow): {names(thin)}")
    return out, notes


def _stacked(a: Drawn, b: Drawn) -> list[tuple[int, int]]:
    """The pairs (unit of ``a``, unit of ``b``) of one vertical category that share a cell,
    found a band of rows at a time (the cells' owners as one key each, their distinct keys)."""
    kinds = sorted(VERTICAL)
    code_a = np.array([kinds.index(u.category) if u.category in VERTICAL else -1 for u in a.units])
    code_b = np.array([kinds.index(u.category) if u.category in VERTICAL else -2 for u in b.units])
    if not (code_a >= 0).any() or not (code_b >= 0).any():
        return []
    code_a, code_b = np.append(code_a, -1), np.append(code_b, -2)  # label -1: none
    n_b = np.int64(len(b.units) + 1)
    rows, cols = a.label.shape
    found = [np.empty(0, dtype=np.int64)]
    step = max(1, BLOCK // cols)
    for r in range(0, rows, step):
        la, lb = a.label[r : r + step], b.label[r : r + step]
        same = code_a[la] == code_b[lb]
        if same.any():
            found.append(np.unique(la[same].astype(np.int64) * n_b + lb[same]))
    keys = np.unique(np.concatenate(found))
    return [(int(k // n_b), int(k % n_b)) for k in keys]


def destinations(
    rec: Records, drawn: dict[int, Drawn], grid: Grid, unit_level: dict[str, int]
) -> tuple[list[Destination], list[str]]:
    """Occupants at their anchors, amenities at their points, and named rooms with neither
    (at their display point, else the middle of their free cells), each at the cell holding
    its point when that is a free cell of its unit (or units), else the nearest one."""
    index = {u.id: i for d in drawn.values() for i, u in enumerate(d.units)}
    rows = grid.shape[0]
    out: list[Destination] = []
    dropped: list[str] = []
    taken: set[str] = set()

    def place(
        name: str, category: str, source: str, fid: str, unit_ids: list[str], xy: FloatArray | None
    ) -> None:
        ordinal = unit_level[unit_ids[0]]
        d = drawn[ordinal]
        same = [u for u in unit_ids if unit_level[u] == ordinal]
        cells = d.cells([index[u] for u in same])
        if not len(cells):
            dropped.append(name)
            return
        if xy is None:
            cu = cells[:, 1].mean() + 0.5
            cv = rows - 1 - cells[:, 0].mean() + 0.5
            cell = nearest(cells, float(cu), float(cv), rows)
        else:
            x, y = (float(v) for v in np.asarray(xy).reshape(2))
            cell = grid.frame.cell_at(x, y, rows)  # the cell holding the point, if free
            if not (cells == cell).all(axis=1).any():
                cu, cv = grid.uv(np.array([[x, y]]))[0]
                cell = nearest(cells, float(cu), float(cv), rows)
        out.append(Destination(name, category, ordinal, cell, source, fid))
        taken.update(same)

    anchors = {a.id: a for a in rec.anchors}
    p = grid.projection
    for occ in rec.occupants:
        anchor = anchors[occ.anchor_id]
        xy = p.many_to_xy(anchor.point.reshape(1, 2))
        place(occ.name, occ.category, "occupant", occ.id, [anchor.unit_id], xy)
    for am in rec.amenities:
        xy = p.many_to_xy(am.point.reshape(1, 2))
        name = am.name or clean_name(am.category)
        place(name, am.category, "amenity", am.id, am.unit_ids, xy)
    for u in rec.units:
        if u.name and u.id not in taken and u.category not in PASSAGES | BLOCKED:
            shown = u.display_point
            at = None if shown is None else p.many_to_xy(shown.reshape(1, 2))
            place(u.name, u.category, "unit", u.id, [u.id], at)
    notes = []
    if dropped:
        notes.append(f"destinations in units with no free cell, left out: {names(dropped)}")
    out.sort(key=lambda d: d.ordinal)
    return out, notes
