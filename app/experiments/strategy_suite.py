"""The strategies experiment's machinery: its arguments, the configurations (a strategy at a
cost level), the suite of maps, and the runs (:mod:`app.experiments.strategies` runs and
reports them)."""

from __future__ import annotations

import multiprocessing
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass
from typing import Any, Literal

import numpy as np
import numpy.typing as npt
from tqdm import tqdm

from app.advice.models import AdviceTables
from app.agents.experts import train_goal_priors
from app.agents.explorers import FIXED_EXPLORERS
from app.agents.simulate import Simulator
from app.arrays import FloatArray
from app.domain.generate import generate_domain
from app.domain.grid import GridDomain
from app.experiments.common import CommonArgs, rng_for
from app.experiments.curves import Config, SuiteRuns, check_strategies, strategy_args
from app.experiments.curves import configs as curve_configs
from app.experiments.traps import dead_end_masks, other_dead_end_share, trap_goal

#: The strategies compared by default, in the order of tables and plots.
STRATEGIES = ("paper", "goal_aware", "early", "importance", "mistake", "random", "always")
MEASURES = ("success", "steps", "advice", "trapped", "other_dead_end_share", "ruled_out")
StrategyOptions = strategy_args("StrategyOptions", STRATEGIES)


@dataclass
class Args(CommonArgs, StrategyOptions):  # type: ignore[valid-type,misc]
    """Strategies arguments (``--tasks``: tasks per map, explorer and configuration)."""

    tasks: int = 50
    """Random one-shot tasks per map; every strategy and level sees the same tasks."""
    steps: int = 5000
    """Step limit of a one-shot task."""
    maps: int = 10
    """Generated mazes besides ``--maze``: the first half perfect, the rest braided."""
    map_size: int = 29
    """Rows and columns of a generated maze (29: 449-465 free cells, as the shipped 455)."""
    braid: float = 0.2
    """Braid of the braided mazes (the shipped maze was generated with 0.2)."""
    workers: int = 2
    """Processes (1: run in this process; a strategy registered at run time needs it)."""
    last_n: int = 500
    """A failure is 'trapped' if half of its last ``last_n`` steps were in another goal's
    dead end (app/experiments/traps.py)."""
    variants: tuple[str, ...] = ("goal_aware beta=0.1", "goal_aware beta=0.5", "goal_aware beta=1")
    """More curves at the default kappa only: '<strategy> <parameter>=<value>'."""
    candidate: str = "goal_aware"
    """The strategy the targets are about (compared with every other at its default level)."""
    baseline: str = "paper"
    """The strategy the candidate must beat for the random walkers."""

    def check(self) -> None:
        super().check()
        self.check_trajectories("strategies")
        if self.maps < 0 or self.map_size < 5 or self.workers < 1 or self.steps < 1:
            raise ValueError("need maps >= 0, map-size >= 5, workers >= 1 and steps >= 1")
        if not 0.0 <= self.braid <= 1.0:
            raise ValueError("braid must be in [0, 1]")
        check_strategies(self)
        for name in (self.candidate, self.baseline):
            if name not in self.strategies:
                raise ValueError(f"{name} is not among the strategies run")


def configs(args: Args) -> list[Config]:
    """Every configuration run, in report order; each curve's levels ascending."""
    return curve_configs(args, args.variants)


@dataclass(frozen=True)
class MapSpec:
    index: int
    kind: str  # "file" (--maze), "perfect" or "braided"
    seed: int  # the generator's seed (-1 for the file)
    name: str


def map_suite(args: Args) -> list[MapSpec]:
    """The ``--maze`` map, then ``--maps`` generated ones (perfect first, then braided)."""
    out = [MapSpec(0, "file", -1, args.maze.stem)]
    n_perfect = (args.maps + 1) // 2
    for i in range(1, args.maps + 1):
        kind = "perfect" if i <= n_perfect else "braided"
        seed = int(rng_for(args.seed, "strategies-maps", i).integers(2**31))
        out.append(MapSpec(i, kind, seed, f"{kind}-{args.map_size}-s{seed}"))
    return out


def load_map(args: Args, spec: MapSpec) -> GridDomain:
    if spec.kind == "file":
        return GridDomain.from_file(args.maze)
    braid = 0.0 if spec.kind == "perfect" else args.braid
    return generate_domain(args.map_size, args.map_size, spec.seed, braid=braid)


@dataclass
class World:
    """One map of the suite, ready to run: the maze, its priors, the simulator, the tasks."""

    spec: MapSpec
    domain: GridDomain
    sim: Simulator
    goals: list[int]
    masks: npt.NDArray[np.bool_]
    states_with_data: int  # cells some expert passed through (elsewhere theta is uniform)


def prepare_world(args: Args, spec: MapSpec) -> World:
    domain = load_map(args, spec)
    # the --maze map uses Table I's expert stream, so its pooled prior is Table I's
    keys = ("experts",) if spec.kind == "file" else ("experts", spec.index)
    source: Literal["start", "anywhere"] = "anywhere" if args.experts == "anywhere" else "start"
    prior, goal_priors = train_goal_priors(
        domain, rng_for(args.seed, *keys), source, args.per_goal, args.alpha0
    )
    sim = Simulator(domain, AdviceTables.paper(prior.theta()), goal_priors)
    goals = rng_for(args.seed, "strategies-tasks", spec.index).choice(
        np.array(domain.goals, dtype=np.int64), size=args.tasks
    )
    with_data = int((prior.pooled_increments_.sum(axis=1) > 0).sum())
    return World(spec, domain, sim, goals.tolist(), dead_end_masks(domain), with_data)


def map_info(world: World) -> dict[str, Any]:
    """What a map of the suite is like (for the report)."""
    d = world.domain
    degree = d.open_moves.sum(axis=1)
    return {
        **asdict(world.spec),
        "states": d.n_states,
        "dead_ends": int((degree == 1).sum()),
        "junctions": int((degree >= 3).sum()),
        "independent_loops": int(d.open_moves.sum()) // 2 - d.n_states + 1,
        "mean_goal_distance": float(d.goal_distances[:, d.start].mean()),
        "states_with_expert_data": world.states_with_data,
    }


_WORLDS: dict[tuple[Any, ...], World] = {}  # per process: a map's jobs come one after another


def cached_world(args: Args, spec: MapSpec) -> World:
    """:func:`prepare_world`, kept for the next job on the same map (expert data takes a BFS
    per trajectory, more than a job's short tasks)."""
    key = (str(args.maze), args.seed, args.experts, args.per_goal, args.alpha0, args.tasks,
           args.map_size, args.braid, spec)  # fmt: skip
    if key not in _WORLDS:
        _WORLDS.clear()
        _WORLDS[key] = prepare_world(args, spec)
    return _WORLDS[key]


def run_job(
    args: Args, spec: MapSpec, explorer: str, todo: list[Config]
) -> dict[str, dict[str, FloatArray]]:
    """Every task of one map for one explorer under every configuration: config key ->
    measure -> one value per task."""
    world = cached_world(args, spec)
    out: dict[str, dict[str, FloatArray]] = {}
    for c in todo:
        m = {name: np.zeros(args.tasks) for name in MEASURES}
        for i, goal in enumerate(world.goals):
            run = world.sim.fixed(
                explorer,
                goal,
                rng_for(args.seed, "strategies", spec.index, explorer, i),
                advised=c.advised,
                strategy=c.strategy,
                kappa=c.kappa,
                window=args.window,
                params=c.params,
                rule_rng=rng_for(args.seed, "strategies-rule", spec.index, explorer, c.key, i),
                max_steps=args.steps,
                record_p=False,
            )
            gi = world.domain.goals.index(goal)
            m["success"][i] = run.success
            m["steps"][i] = run.steps
            m["advice"][i] = run.advice_count if c.advised else 0
            m["trapped"][i] = trap_goal(run.states, run.success, gi, world.masks, args.last_n) >= 0
            m["other_dead_end_share"][i] = other_dead_end_share(run.states, gi, world.masks)
            m["ruled_out"][i] = run.goals_ruled_out
        out[c.key] = m
    return out


@dataclass
class Results(SuiteRuns[MapSpec]):
    """Per-task measures: ``data[explorer][config key][measure]`` has shape (maps, tasks)."""

    data: dict[str, dict[str, dict[str, FloatArray]]]


def run_all(args: Args) -> Results:
    """Every (map, explorer) job, in this process or in ``--workers`` processes."""
    suite, todo = map_suite(args), configs(args)
    jobs = [(spec, name) for spec in suite for name in FIXED_EXPLORERS]
    data = {
        name: {c.key: {m: np.zeros((len(suite), args.tasks)) for m in MEASURES} for c in todo}
        for name in FIXED_EXPLORERS
    }

    def store(spec: MapSpec, name: str, got: dict[str, dict[str, FloatArray]]) -> None:
        for key, measures in got.items():
            for m, values in measures.items():
                data[name][key][m][spec.index] = values

    per_job = args.tasks * len(todo)
    with tqdm(
        total=per_job * len(jobs), desc="strategies", unit="task", disable=not args.progress
    ) as bar:
        if args.workers == 1:
            for spec, name in jobs:
                store(spec, name, run_job(args, spec, name, todo))
                bar.update(per_job)
        else:
            ctx = multiprocessing.get_context("spawn")  # no fork of a process with threads
            with ProcessPoolExecutor(args.workers, mp_context=ctx) as pool:
                futures = {pool.submit(run_job, args, s, n, todo): (s, n) for s, n in jobs}
                for fut in as_completed(futures):
                    store(*futures[fut], fut.result())
                    bar.update(per_job)
    return Results(suite, todo, data)
