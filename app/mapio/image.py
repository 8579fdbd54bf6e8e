"""A floor plan drawn as an image: dark pixels are walls, light ones floor.

The free space around the drawing (connected to the image's border) is outside the building and
is dropped, as are transparent pixels. An entrance drawn as a gap in the outline joins the
outside to the inside: ``seal`` closes openings up to about ``2 * seal`` cells wide while the
outside is found (the openings themselves stay open).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from app.arrays import BoolArray
from app.domain.place import components
from app.mapio import Imported, MapImportError
from app.mapio.budget import MemoryBudget
from app.mapio.raster import merge_cells, read_image


def outside(free: BoolArray, seal: int = 0) -> BoolArray:
    """Free cells reachable from the grid's border, through openings wider than ``2 * seal``."""
    rows, cols = free.shape
    passable = free.copy()
    if seal > 0:  # only cells at least ``seal`` cells from every wall carry the flood
        wall = np.pad(~free, seal, constant_values=False)
        near = np.zeros_like(free)
        for dr in range(-seal, seal + 1):
            for dc in range(-seal, seal + 1):
                near |= wall[seal + dr : seal + dr + rows, seal + dc : seal + dc + cols]
        passable &= ~near
    border = np.zeros_like(free)
    border[0, :] = border[-1, :] = border[:, 0] = border[:, -1] = True
    label = components(passable)
    touching = np.unique(label[border & passable])
    out: BoolArray = np.isin(label, touching) & passable
    for _ in range(seal):  # grow back over the margin kept off the walls, within free space
        grown = out.copy()
        grown[1:, :] |= out[:-1, :]
        grown[:-1, :] |= out[1:, :]
        grown[:, 1:] |= out[:, :-1]
        grown[:, :-1] |= out[:, 1:]
        out = grown & free
    return out


def read_plan(
    path: Path,
    *,
    merge: int = 1,
    threshold: int = 128,
    seal: int = 0,
    budget: MemoryBudget | None = None,
) -> Imported:
    if not 1 <= threshold <= 255:
        raise MapImportError(f"threshold must be a grey level from 1 to 255, got {threshold}")
    if seal < 0:
        raise MapImportError(f"seal must be 0 or more cells, got {seal}")
    grey, opaque = read_image(path, budget or MemoryBudget(), merge)
    height, width = grey.shape
    wall = grey < threshold
    if opaque is not None:
        wall &= opaque
    light = ~wall
    del grey  # the pixels' masks are all that is kept
    if opaque is not None:
        light &= opaque
    n_dark = int(wall.sum())
    n_transparent = 0 if opaque is None else int(opaque.size - opaque.sum())
    del opaque
    cells = merge_cells(light, wall, merge)
    del light, wall
    out = outside(cells, seal)
    inside = cells & ~out
    notes = [f"floor plan {width}x{height} pixels ({n_dark} dark, {n_transparent} transparent)"]
    if merge > 1:
        notes.append(
            f"merged {merge}x{merge} pixels per cell: {cells.shape[1]}x{cells.shape[0]} cells"
        )
    notes.append(f"outside the plan: {int(out.sum())} free cells connected to the image's border")
    if not inside.any():
        hint = " (does the outline have a gap? try --seal 1 or more)" if cells.any() else ""
        raise MapImportError(f"{path}: no floor inside the plan{hint}")
    return Imported(inside, None, notes)
