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

import os
from pathlib import Path

import numpy as np

from app.mapio import Imported, MapImportError, brief, shorten
from app.mapio.budget import MemoryBudget

PASSABLE = ".GS"
BLOCKED = "@OTW"
_PASSABLE = np.frombuffer(PASSABLE.encode(), dtype=np.uint8)
_BLOCKED = np.frombuffer(BLOCKED.encode(), dtype=np.uint8)
#: the header (type, height, width, map) is looked for in the file's first bytes
HEAD_BYTES = 4096
#: bytes a file may have beyond its header's rows (each ended by CR LF): trailing blank lines
SLACK_BYTES = 4096


def read_movingai(path: Path, budget: MemoryBudget | None = None) -> Imported:
    """Read a Moving AI map, refused from its header (before the rows are read) if importing
    it would take more than ``budget``, or if the file is longer than its rows can be."""
    budget = budget or MemoryBudget()
    where = str(path)
    try:
        with path.open("rb") as f:
            size = os.fstat(f.fileno()).st_size
            head = f.read(HEAD_BYTES)
            lines = _ascii(head, where).splitlines()
            if len(head) == HEAD_BYTES and not head.endswith(b"\n"):
                lines = lines[:-1]  # the last line may be cut: the header is before it
            height, width, first = header(lines, where, complete=len(head) < HEAD_BYTES)
            budget.check_text(where, width, height)
            header_bytes = sum(len(line) + 2 for line in lines[: first + 1])
            most = header_bytes + height * (width + 2) + SLACK_BYTES
            if size > most:
                raise MapImportError(
                    f"{where}: {size:,} bytes, more than its header's {height} rows of {width} "
                    f"characters can take ({most:,} at most): not a Moving AI map"
                )
            f.seek(0)
            text = _ascii(f.read(most + 1), where)
    except OSError as exc:
        raise MapImportError(f"{where}: cannot read: {brief(exc.strerror or exc)}") from None
    return parse_movingai(text.splitlines(), where)


def _ascii(data: bytes, where: str) -> str:
    try:
        return data.decode("ascii")
    except UnicodeDecodeError:
        raise MapImportError(f"{where}: not a Moving AI map (not ASCII text)") from None


def header(lines: list[str], where: str = "map", complete: bool = True) -> tuple[int, int, int]:
    """The height and width a Moving AI map's header gives, and the index of its ``map`` line
    (``complete``: ``lines`` is the whole file, not its first lines)."""
    fields: dict[str, str] = {}
    i = 0
    while i < len(lines) and lines[i].strip().lower() != "map":
        parts = lines[i].split()
        if len(parts) != 2 or parts[0].lower() not in ("type", "height", "width"):
            raise MapImportError(
                f"{where}: line {i + 1}: expected 'type octile', 'height H', 'width W' "
                f"or 'map' before the rows, got {shorten(lines[i], 40)}"
            )
        fields[parts[0].lower()] = parts[1]
        i += 1
    if i == len(lines):
        more = "" if complete else f" in its first {HEAD_BYTES} bytes"
        raise MapImportError(f"{where}: no 'map' line{more}: not a Moving AI map")
    for key in ("height", "width"):
        if key not in fields:
            raise MapImportError(f"{where}: the header has no '{key}' line")
        value = fields[key]
        if not (value.isascii() and value.isdigit() and len(value) <= 9 and int(value) >= 1):
            raise MapImportError(
                f"{where}: {key} {shorten(value)} is not a positive whole number (at most 9 digits)"
            )
    if fields.get("type", "octile").lower() != "octile":
        raise MapImportError(
            f"{where}: type {shorten(fields['type'])}: only 'type octile' is known"
        )
    return int(fields["height"]), int(fields["width"]), i


def parse_movingai(lines: list[str], where: str = "map") -> Imported:
    """The grid of a Moving AI map's lines."""
    height, width, i = header(lines, where)
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
