"""Drawing a value per free cell over the maze (matplotlib): where explorers end up."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from matplotlib.axes import Axes
from matplotlib.colors import ListedColormap, PowerNorm

from app.domain.grid import GridDomain

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]


def draw_cells(
    ax: Axes,
    domain: GridDomain,
    values: FloatArray,
    *,
    without_data: BoolArray | None = None,
    title: str = "",
) -> None:
    """Walls black, free cells white (light grey where no expert passed), ``values`` (share of
    visits, drawn where > 0) from yellow (few) to dark red (most); goals numbered in blue,
    the start marked S."""
    rows, cols = domain.shape
    base = np.where(domain.walls, 0.0, 1.0)
    if without_data is not None:
        r, c = domain.cells[without_data].T
        base[r, c] = 0.5
    ax.imshow(base, cmap=ListedColormap(["black", "0.82", "white"]), vmin=0, vmax=1)
    heat = np.full((rows, cols), np.nan)
    r, c = domain.cells.T
    heat[r, c] = np.where(values > 0, values, np.nan)
    if np.isfinite(heat).any():  # square-root scale: a few hot cells must not hide the rest
        ax.imshow(heat, cmap="YlOrRd", norm=PowerNorm(0.5, vmin=0, vmax=float(np.nanmax(heat))))
    for gi, g in enumerate(domain.goals):
        gr, gc = domain.cell(g)
        ax.text(gc, gr, str(gi), color="blue", ha="center", va="center", fontsize=7,
                fontweight="bold")  # fmt: skip
    sr, sc = domain.cell(domain.start)
    ax.text(sc, sr, "S", color="blue", ha="center", va="center", fontsize=7)
    ax.set_title(title, fontsize=9)
    ax.set_xticks([])
    ax.set_yticks([])
