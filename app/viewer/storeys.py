"""How the floors of a building stack in the scene, and what joins them.

Metres to scene units. One scene unit is one cell, so a metre is ``1 / resolution`` units
(the map's frame; :data:`CELL_METRES` where it has none, the cell the generated buildings take
for their rides). A floor's height is its ``elevation`` in metres; where a floor has none,
between two floors that have one it is interpolated by ordinal, above or below them (or
everywhere, when no floor has one) :data:`STOREY_METRES` an ordinal. Drawn to scale, floors 4 m
apart on a map of 100 cells of 0.5 m would lie 8 units apart under 100 units of floor: too
close to tell apart from any angle. So every height is multiplied by one factor, the least
that sets the closest two floors :data:`STOREY_SHARE` of the map's rows apart (its extent
from south to north, along which the camera looks; never less than to scale): the floors keep
the proportions of their heights. The lowest floor lies in the plane z = 0, as a one-floor map
does. Seen from :data:`STACK_PITCH` above the horizon a floor covers about its rows times the
pitch's sine on the screen, and the gap to the next floor the gap times its cosine: a gap of
the rows (tan 38 degrees = 0.78) keeps a floor clear of the one above it, but for the
perspective's enlarging the nearer, upper one (a 40 x 80 floor and a 20 x 20 one were looked
at; a steeper view hid the stairs behind the upper floor, a flatter one showed the top floor
edge on).

Connections are drawn from stop to stop at these heights
(:func:`app.viewer.geometry.connection_segments`).

The camera: a building is seen whole from the south, above (:func:`stack_camera`), at the
distance where every corner of its floors, walls included, is in view; one floor picked, from
above as a one-floor map is (:func:`app.viewer.scene.top_down_camera`).
"""

from __future__ import annotations

import math
import weakref

import numpy as np
import numpy.typing as npt

from app.arrays import FloatArray
from app.domain.building import Building, Domain

#: metres between floors where the map gives no elevation (the generated buildings' storey)
STOREY_METRES = 4.0
#: metres of a cell's side where the map has no frame
CELL_METRES = 1.0
#: the closest two floors are drawn at least this share of the map's rows apart
STOREY_SHARE = 1.0
#: the oblique camera's angle above the horizon (radians), looking north (the module docstring)
STACK_PITCH = math.radians(38.0)

_levels: weakref.WeakKeyDictionary[Building, FloatArray] = weakref.WeakKeyDictionary()


def elevations(building: Building) -> FloatArray:
    """Each floor's height in metres, lowest first: its elevation, or one made up where the
    map gives none (the module docstring)."""
    ordinals = np.array([f.ordinal for f in building.floors], dtype=np.float64)
    given = np.array([f.elevation is not None for f in building.floors])
    if not given.any():
        out: FloatArray = ordinals * STOREY_METRES
        return out
    known = ordinals[given]
    heights = np.array([f.elevation for f in building.floors if f.elevation is not None])
    out = np.interp(ordinals, known, heights)
    below, above = ordinals < known[0], ordinals > known[-1]
    out[below] = heights[0] - (known[0] - ordinals[below]) * STOREY_METRES
    out[above] = heights[-1] + (ordinals[above] - known[-1]) * STOREY_METRES
    return out


def metres_to_units(building: Building) -> float:
    """Scene units per metre of height: the map's cells per metre, or more where its floors
    would be drawn too close (the module docstring)."""
    cell = building.frame.resolution if building.frame is not None else CELL_METRES
    gaps = np.diff(elevations(building))
    least = float(gaps[gaps > 0].min()) if np.any(gaps > 0) else STOREY_METRES
    return max(1.0 / cell, STOREY_SHARE * building.shape[1] / least)


def floor_levels(domain: Domain) -> FloatArray:
    """The height z of each floor in the scene, lowest first (0 for a one-floor map's)."""
    if not isinstance(domain, Building):
        return np.zeros(1)
    known = _levels.get(domain)
    if known is None:
        heights = elevations(domain)
        known = (heights - heights[0]) * metres_to_units(domain)
        known.setflags(write=False)
        _levels[domain] = known
    return known


def stack_camera(
    corners: npt.ArrayLike, fov: float, aspect: float, pitch: float = STACK_PITCH,
    margin: float = 1.04,
) -> tuple[FloatArray, FloatArray, FloatArray]:  # fmt: skip
    """(position, look_at, up) of a camera looking north and down by ``pitch`` at the
    middle of the box of ``corners`` (N, 3), as near as it can be with every corner in a view
    of vertical field of view ``fov`` (radians) and ``aspect`` (width / height), the box's
    extent times ``margin``.

    A point p (from the look-at point) at distance d along the view's axis lies at depth
    d - p.back from the camera, and across and up at p.right and p.up: it is in view when
    |p.right| <= depth tan(fov / 2) aspect and |p.up| <= depth tan(fov / 2); the least d
    that holds for every corner.
    """
    if not 0.0 < fov < math.pi or not aspect > 0.0:
        raise ValueError(f"fov must be in (0, pi) and aspect positive, got {fov}, {aspect}")
    box = np.asarray(corners, dtype=np.float64).reshape(-1, 3)
    look_at = (box.min(axis=0) + box.max(axis=0)) / 2
    back = np.array([0.0, -math.cos(pitch), math.sin(pitch)])  # towards the camera
    right = np.array([1.0, 0.0, 0.0])
    up = np.cross(back, right)  # right x up = back: a right-handed view
    p = box - look_at
    tan = math.tan(fov / 2)
    need = p @ back + margin * np.maximum(np.abs(p @ right) / (tan * aspect), np.abs(p @ up) / tan)
    distance = float(need.max())
    return look_at + distance * back, look_at, np.array([0.0, 0.0, 1.0])


def building_corners(building: Building, top: float) -> FloatArray:
    """The 8 corners (8, 3) of the box around the building's floors, ``top`` above the
    highest."""
    _, rows, cols = building.shape
    levels = floor_levels(building)
    return np.array(
        [[x, y, z] for x in (0.0, cols) for y in (0.0, rows) for z in (levels[0], levels[-1] + top)]
    )
