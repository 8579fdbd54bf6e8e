"""The Moving AI Lab's grid benchmark maps (movingai.com/benchmarks, format ``type octile``)::

    type octile
    height H
    width W
    map
    <H rows of W characters>

Passable: ``.`` ground, ``G`` ground, ``S`` swamp (terrain, not a start or goal). Not passable:
``@`` and ``O`` out of bounds, ``T`` trees, ``W`` water.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from app.mapio import Imported, MapImportError

PASSABLE = ".GS"
BLOCKED = "@OTW"
_PASSABLE = np.frombuffer(PASSABLE.encode(), dtype=np.uint8)
_BLOCKED = np.frombuffer(BLOCKED.encode(), dtype=np.uint8)


def read_movingai(path: Path) -> Imported:
    try:
        lines = path.read_text(encoding="ascii").splitlines()
    except UnicodeDecodeError:
        raise MapImportError(f"{path}: not a Moving AI map (not ASCII text)") from None
    except OSError as exc:
        raise MapImportError(f"{path}: cannot read: {exc.strerror or exc}") from None
    return parse_movingai(lines, str(path))


def parse_movingai(lines: list[str], where: str = "map") -> Imported:
    """The grid of a Moving AI map's lines."""
    header: dict[str, str] = {}
    i = 0
    while i < len(lines) and lines[i].strip().lower() != "map":
        parts = lines[i].split()
        if len(parts) != 2 or parts[0].lower() not in ("type", "height", "width"):
            raise MapImportError(
                f"{where}: line {i + 1}: expected 'type octile', 'height H', 'width W' "
                f"or 'map' before the rows, got {lines[i][:40]!r}"
            )
        header[parts[0].lower()] = parts[1]
        i += 1
    if i == len(lines):
        raise MapImportError(f"{where}: no 'map' line: not a Moving AI map")
    for key in ("height", "width"):
        if key not in header:
            raise MapImportError(f"{where}: the header has no '{key}' line")
        if not header[key].isdigit() or int(header[key]) < 1:
            raise MapImportError(f"{where}: {key} {header[key]!r} is not a positive whole number")
    if header.get("type", "octile").lower() != "octile":
        raise MapImportError(f"{where}: type {header['type']!r}: only 'type octile' is known")
    height, width = int(header["height"]), int(header["width"])
    rows = [r.rstrip("\r") for r in lines[i + 1 :]]
    while rows and not rows[-1].strip():
        rows.pop()
    if len(rows) != height:
        raise MapImportError(
            f"{where}: the header says height {height}, the map has {len(rows)} rows"
        )
    for r, row in enumerate(rows):
        if len(row) != width:
            raise MapImportError(
                f"{where}: line {i + 2 + r}: {len(row)} characters where the header says "
                f"width {width}"
            )
    grid = np.frombuffer("".join(rows).encode("ascii", "replace"), dtype=np.uint8)
    grid = grid.reshape(height, width)
    free = np.isin(grid, _PASSABLE)
    bad = np.argwhere(~free & ~np.isin(grid, _BLOCKED))
    if len(bad):
        r, c = (int(v) for v in bad[0])
        raise MapImportError(
            f"{where}: line {i + 2 + r}, column {c + 1}: unknown terrain {rows[r][c]!r} "
            "(passable . G S, blocked @ O T W)"
        )
    return Imported(free, None, [f"Moving AI map {height}x{width}"])
