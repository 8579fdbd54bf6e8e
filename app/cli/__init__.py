"""The command line, ``python -m app`` (or ``advisor``): the composition root.

Each command wires the parts it needs and nothing else: ``serve`` builds the service (which
learns the default domain's prior from simulated experts on first start) and starts ``viewer``,
the 3D viewer, in a process of its own that reads the service over HTTP; ``simulate`` drives
simulated explorers through a running service as a client, ``experiment`` runs the paper's
experiments in process, ``maze`` and ``train`` work on maps and priors, ``domain put`` sends a
map file to a running service. Heavy imports (the service, numba kernels, matplotlib) wait
until a command runs.
"""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version
from typing import Annotated

import typer

from app.cli import options  # noqa: F401  (how every command shows its options)
from app.cli.domain import domain_cli
from app.cli.experiment import experiment_cli
from app.cli.maze import maze_cli
from app.cli.serve import serve
from app.cli.simulate import simulate
from app.cli.train import train
from app.cli.viewer import viewer

cli = typer.Typer(
    help="An advisor for agents with hidden goals (Rosman & Ramamoorthy, ICRA 2014).",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def package_version() -> str:
    try:
        return version("hidden-goal-advisor")
    except PackageNotFoundError:
        return "0+unknown (not installed)"


def _show_version(value: bool) -> None:
    if value:
        typer.echo(f"advisor {package_version()}")
        raise typer.Exit()


@cli.callback()
def main_options(
    show_version: Annotated[
        bool,
        typer.Option(
            "--version", callback=_show_version, is_eager=True, help="Print the version and exit."
        ),
    ] = False,
) -> None:
    """An advisor for agents with hidden goals (Rosman & Ramamoorthy, ICRA 2014)."""


cli.add_typer(maze_cli, name="maze")
cli.command()(train)
cli.add_typer(experiment_cli, name="experiment")
cli.command()(serve)
cli.command()(simulate)
cli.command()(viewer)
cli.add_typer(domain_cli, name="domain")


def main() -> None:
    cli()
