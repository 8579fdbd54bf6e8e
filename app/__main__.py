"""Command line: ``python -m app --help``."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, cast

import numpy as np
import typer

from app.domain.grid import ACTIONS, GridDomain, MapError
from app.domain.maps import DEFAULT_MAP

cli = typer.Typer(
    help="An advisor for agents with hidden goals (Rosman & Ramamoorthy, ICRA 2014).",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
maze_cli = typer.Typer(help="Show, check and generate ASCII maze maps.", no_args_is_help=True)
cli.add_typer(maze_cli, name="maze")

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


@cli.command()
def train(
    maze: MazeOption = DEFAULT_MAP,
    experts: Annotated[
        str, typer.Option(help="Where experts start: start | anywhere | policy (full policies).")
    ] = "start",
    per_goal: Annotated[int, typer.Option(min=1, help="Expert trajectories per goal.")] = 10,
    alpha0: Annotated[
        float, typer.Option(min=0.0, help="Dirichlet hyperprior alpha0 (> 0).")
    ] = 1.0,
    delta: Annotated[float, typer.Option(min=0.0, max=1.0, help="Policy threshold (eq. 1).")] = 0.0,
    epsilon: Annotated[
        float, typer.Option(min=0.0, max=1.0, help="Experts' chance of a random move per step.")
    ] = 0.0,
    seed: Annotated[int, typer.Option(help="Random seed.")] = 0,
    out: Annotated[Path, typer.Option(help="Where to write the prior (.npz).")] = Path("prior.npz"),
    as_json: Annotated[bool, typer.Option("--json", help="Print the summary as JSON.")] = False,
) -> None:
    """Learn an action prior from simulated optimal experts and write it as .npz."""
    from app.advice.text import direction_map
    from app.agents.experts import EXPERT_SOURCES, ExpertSource, train_prior

    if experts not in EXPERT_SOURCES:
        typer.echo(f"error: --experts must be one of {', '.join(EXPERT_SOURCES)}", err=True)
        raise typer.Exit(code=2)
    domain = load_domain(maze)
    try:
        source = cast(ExpertSource, experts)
        rng = np.random.default_rng(seed)
        prior = train_prior(domain, rng, source, per_goal, alpha0, delta, epsilon)
    except ValueError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(code=2) from None
    prior.save(out)
    summary = prior.summary() | {
        "maze": str(maze),
        "experts": experts,
        "per_goal": per_goal,
        "alpha0": alpha0,
        "delta": delta,
        "epsilon": epsilon,
        "seed": seed,
        "out": str(out),
    }
    if as_json:
        typer.echo(json.dumps(summary, indent=2))
        return
    typer.echo(describe(domain))
    kind = "policies" if experts == "policy" else "trajectories"
    typer.echo(
        f"prior: {summary['trajectories']} expert {kind}"
        f" ({experts}), alpha0={alpha0}, delta={delta}; {summary['states_with_data']}/"
        f"{summary['states']} states have expert data; mean entropy "
        f"{summary['mean_entropy_nats']:.3f} nats (uniform {np.log(len(ACTIONS)):.3f})"
    )
    typer.echo(f"wrote {out}\nmost advised direction (· no data, + tie):")
    typer.echo(direction_map(domain, prior.theta()))


from app.experiments.cli import experiment  # noqa: E402  (its heavy imports are deferred)

cli.command()(experiment)

from app.service.cli import serve  # noqa: E402  (uvicorn and the app are imported on use)
from app.service.simulate import simulate  # noqa: E402

cli.command()(serve)
cli.command()(simulate)


def main() -> None:
    cli()


if __name__ == "__main__":
    main()
