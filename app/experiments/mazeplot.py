"""Drawing a value per free cell over the maze (matplotlib): where explorers end up."""

from __future__ import annotations

import numpy as np
from matplotlib.axes import Axes
from matplotlib.colors import ListedColormap, LogNorm, Normalize, PowerNorm

from app.arrays import BoolArray, FloatArray
from app.domain.grid import GridDomain

#: The heat map's colours: yellow (few visits) to dark red (most).
HEAT_CMAP = "YlOrRd"


def shared_log_norm(values: list[FloatArray], decades: float = 4.0) -> LogNorm:
    """One logarithmic scale for several panels of shares (so one colour bar reads them all):
    up to the largest share of any panel, down to the smallest positive one but at most
    ``decades`` below the top (smaller shares take the palest colour)."""
    positive = np.concatenate([np.ravel(v)[np.ravel(v) > 0] for v in values] + [np.zeros(0)])
    if positive.size == 0:  # nothing to show: any scale will do
        positive = np.ones(1)
    top = float(positive.max())
    return LogNorm(vmin=max(float(positive.min()), top / 10**decades), vmax=top, clip=True)


def draw_cells(
    ax: Axes,
    domain: GridDomain,
    values: FloatArray,
    *,
    without_data: BoolArray | None = None,
    title: str = "",
    norm: Normalize | None = None,
) -> None:
    """Walls black, free cells white (light grey where no expert passed), ``values`` (share of
    visits, drawn where > 0) from yellow (few) to dark red (most); goals numbered in blue,
    the start marked S. ``norm`` maps values to colours (default: a square-root scale up to
    this panel's largest value)."""
    rows, cols = domain.shape
    base = np.where(domain.walls, 0.0, 1.0)
    if without_data is not None:
        r, c = domain.cells[without_data].T
        base[r, c] = 0.5
    ax.imshow(base, cmap=ListedColormap(["black", "0.82", "white"]), vmin=0, vmax=1)
    heat = np.full((rows, cols), np.nan)
    r, c = domain.cells.T
    heat[r, c] = np.where(values > 0, values, np.nan)
    if np.isfinite(heat).any():
        if norm is None:  # square-root scale: a few hot cells must not hide the rest
            norm = PowerNorm(0.5, vmin=0, vmax=float(np.nanmax(heat)))
        ax.imshow(heat, cmap=HEAT_CMAP, norm=norm)
    for gi, g in enumerate(domain.goals):
        gr, gc = domain.cell(g)
        ax.text(gc, gr, str(gi), color="blue", ha="center", va="center", fontsize=7,
                fontweight="bold")  # fmt: skip
    sr, sc = domain.cell(domain.start)
    ax.text(sc, sr, "S", color="blue", ha="center", va="center", fontsize=7)
    ax.set_title(title, fontsize=9)
    ax.set_xticks([])
    ax.set_yticks([])
