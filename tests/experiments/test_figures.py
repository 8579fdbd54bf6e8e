"""The figures read on their own: the failures heat map has a labelled colour bar on one scale
for all panels, Figure 6's legends cover no curve."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from matplotlib.colors import LogNorm
from matplotlib.figure import Figure

from app.experiments import figure6, table1
from app.experiments.mazeplot import shared_log_norm
from app.experiments.output import RunDir

TINY = {"tasks": 3, "steps": 300, "episodes": 6, "episode_steps": 40, "progress": False}


class KeptFigures(RunDir):
    """A run directory that also keeps each figure it writes, to look inside."""

    def __init__(self, path: Path):
        super().__init__(path)
        self.figures: dict[str, Figure] = {}

    def figure(self, name: str, fig: Figure) -> Path:
        self.figures[name] = fig
        return super().figure(name, fig)


def test_failures_heat_map_has_one_labelled_colour_bar(small_maze: Path, tmp_path: Path) -> None:
    out = KeptFigures(tmp_path)
    table1.run(table1.Args(maze=small_maze, **TINY), out)  # type: ignore[arg-type]
    fig = out.figures["table1_failures"]
    bars = [ax for ax in fig.axes if ax.get_label() == "<colorbar>"]
    assert len(bars) == 1
    assert "share of the failed explorers' last 500 steps" in bars[0].get_ylabel()
    # every panel's heat map is on the colour bar's scale
    heat = [im for ax in fig.axes for im in ax.get_images() if isinstance(im.norm, LogNorm)]
    assert heat and all(im.norm is heat[0].norm for im in heat)


def test_shared_log_norm_spans_every_panel_within_its_decades() -> None:
    rng = np.random.default_rng(0)
    panels = [rng.random(50) ** 6 * (rng.random(50) > 0.3) for _ in range(5)]
    norm = shared_log_norm(panels, decades=3.0)
    top = max(float(p.max()) for p in panels)
    smallest = min(float(p[p > 0].min()) for p in panels)
    assert norm.vmax == top
    assert norm.vmin == pytest.approx(max(smallest, top / 1e3))
    empty = shared_log_norm([np.zeros(4)])  # nothing positive: still a valid scale
    assert empty.vmin is not None and empty.vmax is not None and 0 < empty.vmin <= empty.vmax


def test_figure6_legends_sit_below_their_axes(small_maze: Path, tmp_path: Path) -> None:
    out = KeptFigures(tmp_path)
    args = figure6.Args(maze=small_maze, **{k: v for k, v in TINY.items() if k != "steps"})  # type: ignore[arg-type]
    figure6.run(args, out)
    fig = out.figures["figure6"]
    fig.draw_without_rendering()  # lays the figure out as savefig does
    axes = [ax for ax in fig.axes if ax.get_legend() is not None]
    assert len(axes) == 2
    for ax in axes:
        legend = ax.get_legend()
        assert legend is not None
        box, area = legend.get_window_extent(), ax.get_window_extent()
        assert box.y1 <= area.y0  # wholly under the plotting area: it covers no curve
        labels = [t.get_text() for t in legend.get_texts()]
        assert any("advised" in label for label in labels)
        assert any("no advice" in label for label in labels)
