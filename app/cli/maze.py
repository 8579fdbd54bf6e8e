"""``python -m app maze``: show, check and generate ASCII maze maps."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from app.domain.grid import GridDomain, MapError
from app.domain.maps import DEFAULT_MAP

maze_cli = typer.Typer(help="Show, check and generate ASCII maze maps.", no_args_is_help=True)

MazeOption = Annotated[
    Path, typer.Option("--maze", "-m", help="ASCII map file ('#' wall, '.' free, 'S', 'G').")
]


def load_domain(path: Path) -> GridDomain:
    """Load a map or exit with the loader's message (which names line and column)."""
    try:
        return GridDomain.from_file(path)
    except MapError as exc:
        typer.echo(f"error: {path}: {exc}", err=True)
        raise typer.Exit(code=2) from None


def describe(domain: GridDomain) -> str:
    rows, cols = domain.shape
    dist = domain.goal_distances[:, domain.start]
    goals = ", ".join(
        f"G{i}{list(domain.cell(g))} at {int(d)}"
        for i, (g, d) in enumerate(zip(domain.goals, dist, strict=True))
    )
    return (
        f"{domain.name}: {rows}x{cols}, {domain.n_states} free cells, "
        f"{len(domain.dead_ends)} dead ends, start {list(domain.cell(domain.start))}\n"
        f"goals (shortest distance from start): {goals}"
    )


@maze_cli.command("show")
def maze_show(
    maze: Annotated[
        Path, typer.Argument(help="Map file (default: the shipped maze).")
    ] = DEFAULT_MAP,
) -> None:
    """Print a map and what it contains."""
    domain = load_domain(maze)
    typer.echo(str(domain))
    typer.echo(describe(domain))


@maze_cli.command("check")
def maze_check(maze: Annotated[Path, typer.Argument(help="Map file to validate.")]) -> None:
    """Validate a map file: exit 0 if it is a valid domain, 2 with the problem otherwise."""
    domain = load_domain(maze)
    typer.echo(f"ok: {describe(domain)}")


@maze_cli.command("generate")
def maze_generate(
    out: Annotated[Path | None, typer.Option(help="Write here (default: print).")] = None,
    rows: Annotated[int, typer.Option(min=3, help="Rows, including walls.")] = 30,
    cols: Annotated[int, typer.Option(min=3, help="Columns, including walls.")] = 30,
    seed: Annotated[int, typer.Option(help="Random seed.")] = 0,
    braid: Annotated[
        float, typer.Option(min=0.0, max=1.0, help="0 perfect maze; >0 opens dead ends (loops).")
    ] = 0.0,
    goals: Annotated[int, typer.Option(min=1, help="Number of goals.")] = 8,
) -> None:
    """Generate a maze (start lower-left, goals at corners and corridor ends)."""
    from app.domain.generate import generate_maze

    try:
        text = generate_maze(rows, cols, np.random.default_rng(seed), braid=braid, n_goals=goals)
    except ValueError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(code=2) from None
    body = "\n".join(text) + "\n"
    if out is None:
        typer.echo(body, nl=False)
    else:
        out.write_text(body, encoding="utf-8")
        typer.echo(f"wrote {out}: {describe(GridDomain.from_strings(text, name=out.stem))}")
