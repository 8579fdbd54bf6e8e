"""Live sessions on a maze: each one's recent path, where it is, and the advice it was given.

Scene nodes (one each for all sessions, so a tick sends a few messages, not one per session)::

    /paths/lines      recent paths as line segments, in each session's colour, older parts faded
    /markers/points   where each session is now; /markers/picked labels the picked session
    /advice/arrows    the advice each session was given, drawn at the cell where it was given

Their sizes change with every move, so each is re-created under the same name (viser replaces
the node) and removed when there is nothing to draw. On a building each floor has its own
(``/paths/f1/lines``, ``/markers/f1/points``, ``/advice/f1/arrows``, ``/markers/f1/picked``:
:func:`node`), so that showing one floor hides the others' explorers: a path's segment belongs
to the floor it leaves (a ride rises from it), advice to the floor where it was given (U and D
as arrows straight up and down).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import viser
from viser import SceneNodeHandle

from app.arrays import BoolArray, FloatArray, IntArray
from app.domain.building import Domain
from app.viewer import geometry as geo
from app.viewer.state import SessionView

FLOOR_COLOUR = (236, 233, 224)
#: Distinct colours; a session keeps its colour while it lives, a new one takes the least used.
PALETTE = np.array(
    [[214, 39, 40], [148, 103, 189], [23, 190, 207], [255, 127, 14], [227, 119, 194],
     [44, 160, 44], [140, 86, 75], [188, 189, 34], [31, 119, 180], [127, 127, 127]],
    dtype=np.uint8,
)  # fmt: skip
PATH_Z, MARKER_Z, ADVICE_Z = 0.12, 0.35, 0.3
#: Advice arrows below this probability are not drawn (they would be specks).
ADVICE_MIN_P = 0.05
#: How far an advice arrow with probability 1 reaches (cells): past the cell, to stand out.
ADVICE_REACH = 0.85


def node(layer: str, floor: int | None, leaf: str) -> str:
    """The scene name of ``leaf`` in ``layer`` on ``floor`` (None: a one-floor map, whose
    nodes sit in the layer itself): ``/paths/lines``, ``/paths/f1/lines``."""
    return f"/{layer}/{leaf}" if floor is None else f"/{layer}/f{floor}/{leaf}"


def floors_of(domain: Domain) -> list[int | None]:
    """The floors to draw each layer on: [None] on a one-floor map, else each index."""
    return [None] if domain.width == 2 else list(range(domain.shape[0]))


def palette_colour(index: int) -> tuple[int, int, int]:
    r, g, b = PALETTE[index % len(PALETTE)]
    return (int(r), int(g), int(b))


class SessionLayers:
    """The live sessions of one domain, drawn into a viser scene (a server's or a client's)."""

    def __init__(self, server: viser.ViserServer | viser.ClientHandle, domain: Domain):
        self.server = server
        self.domain = domain
        self.floors = floors_of(domain)
        self.session_ids: tuple[str, ...] = ()
        self.picked: str | None = None
        self._session_key: tuple[object, ...] = ()
        self._nodes: dict[str, SceneNodeHandle] = {}
        self._colour_index: dict[str, int] = {}

    def update(self, sessions: Sequence[SessionView], picked: str | None = None) -> bool:
        """Draw these sessions (all on this domain); returns whether anything was redrawn."""
        key = (picked, *((s.session_id, s.version) for s in sessions))
        if key == self._session_key:
            return False
        self._session_key = key
        self.session_ids = tuple(s.session_id for s in sessions)
        self.picked = picked
        self._assign_colours(self.session_ids)
        self._draw_paths(sessions)
        self._draw_markers(sessions, picked)
        self._draw_advice(sessions)
        return True

    def colour(self, session_id: str) -> tuple[int, int, int]:
        return palette_colour(self._colour_index.get(session_id, 0))

    def _colours(self, sessions: Sequence[SessionView]) -> FloatArray:
        """(len(sessions), 3) RGB rows, one per session."""
        rows = np.array([self.colour(s.session_id) for s in sessions], dtype=np.float64)
        return rows.reshape(-1, 3)

    def _assign_colours(self, ids: Sequence[str]) -> None:
        """A session keeps its colour while it lives; a new one takes the least used colour."""
        live = set(ids)
        self._colour_index = {k: v for k, v in self._colour_index.items() if k in live}
        for sid in ids:
            if sid not in self._colour_index:
                used = np.bincount(list(self._colour_index.values()), minlength=len(PALETTE))
                self._colour_index[sid] = int(np.argmin(used))

    def _on(self, floor: int | None, floors: IntArray) -> BoolArray:
        """Which of the things on ``floors`` are drawn on ``floor`` (None: all)."""
        on: BoolArray = np.ones(len(floors), dtype=bool) if floor is None else floors == floor
        return on

    def _draw_paths(self, sessions: Sequence[SessionView]) -> None:
        segments, owner, age = geo.path_segments(self.domain, [s.path for s in sessions], PATH_Z)
        # older segments fade towards the floor, so the direction of travel shows
        fade = (0.25 + 0.75 * age)[:, None]
        colours = fade * self._colours(sessions)[owner] + (1 - fade) * np.array(FLOOR_COLOUR)
        pairs = np.repeat(colours[:, None, :], 2, axis=1).astype(np.uint8)
        leaves = geo.floor_at(self.domain, segments[:, 0, 2])
        for floor in self.floors:
            name, on = node("paths", floor, "lines"), self._on(floor, leaves)

            def lines(pts: FloatArray, name: str = name, on: BoolArray = on) -> SceneNodeHandle:
                return self.server.scene.add_line_segments(name, pts, pairs[on], thickness=0.14)

            self._replace_or_remove(name, [segments[on]], lines)

    def _draw_markers(self, sessions: Sequence[SessionView], picked: str | None) -> None:
        scene = self.server.scene
        where = [s.position for s in sessions]
        pts = geo.cell_centres(self.domain, where, MARKER_Z)
        floors = geo.floor_of(self.domain, where)
        colours = np.array([self.colour(s.session_id) for s in sessions], dtype=np.uint8)
        chosen = [s for s in sessions if s.session_id == picked]
        for floor in self.floors:
            name, on = node("markers", floor, "points"), self._on(floor, floors)

            def points(p: FloatArray, name: str = name, on: BoolArray = on) -> SceneNodeHandle:
                return scene.add_point_cloud(
                    name, p, colours[on].reshape(-1, 3), point_size=0.62, point_shape="circle"
                )

            self._replace_or_remove(name, [pts[on]], points)
            label = node("markers", floor, "picked")
            if chosen and self._on(floor, geo.floor_of(self.domain, [chosen[0].position]))[0]:
                pos = geo.cell_centres(self.domain, [chosen[0].position], MARKER_Z + 0.3)[0]
                self._nodes[label] = scene.add_label(label, f"▶ {picked}", position=tuple(pos))
            else:
                self._remove(label)

    def _draw_advice(self, sessions: Sequence[SessionView]) -> None:
        cells: list[tuple[int, ...]] = []
        probs: list[tuple[float, ...]] = []
        owner: list[int] = []
        for k, s in enumerate(sessions):
            latest = {cell: p for _, cell, p in s.advice}  # one set of arrows per cell
            cells.extend(latest)
            probs.extend(latest.values())
            owner.extend([k] * len(latest))
        points, row = geo.advice_arrows(
            self.domain, cells, probs, ADVICE_REACH, ADVICE_MIN_P, ADVICE_Z
        )
        colours = self._colours(sessions)[np.asarray(owner, dtype=np.int64)[row]]
        floors = geo.floor_of(self.domain, cells)[row]
        for floor in self.floors:
            name, on = node("advice", floor, "arrows"), self._on(floor, floors)

            def arrows(pts: FloatArray, name: str = name, on: BoolArray = on) -> SceneNodeHandle:
                return self.server.scene.add_arrows(
                    name, pts, colours[on].astype(np.uint8),
                    shaft_radius=0.05, head_radius=0.13, head_length=0.16,
                )  # fmt: skip

            self._replace_or_remove(name, [points[on]], arrows)

    def _replace_or_remove(
        self, name: str, parts: list[FloatArray], add: Callable[[FloatArray], SceneNodeHandle]
    ) -> None:
        """Re-create node ``name`` from the concatenated ``parts``, or remove it if empty."""
        parts = [p for p in parts if len(p)]
        if parts:
            self._nodes[name] = add(np.concatenate(parts))
        else:
            self._remove(name)

    def _remove(self, name: str) -> None:
        handle = self._nodes.pop(name, None)
        if handle is not None:
            handle.remove()

    @property
    def nodes(self) -> dict[str, SceneNodeHandle]:
        """The nodes drawn now, by name (paths, markers, advice, label)."""
        return dict(self._nodes)

    def forget(self) -> None:
        """The layers' frames were removed with the domain: drop the handles."""
        self._nodes.clear()
        self._session_key = ()
