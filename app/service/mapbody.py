"""A domain PUT's map, whichever way it came: rows (``map``, with ``resolution``, ``origin`` and
``destinations`` as fields) or a map file's text (``text``, or a ``text/plain`` body: its header
lines give the resolution, origin and the destinations' names). Errors are ``maze check``'s,
naming the line and column of the text. A map of several floors (``floor:`` lines, in a text
only) is read into a :class:`~app.domain.building.Building` (:func:`building_of`)."""

from __future__ import annotations

from app.domain.building import Building
from app.domain.floors import is_floors_text, read_floors
from app.domain.grid import Frame, Header, MapError, NamedCell, split_text
from app.service.problems import BadInput
from app.service.schemas import DomainPut


def map_of(body: DomainPut) -> tuple[Header, list[str]]:
    """(what the header gives: the grid's frame, the destinations' names, how many lines came
    before the rows; the rows)."""
    if body.text is not None:
        try:
            return split_text(body.text)
        except MapError as exc:
            raise BadInput(f"map: {exc}") from None
    assert body.map is not None  # DomainPut holds one of them
    frame = None
    if body.resolution is not None:
        ox, oy, *yaw = body.origin if body.origin is not None else (0.0, 0.0)
        frame = Frame(body.resolution, (ox, oy, yaw[0] if yaw else 0.0))
    names = tuple(
        NamedCell(d.cell[0], d.cell[1], d.name, label=f"destinations[{i}]")
        for i, d in enumerate(body.destinations or ())
    )
    return Header(frame, names, 0), body.map


def text_of(raw: bytes) -> str:
    """A ``text/plain`` body as text: UTF-8 (a byte order mark is dropped)."""
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise BadInput(
            f"the map file is not UTF-8 text ({exc.reason} at byte {exc.start}): a map is "
            "ASCII ('#', '.', 'S', 'G'); `maze import` makes one of an image, a ROS or a "
            "Moving AI map"
        ) from None


def building_of(body: DomainPut, max_cells: int, name: str) -> Building | None:
    """*Worker thread.* None for a one-floor map. A map text of several floors read and
    checked as ``maze check`` checks it (its errors naming the floor, line and column; past
    ``max_cells`` cells in all, refused before the check): the building, named ``name``."""
    if body.text is None or not is_floors_text(body.text):
        return None
    try:
        parts = read_floors(body.text)
        cells = sum(len(f.rows) * max((len(r) for r in f.rows), default=0) for f in parts.floors)
        if cells > max_cells:
            raise BadInput(
                f"map: {len(parts.floors)} floors of {cells} cells in all: this service takes "
                f"maps of at most {max_cells} cells (ADVISOR_MAX_MAP_CELLS)"
            )
        return Building.from_parts(parts.floors, parts.connections, parts.names, parts.frame, name)
    except MapError as exc:
        raise BadInput(f"map: {exc}") from None
