"""A domain PUT's map, whichever way it came: rows (``map``, with ``resolution``, ``origin`` and
``destinations`` as fields) or a map file's text (``text``, or a ``text/plain`` body: its header
lines give the resolution, origin and the destinations' names). Errors are ``maze check``'s,
naming the line and column of the text."""

from __future__ import annotations

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
