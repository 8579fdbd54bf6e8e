"""``python -m app train``: learn an action prior from simulated experts and show it.

A served domain learns the same prior from the same experts with ``PUT /domains/{name}`` and
``experts`` (source, per_goal, seed), which stores their trajectories with their goals, as the
store keeps every prior (counts are a recount of trajectories)."""

from __future__ import annotations

import json
from typing import Annotated, cast

import numpy as np
import typer

from app.cli.building import describe_building
from app.cli.maze import MazeOption, describe, load_any
from app.cli.options import choice
from app.domain.building import Building
from app.domain.maps import DEFAULT_MAP

SOURCES = ("start", "anywhere", "policy")  # app.agents.experts.EXPERT_SOURCES (checked below)


def _positive(value: float) -> float:
    if not value > 0:
        raise typer.BadParameter(f"{value} is not > 0 (alpha0 keeps every probability positive)")
    return value


def train(
    maze: MazeOption = DEFAULT_MAP,
    experts: Annotated[
        str, choice(SOURCES, "Where experts start (policy: full optimal policies).")
    ] = "start",
    per_goal: Annotated[int, typer.Option(min=1, help="Expert trajectories per goal.")] = 10,
    alpha0: Annotated[
        float,
        typer.Option(callback=_positive, help="Dirichlet hyperprior alpha0, > 0 (every count)."),
    ] = 1.0,
    delta: Annotated[
        float, typer.Option(min=0.0, max=1.0, help="Policy threshold (eq. (1)).")
    ] = 0.0,
    epsilon: Annotated[
        float, typer.Option(min=0.0, max=1.0, help="Experts' chance of a random move per step.")
    ] = 0.0,
    seed: Annotated[int, typer.Option(help="Random seed.")] = 0,
    as_json: Annotated[bool, typer.Option("--json", help="Print the summary as JSON.")] = False,
) -> None:
    """Learn an action prior from simulated optimal experts; print what it holds and each
    cell's most advised direction (a map of several floors: floor by floor, U and D where
    experts ride up or down). (A service domain learns it with PUT /domains/{name} and
    "experts": {"source", "per_goal", "seed"}.)"""
    from app.advice.text import direction_map
    from app.agents.experts import EXPERT_SOURCES, ExpertSource, train_prior

    if experts not in EXPERT_SOURCES:
        typer.echo(f"error: --experts must be one of {', '.join(EXPERT_SOURCES)}", err=True)
        raise typer.Exit(code=2)
    domain = load_any(maze)
    try:
        source = cast(ExpertSource, experts)
        rng = np.random.default_rng(seed)
        prior = train_prior(domain, rng, source, per_goal, alpha0, delta, epsilon)
    except ValueError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(code=2) from None
    summary = prior.summary() | {
        "maze": str(maze),
        "experts": experts,
        "per_goal": per_goal,
        "alpha0": alpha0,
        "delta": delta,
        "epsilon": epsilon,
        "seed": seed,
    }
    if as_json:
        typer.echo(json.dumps(summary, indent=2))
        return
    typer.echo(describe_building(domain) if isinstance(domain, Building) else describe(domain))
    kind = "policies" if experts == "policy" else "trajectories"
    typer.echo(
        f"prior: {summary['trajectories']} expert {kind}"
        f" ({experts}), alpha0={alpha0}, delta={delta}; {summary['states_with_data']}/"
        f"{summary['states']} states have expert data; mean entropy "
        f"{summary['mean_entropy_nats']:.3f} nats (uniform over {domain.n_actions} actions "
        f"{np.log(domain.n_actions):.3f})"
    )
    typer.echo("most advised direction (· no data, + tie):")
    typer.echo(direction_map(domain, prior.theta()))
