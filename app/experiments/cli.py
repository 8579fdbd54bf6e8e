"""``python -m app experiment NAME``: run one experiment (or all) and write ``results/<run>/``.

The experiment modules (numba, matplotlib) are imported when a command runs, so registering
this command costs the rest of the command line nothing.
"""

from __future__ import annotations

import time
from dataclasses import fields
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, TypeVar

import typer

from app.domain.grid import MapError
from app.domain.maps import DEFAULT_MAP

if TYPE_CHECKING:
    from app.experiments.output import RunDir

T = TypeVar("T")


class Name(StrEnum):
    table1 = "table1"
    figure5 = "figure5"
    figure6 = "figure6"
    figure7 = "figure7"
    difficulty = "difficulty"
    ablations = "ablations"
    strategies = "strategies"
    all = "all"


def build(cls: type[T], options: dict[str, Any]) -> T:
    """The experiment's argument dataclass from the options it has (unset ones: defaults)."""
    from app.experiments.common import CommonArgs, LearningArgs

    names = {f.name for f in fields(cls)}  # type: ignore[arg-type]
    args = cls(**{k: v for k, v in options.items() if k in names and v is not None})
    if isinstance(args, CommonArgs):
        args.check()
    if isinstance(args, LearningArgs):
        args.q_params()  # validates the Q-learner's settings
    return args


def run_all(options: dict[str, Any], out: RunDir) -> dict[str, float]:
    """The paper's protocol end to end; Table I reuses Figure 6's Q-learning runs."""
    from app.experiments import difficulty, figure5, figure6, figure7, table1

    seconds: dict[str, float] = {}
    t = time.perf_counter()
    difficulty.run(build(difficulty.Args, options), out)
    seconds["difficulty"] = time.perf_counter() - t
    t = time.perf_counter()
    _, learning = figure6.run(build(figure6.Args, options), out)
    seconds["figure6"] = time.perf_counter() - t
    t = time.perf_counter()
    table1.run(build(table1.Args, options), out, learning=learning)
    seconds["table1"] = time.perf_counter() - t
    t = time.perf_counter()
    figure5.run(build(figure5.Args, options), out)
    seconds["figure5"] = time.perf_counter() - t
    t = time.perf_counter()
    figure7.run(build(figure7.Args, options), out)
    seconds["figure7"] = time.perf_counter() - t
    return seconds


def experiment(
    name: Annotated[Name, typer.Argument(help="Which table or figure (all: every one).")],
    maze: Annotated[Path, typer.Option(help="ASCII map file.")] = DEFAULT_MAP,
    seed: Annotated[int, typer.Option(help="Seeds every random choice.")] = 0,
    tasks: Annotated[
        int | None,
        typer.Option(
            min=1,
            help="Random one-shot tasks per explorer [20; ablations 200; strategies 50 per map].",
        ),
    ] = None,
    kappa: Annotated[float, typer.Option(min=0.0, help="Cost of one piece of advice.")] = 0.5,
    alpha0: Annotated[float, typer.Option(help="Dirichlet hyperprior alpha0 (> 0).")] = 1.0,
    window: Annotated[int, typer.Option(min=1, help="History window W.")] = 300,
    experts: Annotated[str, typer.Option(help="start | anywhere | policy.")] = "start",
    per_goal: Annotated[int, typer.Option(min=1, help="Expert trajectories per goal.")] = 10,
    steps: Annotated[
        int | None,
        typer.Option(min=1, help="Step limit of a one-shot task [5000; Figure 7: 1000]."),
    ] = None,
    episodes: Annotated[int, typer.Option(min=1, help="Q-learning episodes per task.")] = 5000,
    episode_steps: Annotated[
        int, typer.Option(min=1, help="Step limit of a Q-learning episode.")
    ] = 200,
    q_alpha: Annotated[float, typer.Option(help="Q-learning step size.")] = 0.1,
    q_gamma: Annotated[float, typer.Option(help="Q-learning discount.")] = 0.95,
    q_epsilon: Annotated[float, typer.Option(help="Q-learning exploration rate.")] = 0.1,
    q_ties: Annotated[str, typer.Option(help="Equal Q-values: advice | uniform.")] = "advice",
    q_keep_history: Annotated[
        bool, typer.Option(help="Advisor window carries over between Q-learning episodes.")
    ] = True,
    trajectories: Annotated[
        int, typer.Option(min=1, help="Figure 7: trajectories per explorer and kappa.")
    ] = 10,
    maps: Annotated[
        int | None, typer.Option(min=0, help="Strategies: generated mazes besides --maze [10].")
    ] = None,
    map_size: Annotated[
        int | None, typer.Option(min=5, help="Strategies: rows = columns of a generated maze [29].")
    ] = None,
    braid: Annotated[
        float | None, typer.Option(help="Strategies: braid of the braided mazes [0.2].")
    ] = None,
    beta: Annotated[
        float | None,
        typer.Option(help="Strategies: goal-aware weight of per-goal likelihoods, 0..1 [0]."),
    ] = None,
    workers: Annotated[
        int | None, typer.Option(min=1, help="Strategies: worker processes [2].")
    ] = None,
    out: Annotated[
        Path | None, typer.Option(help="Results directory [results/<name>-<time>].")
    ] = None,
    progress: Annotated[bool, typer.Option(help="Progress bars.")] = True,
) -> None:
    """Reproduce the paper's Table I and Figures 5-7 (or the ablations, or compare the
    advising strategies) on a maze."""
    options = {k: v for k, v in locals().items() if k not in ("name", "out")}
    from app.experiments import (
        ablations,
        difficulty,
        figure5,
        figure6,
        figure7,
        strategies,
        table1,
    )
    from app.experiments.output import RunDir, default_run_dir

    run_dir = RunDir(out or default_run_dir(name.value))
    started = time.perf_counter()
    try:
        if name is Name.all:
            seconds = run_all(options, run_dir)
            typer.echo(" ".join(f"{k} {v:.1f}s" for k, v in seconds.items()))
        else:
            module = {
                Name.table1: table1,
                Name.figure5: figure5,
                Name.figure6: figure6,
                Name.figure7: figure7,
                Name.difficulty: difficulty,
                Name.ablations: ablations,
                Name.strategies: strategies,
            }[name]
            module.run(build(module.Args, options), run_dir)
    except (ValueError, MapError) as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(code=2) from None
    typer.echo(f"{name.value}: {time.perf_counter() - started:.1f}s, wrote {run_dir.path}/")
    for p in run_dir.written:
        if p.suffix == ".md":
            typer.echo(p.read_text(encoding="utf-8"))
