"""A map's fixed nodes, drawn once: each floor's floor, walls, start, destinations and their
labels, and on a building each floor's name and its connections' stops labelled by name, and
the connections between floors.

Node names (:func:`app.viewer.sessions.node`): ``/maze/floor``, ``/maze/walls`` (one batched
mesh), ``/maze/start``, ``/maze/goals``, ``/maze/goal_labels/G0``... on a one-floor map;
``/maze/f1/walls``, ``/maze/f1/name``, ``/maze/f1/stops``, ``/maze/f1/stop_labels/C0`` (each
connection's name at its stop)... on each floor of a building, and
``/maze/connections/lift``, ``/maze/connections/stairs``... (one node a kind) between them:
lifts and ramps straight from stop to stop, stairs and escalators zigzagging
(:func:`app.viewer.geometry.connection_segments`), each kind in its colour. A map of more than
:data:`DETAIL_CELLS` free cells has each floor drawn as one image instead.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt
import viser
from viser import BatchedMeshHandle, FrameHandle

from app.arrays import BoolArray
from app.domain.building import Building, Domain
from app.viewer import geometry as geo
from app.viewer.sessions import FLOOR_COLOUR, node
from app.viewer.storeys import floor_levels

WALL_HEIGHT = 0.6
WALL_COLOUR = (52, 61, 82)
START_COLOUR = (46, 160, 67)
GOAL_COLOUR = (230, 168, 23)
#: each kind of connection's colour, line thickness (cells) and flights a floor (0: straight)
CONNECTION_STYLE: dict[str, tuple[tuple[int, int, int], float, int]] = {
    "lift": ((142, 68, 173), 0.22, 0),
    "stairs": ((22, 160, 133), 0.12, 2),
    "escalator": ((211, 84, 140), 0.12, 2),
    "ramp": ((120, 130, 150), 0.16, 0),
}
CONNECTION_Z = 0.05
#: Above this many free cells a map is drawn in a bounded form: walls and the kappa shading as
#: images (a few bytes a cell), and the prior's arrows not at all (44 bytes an arrow, four a
#: cell: a 500 x 500 map would send 55 MB). Below it, everything is drawn as instances.
DETAIL_CELLS = 10_000

Scene = viser.SceneApi


def on_floor(domain: Domain, floor: int | None, cells: npt.ArrayLike) -> BoolArray:
    """Which of ``cells`` lie on ``floor`` (all of them on a one-floor map: None)."""
    floors = geo.floor_of(domain, cells)
    on: BoolArray = np.ones(len(floors), bool) if floor is None else floors == floor
    return on


def draw_floor(
    scene: Scene, domain: Domain, floor: int | None, detailed: bool
) -> BatchedMeshHandle | None:
    """Floor ``floor`` of ``domain`` (None: a one-floor map); its walls' mesh (None: drawn as
    an image, ``detailed`` false)."""
    rows, cols = domain.shape[-2:]
    level = float(floor_levels(domain)[floor or 0])
    if isinstance(domain, Building) and floor is not None:
        info = domain.floors[floor]
        scene.add_label(node("maze", floor, "name"), f"{info.name} ({info.ordinal})",
                        position=(0.0, 0.0, level + WALL_HEIGHT), anchor="bottom-left")  # fmt: skip
    if not detailed:
        draw_image(scene, domain, floor, level)
        return None
    scene.add_box(
        node("maze", floor, "floor"),
        color=FLOOR_COLOUR,
        dimensions=(cols, rows, 0.02),
        position=(cols / 2, rows / 2, level - 0.011),
        cast_shadow=False,
    )
    walls = geo.wall_cells(domain)
    walls = walls[on_floor(domain, floor, walls)]
    vertices, faces = geo.box_mesh()
    handle = scene.add_batched_meshes_simple(
        node("maze", floor, "walls"),
        vertices=vertices,
        faces=faces,
        batched_wxyzs=np.tile([1.0, 0.0, 0.0, 0.0], (len(walls), 1)),
        batched_positions=geo.cell_centres(domain, walls, WALL_HEIGHT / 2),
        batched_scales=np.tile([1.0, 1.0, WALL_HEIGHT], (len(walls), 1)),
        batched_colors=WALL_COLOUR,
        flat_shading=True,
        lod="off",
    )
    start = domain.cell(domain.start)
    if on_floor(domain, floor, [start])[0]:
        scene.add_box(node("maze", floor, "start"), color=START_COLOUR, dimensions=(0.9, 0.9, 0.01),
                      position=tuple(geo.cell_centres(domain, [start], 0.006)[0]))  # fmt: skip
    goal_cells = [domain.cell(g) for g in domain.goals]
    here = np.flatnonzero(on_floor(domain, floor, goal_cells))
    tiles(scene, domain, node("maze", floor, "goals"), [goal_cells[i] for i in here], GOAL_COLOUR)
    goals = geo.cell_centres(domain, [goal_cells[i] for i in here], 0.006)
    for i, pos in zip(here, goals + np.array([0.0, 0.0, 0.2]), strict=True):
        scene.add_label(node("maze", floor, f"goal_labels/G{i}"), domain.goal_label(int(i)),
                        position=tuple(pos))  # fmt: skip
    if isinstance(domain, Building):
        stops = [(k, s) for k, c in enumerate(domain.connections) for s in c.stops
                 if s[0] == floor]  # fmt: skip
        kinds = [domain.connections[k].kind for k, _ in stops]
        tiles(scene, domain, node("maze", floor, "stops"), [s for _, s in stops],
              [CONNECTION_STYLE[kind][0] for kind in kinds])  # fmt: skip
        at = geo.cell_centres(domain, [s for _, s in stops], 0.006) + np.array([0.0, 0.0, 0.2])
        for (k, _), pos in zip(stops, at, strict=True):
            c = domain.connections[k]
            scene.add_label(node("maze", floor, f"stop_labels/C{k}"), c.name or c.kind,
                            position=tuple(pos))  # fmt: skip
    return handle


def tiles(
    scene: Scene, domain: Domain, name: str, cells: Sequence[tuple[int, ...]],
    colours: npt.ArrayLike,
) -> None:  # fmt: skip
    """Flat tiles on ``cells`` (none: no node), in one colour or one each."""
    if not cells:
        return
    vertices, faces = geo.box_mesh()
    each = np.ndim(colours) == 2
    scene.add_batched_meshes_simple(
        name,
        vertices=vertices,
        faces=faces,
        batched_wxyzs=np.tile([1.0, 0.0, 0.0, 0.0], (len(cells), 1)),
        batched_positions=geo.cell_centres(domain, cells, 0.006),
        batched_scales=np.tile([0.9, 0.9, 0.01], (len(cells), 1)),
        batched_colors=np.asarray(colours, np.uint8) if each else tuple(np.ravel(colours)[:3]),
        lod="off",
    )


def draw_connections(scene: Scene, domain: Domain) -> FrameHandle | None:
    """A building's connections between their stops, by kind (one node a kind), in a frame
    (returned: showing one floor hides it); None for a map without."""
    if not isinstance(domain, Building) or not domain.connections:
        return None
    frame = scene.add_frame("/maze/connections", show_axes=False)
    for kind, (colour, thickness, flights) in CONNECTION_STYLE.items():
        parts = [
            geo.connection_segments(domain, i, flights, CONNECTION_Z)
            for i, c in enumerate(domain.connections)
            if c.kind == kind
        ]
        if parts:
            segments = np.concatenate(parts)
            colours = np.broadcast_to(np.array(colour, np.uint8), (*segments.shape[:2], 3))
            scene.add_line_segments(f"/maze/connections/{kind}", segments, colours,
                                    thickness=thickness)  # fmt: skip
    return frame


def draw_image(scene: Scene, domain: Domain, floor: int | None, level: float) -> None:
    """A big map's floor as one image: walls dark, start, goals and stops in their colours
    (one pixel a cell, sent as a PNG)."""
    rows, cols = domain.shape[-2:]
    image = np.empty((rows, cols, 3), dtype=np.uint8)
    image[:] = FLOOR_COLOUR
    image[domain.walls if floor is None else domain.walls[floor]] = WALL_COLOUR
    if isinstance(domain, Building):
        for c in domain.connections:
            for f, r, col in c.stops:
                if f == floor:
                    image[r, col] = CONNECTION_STYLE[c.kind][0]
    marks = [(domain.cell(g), GOAL_COLOUR) for g in domain.goals]
    for cell, colour in [*marks, (domain.cell(domain.start), START_COLOUR)]:
        if on_floor(domain, floor, [cell])[0]:
            image[cell[-2:]] = colour
    scene.add_image(
        node("maze", floor, "image"), image, render_width=cols, render_height=rows,
        format="png", position=(cols / 2, rows / 2, level + 0.002), cast_shadow=False,
        receive_shadow=False,
    )  # fmt: skip
