"""The maze as a viser scene: walls, floor, start and goals, the prior, and live explorers.

Scene tree (names like paths; each top-level layer is a frame whose visibility toggles it)::

    /maze/floor, /maze/walls (one batched mesh), /maze/start, /maze/goals, /maze/goal_labels/*
    /prior/arrows     one flat arrow per free cell and action; length and opacity follow theta
    /shading/cells    a tile per free cell, opaque where a lost explorer would be advised
    /paths, /markers, /advice   live sessions (:mod:`app.viewer.sessions`)

A :class:`MazeScene` draws one domain; it is fed plain data (:mod:`app.viewer.state`) and keeps
no reference to any service. The map, prior and shading have a fixed number of instances and
update their arrays in place.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt
import viser
from viser import BatchedMeshHandle, ImageHandle, SceneNodeHandle

from app.arrays import FloatArray
from app.domain.grid import GridDomain
from app.viewer import geometry as geo
from app.viewer.sessions import FLOOR_COLOUR, SessionLayers
from app.viewer.state import SessionView

LAYERS = ("prior", "shading", "paths", "markers", "advice")
WALL_HEIGHT = 0.6
WALL_COLOUR = (52, 61, 82)
START_COLOUR = (46, 160, 67)
GOAL_COLOUR = (230, 168, 23)
PRIOR_COLOUR = (38, 92, 200)
SHADE_COLOUR = (235, 87, 87)
SHADE_OPACITY = 0.45


#: viser's default vertical field of view (75 degrees), until a browser says its own.
DEFAULT_FOV = math.radians(75.0)


def top_down_camera(
    domain: GridDomain, fov: float = DEFAULT_FOV, aspect: float = 1.0
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(position, look_at, up) for a camera above the middle of the map, north up, at the
    height where the map fills a view of vertical field of view ``fov`` (radians) and
    ``aspect`` (width / height), walls included (:func:`geometry.fit_height`)."""
    rows, cols = domain.shape
    centre = np.array([cols / 2, rows / 2, 0.0])
    height = geo.fit_height(rows, cols, fov, aspect, top=WALL_HEIGHT)
    return centre + np.array([0.0, 0.0, height]), centre, np.array([0.0, 1.0, 0.0])


Target = viser.ViserServer | viser.ClientHandle
#: Above this many free cells a map is drawn in a bounded form: walls and the kappa shading as
#: images (a few bytes a cell), and the prior's arrows not at all (44 bytes an arrow, four a
#: cell: a 500 x 500 map would send 55 MB). Below it, everything is drawn as instances.
DETAIL_CELLS = 10_000


class MazeScene:
    """One domain drawn into a viser scene (a server's, shown to every browser, or one
    client's), with its prior and the live sessions on it."""

    def __init__(self, server: Target, domain: GridDomain, theta: npt.ArrayLike):
        self.server = server
        self.domain = domain
        self.detailed = domain.n_states <= DETAIL_CELLS
        self.walls: BatchedMeshHandle | None = None  # none on a big map: an image instead
        self.prior_arrows: BatchedMeshHandle | None = None  # none on a big map
        self.shading: BatchedMeshHandle | ImageHandle | None = None
        self.frames = {name: server.scene.add_frame(f"/{name}", show_axes=False) for name in LAYERS}
        self.maze_frame = server.scene.add_frame("/maze", show_axes=False)
        self._draw_static()
        self._draw_prior(theta)
        self._draw_shading()
        self.live = SessionLayers(server, domain)

    # ---- the map ------------------------------------------------------------------------
    def _draw_static(self) -> None:
        d, scene = self.domain, self.server.scene
        rows, cols = d.shape
        if not self.detailed:
            self._draw_map_image()
            return
        scene.add_box(
            "/maze/floor",
            color=FLOOR_COLOUR,
            dimensions=(cols, rows, 0.02),
            position=(cols / 2, rows / 2, -0.011),
            cast_shadow=False,
        )
        walls = geo.wall_cells(d)
        vertices, faces = geo.box_mesh()
        self.walls = scene.add_batched_meshes_simple(
            "/maze/walls",
            vertices=vertices,
            faces=faces,
            batched_wxyzs=np.tile([1.0, 0.0, 0.0, 0.0], (len(walls), 1)),
            batched_positions=geo.cell_centres(d, walls, WALL_HEIGHT / 2),
            batched_scales=np.tile([1.0, 1.0, WALL_HEIGHT], (len(walls), 1)),
            batched_colors=WALL_COLOUR,
            flat_shading=True,
            lod="off",
        )
        start = geo.cell_centres(d, [d.cell(d.start)], 0.006)[0]
        scene.add_box("/maze/start", color=START_COLOUR, dimensions=(0.9, 0.9, 0.01),
                      position=tuple(start))  # fmt: skip
        goals = geo.cell_centres(d, [d.cell(g) for g in d.goals], 0.006)
        scene.add_batched_meshes_simple(
            "/maze/goals",
            vertices=vertices,
            faces=faces,
            batched_wxyzs=np.tile([1.0, 0.0, 0.0, 0.0], (len(goals), 1)),
            batched_positions=goals,
            batched_scales=np.tile([0.9, 0.9, 0.01], (len(goals), 1)),
            batched_colors=GOAL_COLOUR,
            lod="off",
        )
        for i, pos in enumerate(goals + np.array([0.0, 0.0, 0.2])):
            scene.add_label(f"/maze/goal_labels/G{i}", d.goal_label(i), position=tuple(pos))

    def _draw_map_image(self) -> None:
        """A big map as one image on the floor: walls dark, start and goals in their colours
        (one pixel a cell, sent as a PNG)."""
        d, scene = self.domain, self.server.scene
        rows, cols = d.shape
        image = np.empty((rows, cols, 3), dtype=np.uint8)
        image[:] = FLOOR_COLOUR
        image[d.walls] = WALL_COLOUR
        for g in d.goals:
            image[d.cell(g)] = GOAL_COLOUR
        image[d.cell(d.start)] = START_COLOUR
        scene.add_image(
            "/maze/image", image, render_width=cols, render_height=rows, format="png",
            position=(cols / 2, rows / 2, 0.002), cast_shadow=False, receive_shadow=False,
        )  # fmt: skip

    # ---- the prior and the kappa shading -------------------------------------------------
    def _draw_prior(self, theta: npt.ArrayLike) -> None:
        if not self.detailed:  # not drawn: four arrows a cell would be too many
            return
        positions, wxyzs, scales, opacities = geo.prior_arrows(self.domain, theta)
        vertices, faces = geo.flat_arrow_mesh()
        self.prior_arrows = self.server.scene.add_batched_meshes_simple(
            "/prior/arrows",
            vertices=vertices,
            faces=faces,
            batched_wxyzs=wxyzs,
            batched_positions=positions,
            batched_scales=scales,
            batched_colors=PRIOR_COLOUR,
            batched_opacities=opacities,
            opacity=1.0,
            side="double",
            cast_shadow=False,
            receive_shadow=False,
            lod="off",
        )

    def set_prior(self, theta: npt.ArrayLike) -> None:
        """The prior changed: resize and re-shade the arrows in place."""
        if self.prior_arrows is None:
            return
        _, _, scales, opacities = geo.prior_arrows(self.domain, theta)
        self.prior_arrows.batched_scales = scales.astype(np.float32)
        self.prior_arrows.batched_opacities = opacities.astype(np.float32)

    def _draw_shading(self) -> None:
        d = self.domain
        n = d.n_states
        self.shaded = np.zeros(n, dtype=bool)
        if not self.detailed:  # an image, made at the first shade
            return
        vertices, faces = geo.box_mesh()
        self.shading = self.server.scene.add_batched_meshes_simple(
            "/shading/cells",
            vertices=vertices,
            faces=faces,
            batched_wxyzs=np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)),
            batched_positions=geo.cell_centres(d, d.cells, 0.004),
            batched_scales=np.tile([0.98, 0.98, 0.004], (n, 1)),
            batched_colors=SHADE_COLOUR,
            batched_opacities=np.zeros(n),
            opacity=1.0,
            cast_shadow=False,
            receive_shadow=False,
            lod="off",
        )

    def shade(self, theta: npt.ArrayLike, kappa: float, p_normal: float = 0.0) -> int:
        """Shade the cells where an explorer with P(M1 | H) = ``p_normal`` would be advised at
        ``kappa`` (see :func:`geometry.advised_cells`); returns how many cells that is."""
        mask = geo.advised_cells(theta, kappa, p_normal)
        if not np.array_equal(mask, self.shaded) or (self.shading is None and not self.detailed):
            self.shaded = mask
            if isinstance(self.shading, BatchedMeshHandle):
                opacity = np.where(mask, SHADE_OPACITY, 0.0).astype(np.float32)
                self.shading.batched_opacities = opacity
            else:
                self._shade_image(mask)
        return int(mask.sum())

    def _shade_image(self, mask: npt.NDArray[np.bool_]) -> None:
        d = self.domain
        rows, cols = d.shape
        image = np.zeros((rows, cols, 4), dtype=np.uint8)
        cells = d.cells[mask]
        image[cells[:, 0], cells[:, 1]] = (*SHADE_COLOUR, int(255 * SHADE_OPACITY))
        self.shading = self.server.scene.add_image(
            "/shading/image", image, render_width=cols, render_height=rows, format="png",
            position=(cols / 2, rows / 2, 0.004), cast_shadow=False, receive_shadow=False,
        )  # fmt: skip

    def set_layer(self, layer: str, visible: bool) -> None:
        if layer not in self.frames:
            raise ValueError(f"unknown layer {layer!r}: one of {', '.join(LAYERS)}")
        self.frames[layer].visible = visible

    # ---- live sessions -------------------------------------------------------------------
    def update_sessions(self, sessions: Sequence[SessionView], picked: str | None = None) -> bool:
        """Draw these sessions (all on this domain); returns whether anything was redrawn."""
        return self.live.update(sessions, picked)

    @property
    def session_ids(self) -> tuple[str, ...]:
        return self.live.session_ids

    @property
    def session_nodes(self) -> dict[str, SceneNodeHandle]:
        """The nodes drawn for live sessions, by name (paths, markers, advice, label)."""
        return self.live.nodes

    def colour(self, session_id: str) -> tuple[int, int, int]:
        return self.live.colour(session_id)

    def remove(self) -> None:
        """Take the whole domain out of the scene (before drawing another)."""
        for frame in (*self.frames.values(), self.maze_frame):
            frame.remove()
        self.live.forget()
