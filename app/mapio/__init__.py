"""Maps from other formats: Moving AI benchmarks, ROS map_server, plain floor-plan images.

Each reader returns an :class:`Imported` grid of passable cells (and the metric frame, when the
format has one); :func:`app.domain.place.largest_region` and :func:`app.domain.place.place` make
a domain of it. Errors are :class:`MapImportError` (a :class:`~app.domain.grid.MapError`)
naming the file and the problem in one line; values quoted from a file are cut short. Every
reader checks what its import will take against a :class:`~app.mapio.budget.MemoryBudget`
from the file's header, before reading the rest.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Literal

from app.arrays import BoolArray
from app.domain.grid import Frame, MapError

if TYPE_CHECKING:
    from app.mapio.budget import MemoryBudget

Format = Literal["auto", "movingai", "ros", "image"]
FORMATS: tuple[str, ...] = ("auto", "movingai", "ros", "image")
IMAGE_SUFFIXES = (".png", ".pgm", ".bmp", ".gif", ".jpg", ".jpeg", ".tif", ".tiff")


#: how many characters of a value from a file an error message quotes
QUOTE_CHARS = 80


class MapImportError(MapError):
    """A file that cannot be imported; the message names the file and the problem."""


def shorten(value: object, limit: int = QUOTE_CHARS) -> str:
    """``repr(value)``, cut to ``limit`` characters ending in ``...`` when longer."""
    if isinstance(value, str) and len(value) > limit:
        value = value[:limit]  # its repr's start is all that is shown
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def brief(error: object, limit: int = 2 * QUOTE_CHARS) -> str:
    """Another library's error message on one line, cut to ``limit`` characters."""
    text = " ".join(str(error).split()) or type(error).__name__
    return text if len(text) <= limit else text[: limit - 3] + "..."


def utf8(raw: bytes, where: str, what: str, bom: bool = False) -> str:
    """``raw`` as UTF-8 text (a byte order mark dropped with ``bom``), else
    :class:`MapImportError`: ``where`` is not ``what`` (not UTF-8 text)."""
    try:
        return raw.decode("utf-8-sig" if bom else "utf-8")
    except UnicodeDecodeError:
        raise MapImportError(f"{where}: not {what} (not UTF-8 text)") from None


@dataclass
class Imported:
    """A passability grid (row 0 at the top) and what the reader noticed; ``goals``: named
    cells the map itself gives as destinations (IMDF), each a free cell of ``free``."""

    free: BoolArray
    frame: Frame | None = None
    notes: list[str] = field(default_factory=list)
    goals: list[tuple[tuple[int, int], str]] = field(default_factory=list)


def detect(path: Path) -> Format:
    """The format a file's name suggests."""
    suffix = path.suffix.lower()
    if suffix == ".map":
        return "movingai"
    if suffix in (".yaml", ".yml"):
        return "ros"
    if suffix in IMAGE_SUFFIXES:
        return "image"
    raise MapImportError(
        f"{path}: cannot tell the format from the name {path.name!r} "
        "(.map Moving AI, .yaml ROS map_server, .png/.pgm image): give --format"
    )


def read_map(
    path: Path,
    kind: Format = "auto",
    *,
    merge: int = 1,
    threshold: int = 128,
    seal: int = 0,
    budget: MemoryBudget | None = None,
) -> Imported:
    """Read ``path`` in format ``kind``; ``merge``: pixels per cell side (images, ROS maps);
    ``threshold``: the grey level below which a floor-plan pixel is wall; ``seal``: openings of
    the outline up to this many pixels are closed while a floor plan's outside is found;
    ``budget``: the memory the import may take (default :class:`MemoryBudget`'s), checked
    from the file's header before it is decoded."""
    from app.mapio.budget import MemoryBudget

    budget = budget or MemoryBudget()
    if merge < 1:
        raise MapImportError(f"merge must be at least 1 pixel per cell, got {merge}")
    try:
        is_file = path.is_file()
    except (OSError, ValueError):  # a name too long for the system, a NUL in it
        is_file = False
    if not is_file:
        raise MapImportError(f"{path}: no such file")
    fmt = detect(path) if kind == "auto" else kind
    if fmt == "movingai":
        from app.mapio.movingai import read_movingai

        return read_movingai(path, budget)
    if fmt == "ros":
        from app.mapio.ros import read_ros

        return read_ros(path, merge=merge, budget=budget)
    if fmt == "image":
        from app.mapio.image import read_plan

        return read_plan(path, merge=merge, threshold=threshold, seal=seal, budget=budget)
    raise MapImportError(f"unknown format {shorten(kind)}: use one of {', '.join(FORMATS)}")
