"""The maze as a viser scene: walls, floor, start and goals, the prior, and live explorers.

Scene tree (names like paths; each top-level layer is a frame whose visibility toggles it)::

    /maze/floor, /maze/walls (one batched mesh), /maze/start, /maze/goals, /maze/goal_labels/*
    /prior/arrows     one flat arrow per free cell and action; length and opacity follow theta
    /shading/cells    a tile per free cell, opaque where a lost explorer would be advised
    /paths, /markers, /advice   live sessions (:mod:`app.viewer.sessions`)

The map's fixed nodes are drawn by :mod:`app.viewer.plan`. A building (a map of several floors)
is drawn floor by floor at its floors' heights (:mod:`app.viewer.storeys`): each layer holds a
frame per floor (``/maze/f0``, ``/prior/f0``, ...) with that floor's nodes in it
(``/maze/f0/walls``, ``/prior/f0/arrows``; the floor's name, its connections' stops, the
destinations labelled by name), and ``/maze/connections`` joins the floors. Showing one floor
(:meth:`MazeScene.show_floor`) hides the other floors' frames and the connections; U and D, up
and down, are flat arrows standing upright in the prior and arrows straight up and down in the
advice.

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
from viser import BatchedMeshHandle, FrameHandle, ImageHandle, SceneNodeHandle

from app.arrays import BoolArray, FloatArray
from app.domain.building import Building, Domain
from app.viewer import geometry as geo
from app.viewer import plan
from app.viewer.plan import DETAIL_CELLS as DETAIL_CELLS  # plan's, said here too
from app.viewer.plan import WALL_HEIGHT as WALL_HEIGHT
from app.viewer.sessions import SessionLayers, floors_of, node
from app.viewer.state import SessionView
from app.viewer.storeys import building_corners, floor_levels, stack_camera

LAYERS = ("prior", "shading", "paths", "markers", "advice")
PRIOR_COLOUR = (38, 92, 200)
SHADE_COLOUR = (235, 87, 87)
SHADE_OPACITY = 0.45


#: viser's default vertical field of view (75 degrees), until a browser says its own.
DEFAULT_FOV = math.radians(75.0)


def top_down_camera(
    domain: Domain, fov: float = DEFAULT_FOV, aspect: float = 1.0, floor: int = 0
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(position, look_at, up) for a camera above the middle of the map (on a building, of
    floor ``floor``), north up, at the height where the map fills a view of vertical field of
    view ``fov`` (radians) and ``aspect`` (width / height), walls included
    (:func:`geometry.fit_height`)."""
    rows, cols = domain.shape[-2:]
    centre = np.array([cols / 2, rows / 2, float(floor_levels(domain)[floor])])
    height = geo.fit_height(rows, cols, fov, aspect, top=WALL_HEIGHT)
    return centre + np.array([0.0, 0.0, height]), centre, np.array([0.0, 1.0, 0.0])


def building_camera(
    building: Building, fov: float = DEFAULT_FOV, aspect: float = 1.0
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(position, look_at, up) for a camera that sees every floor of ``building`` from the
    south and above (:func:`app.viewer.storeys.stack_camera`), walls included."""
    return stack_camera(building_corners(building, WALL_HEIGHT), fov, aspect)


Target = viser.ViserServer | viser.ClientHandle


class MazeScene:
    """One domain drawn into a viser scene (a server's, shown to every browser, or one
    client's), with its prior and the live sessions on it. On a building, ``floor_walls``,
    ``floor_arrows`` and ``floor_shading`` hold each floor's nodes, lowest first; ``walls``,
    ``prior_arrows`` and ``shading`` are a one-floor map's (None on a building)."""

    def __init__(self, server: Target, domain: Domain, theta: npt.ArrayLike):
        self.server = server
        self.domain = domain
        self.floors = floors_of(domain)  # [None] on a one-floor map
        self.states = geo.floor_states(domain)  # each floor's states
        self.detailed = domain.n_states <= DETAIL_CELLS
        self.floor_walls: list[BatchedMeshHandle] = []  # none on a big map: images instead
        self.floor_arrows: list[BatchedMeshHandle] = []  # none on a big map
        none: list[BatchedMeshHandle | ImageHandle | None] = [None] * len(self.floors)
        self.floor_shading = none
        self.shown_floor: int | None = None
        scene = server.scene
        self.frames = {name: scene.add_frame(f"/{name}", show_axes=False) for name in LAYERS}
        self.maze_frame = scene.add_frame("/maze", show_axes=False)
        # on a building, a frame per floor in each layer: showing one floor hides the others'
        self.floor_frames: list[list[FrameHandle]] = [
            [scene.add_frame(f"/{layer}/f{f}", show_axes=False) for layer in ("maze", *LAYERS)]
            for f in self.floors
            if f is not None
        ]
        for floor in self.floors:
            walls = plan.draw_floor(scene, domain, floor, self.detailed)
            if walls is not None:
                self.floor_walls.append(walls)
        self.connections = plan.draw_connections(scene, domain)
        self._draw_prior(theta)
        self._draw_shading()
        self.live = SessionLayers(server, domain)

    @property
    def walls(self) -> BatchedMeshHandle | None:
        return self._one(self.floor_walls)

    @property
    def prior_arrows(self) -> BatchedMeshHandle | None:
        return self._one(self.floor_arrows)

    @property
    def shading(self) -> BatchedMeshHandle | ImageHandle | None:
        return self.floor_shading[0] if self.floors == [None] else None

    def _one(self, handles: list[BatchedMeshHandle]) -> BatchedMeshHandle | None:
        return handles[0] if handles and self.floors == [None] else None

    # ---- the prior and the kappa shading -------------------------------------------------
    def _draw_prior(self, theta: npt.ArrayLike) -> None:
        if not self.detailed:  # not drawn: four arrows a cell would be too many
            return
        a = self.domain.n_actions
        positions, wxyzs, scales, opacities = geo.prior_arrows(self.domain, theta)
        vertices, faces = geo.flat_arrow_mesh()
        for floor, states in zip(self.floors, self.states, strict=True):
            at = slice(a * states.start, a * states.stop)
            self.floor_arrows.append(self.server.scene.add_batched_meshes_simple(
                node("prior", floor, "arrows"),
                vertices=vertices,
                faces=faces,
                batched_wxyzs=wxyzs[at],
                batched_positions=positions[at],
                batched_scales=scales[at],
                batched_colors=PRIOR_COLOUR,
                batched_opacities=opacities[at],
                opacity=1.0,
                side="double",
                cast_shadow=False,
                receive_shadow=False,
                lod="off",
            ))  # fmt: skip

    def set_prior(self, theta: npt.ArrayLike) -> None:
        """The prior changed: resize and re-shade the arrows in place."""
        if not self.floor_arrows:
            return
        a = self.domain.n_actions
        _, _, scales, opacities = geo.prior_arrows(self.domain, theta)
        for arrows, states in zip(self.floor_arrows, self.states, strict=True):
            at = slice(a * states.start, a * states.stop)
            arrows.batched_scales = scales[at].astype(np.float32)
            arrows.batched_opacities = opacities[at].astype(np.float32)

    def _draw_shading(self) -> None:
        d = self.domain
        self.shaded = np.zeros(d.n_states, dtype=bool)
        self._shade_drawn = False
        if not self.detailed:  # images, made at the first shade
            return
        vertices, faces = geo.box_mesh()
        for k, (floor, states) in enumerate(zip(self.floors, self.states, strict=True)):
            n = states.stop - states.start
            self.floor_shading[k] = self.server.scene.add_batched_meshes_simple(
                node("shading", floor, "cells"),
                vertices=vertices,
                faces=faces,
                batched_wxyzs=np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)),
                batched_positions=geo.cell_centres(d, d.cells[states], 0.004),
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
        if not np.array_equal(mask, self.shaded) or not (self.detailed or self._shade_drawn):
            self.shaded = mask
            self._shade_drawn = True
            for k, (floor, states) in enumerate(zip(self.floors, self.states, strict=True)):
                shading = self.floor_shading[k]
                if isinstance(shading, BatchedMeshHandle):
                    opacity = np.where(mask[states], SHADE_OPACITY, 0.0).astype(np.float32)
                    shading.batched_opacities = opacity
                else:
                    self._shade_image(k, floor, states, mask)
        return int(mask.sum())

    def _shade_image(self, k: int, floor: int | None, states: slice, mask: BoolArray) -> None:
        d = self.domain
        rows, cols = d.shape[-2:]
        image = np.zeros((rows, cols, 4), dtype=np.uint8)
        cells = d.cells[states][mask[states]]
        image[cells[:, -2], cells[:, -1]] = (*SHADE_COLOUR, int(255 * SHADE_OPACITY))
        level = float(floor_levels(d)[floor or 0])
        self.floor_shading[k] = self.server.scene.add_image(
            node("shading", floor, "image"), image, render_width=cols, render_height=rows,
            format="png", position=(cols / 2, rows / 2, level + 0.004), cast_shadow=False,
            receive_shadow=False,
        )  # fmt: skip

    def set_layer(self, layer: str, visible: bool) -> None:
        if layer not in self.frames:
            raise ValueError(f"unknown layer {layer!r}: one of {', '.join(LAYERS)}")
        self.frames[layer].visible = visible

    # ---- floors and the camera -----------------------------------------------------------
    def show_floor(self, floor: int | None) -> None:
        """Show every floor (None) or floor ``floor`` (its index) alone: the others' maps,
        prior, shading and explorers hidden, and the connections between floors."""
        if floor is not None and not 0 <= floor < len(self.floor_frames):
            raise ValueError(f"no floor {floor}: this map has {len(self.floor_frames)} floors")
        if floor == self.shown_floor:
            return
        self.shown_floor = floor
        for f, frames in enumerate(self.floor_frames):
            for frame in frames:
                frame.visible = floor is None or f == floor
        if self.connections is not None:
            self.connections.visible = floor is None

    def camera(
        self, fov: float = DEFAULT_FOV, aspect: float = 1.0
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(position, look_at, up) of the camera that fits what is shown: a one-floor map or
        the floor shown from above, every floor of a building from the south and above."""
        d = self.domain
        if isinstance(d, Building) and self.shown_floor is None:
            return building_camera(d, fov, aspect)
        return top_down_camera(d, fov, aspect, self.shown_floor or 0)

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
