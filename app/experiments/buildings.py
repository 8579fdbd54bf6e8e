"""Advice in buildings: does a lost visitor who follows the advice arrive, and at what cost?

Beyond the paper. A suite of building-like maps (:mod:`app.experiments.suite`): generated
rooms-and-corridors floors (``--buildings``: sizes, each with its own seed; ``--buildings 0``:
none), generated hospitals of several floors (``--hospitals FxS``: F floors of S x S cells,
lifts and stairs, ``--hospital-goals`` named destinations a floor, each with its own seed),
the project's IMDF venue (``--imdf``: app/mapio/imdf/sample.py's three-level hospital,
imported whole as ``maze import`` imports it) and any map files of one floor or several
(``--mazes``, the project's text format, e.g. written by ``maze import`` from a public
benchmark map; ``--maze`` too when it is not the shipped maze). On each map, experts walk from
the start to every destination (``--per-goal``, ``--experts``), as the service's PUT
``experts`` does, so most cells of a big map have no expert data.

On a map of several floors the actions are six (``U`` and ``D`` the rides), distances and
steps count actions (a ride is one), and the KL the paper's rule and goal_aware compare with
kappa is in four actions' units (``AdviceTables.kl_scale``: log 4 / log 6), so their kappa
levels mean the same on one floor and on several; the report says so and names each map's
floors and free cells.

For every fixed-policy explorer, ``--tasks`` one-shot tasks per map (the goal drawn uniformly
from the map's destinations, start at 'S', at most ``--steps`` moves), without advice and
advised by ``paper``, ``goal_aware`` and ``guide``, each at several kappas (the curve of
success against advice per 100 steps as the cost of advice varies). Every configuration sees
the same tasks with the same explorer streams, so every change is paired task by task.

Q-learning: per map ``--q-tasks`` learners, each ``--episodes`` episodes of at most
``q_steps`` = ``--q-reach`` x the farthest destination's BFS distance from the start (long
enough to reach it, stated in the report), advised or not by ``paper`` and ``guide`` at the
default kappa; measured by the share of episodes that reach the goal.

Targets (``--candidate``, ``guide``, at its defaults, what a session with only
``{"strategy": "guide"}`` gets: kappa 0.5, window 300, and guide's own parameters;
``--p-lost``, ``--slack`` and ``--spread`` change them for every guide run here):
random and random-avoid >= 90 % success, bug >= 80 %, each at <= 25 advice per 100 steps,
on every map; left, optimal and Q-learning never significantly worse than without advice
(the paired 95 % interval of the change includes 0 or lies above it); for random and
random-avoid, guide's curve above paper's and goal_aware's over the advice rates both reach.

    python -m app experiment buildings --mazes den312d.txt --mazes den308d.txt
    python -m app experiment buildings --buildings 0 --hospitals 3x64 --hospitals 5x128 --imdf
"""

from __future__ import annotations

import itertools
import math
from dataclasses import asdict, dataclass, field
from functools import partial
from typing import Any, Literal

import numpy as np
from matplotlib.figure import Figure

from app import strategies
from app.advice.advisor import DEFAULT_STRATEGY
from app.advice.models import AdviceTables
from app.agents.experts import train_goal_priors
from app.agents.explorers import FIXED_EXPLORERS
from app.agents.simulate import Simulator
from app.arrays import FloatArray
from app.domain.building import Domain
from app.experiments.common import (
    CommonArgs,
    LearningArgs,
    fill,
    rng_for,
    run_jobs,
    timed,
    wilson,
)
from app.experiments.curves import (
    Z95,
    Config,
    SuiteRuns,
    base_params,
    check_strategies,
    paired,
    strategy_args,
)
from app.experiments.curves import configs as curve_configs
from app.experiments.output import RunDir, header, markdown_table
from app.experiments.suite import (
    MapSpec,
    SuiteArgs,
    compass_detours,
    goal_moves,
    load_map,
    map_suite,
    plan_of,
)

#: the strategies compared by default, and their kappa levels here (guide's are its entry's)
STRATEGIES = ("paper", "goal_aware", "guide")
LEVELS = {"paper": (0.25, 0.5, 1.0, 2.0), "goal_aware": (0.25, 0.5, 1.0, 2.0)}
#: the curves' colours, in the order of the strategies compared
PALETTE = ("tab:blue", "tab:red", "tab:green", "tab:purple", "tab:brown", "tab:grey", "black")
StrategyOptions = strategy_args("BuildingsStrategies", STRATEGIES, LEVELS)
#: the target explorers and their success targets
TARGETS = {"random": 0.9, "random-avoid": 0.9, "bug": 0.8}
MAX_ADVICE_PER_100 = 25.0
#: explorers that advice must not make significantly worse
UNHARMED = ("left", "optimal")


@dataclass
class Args(CommonArgs, LearningArgs, StrategyOptions, SuiteArgs):  # type: ignore[valid-type,misc]
    """Buildings arguments (``--tasks``: tasks per map, explorer and configuration)."""

    tasks: int = 100
    """One-shot tasks per map and explorer; every configuration sees the same tasks."""
    steps: int = 5000
    """Step limit of a one-shot task (actions: a ride is one)."""
    candidate: str = "guide"
    """The strategy the targets are about (its curve against the others', its defaults)."""
    q_tasks: int = 20
    """Q-learning tasks per map (0: none), at the default kappa."""
    episodes: int = 100
    """Q-learning episodes per task."""
    episode_steps: int = 0
    """Step limit of one Q-learning episode (0: --q-reach x the farthest destination's BFS
    distance from the start, so that every destination can be reached)."""
    q_reach: float = 3.0
    """With --episode-steps 0: episodes this many times the farthest destination's distance."""
    workers: int = 2
    """Processes (1: run in this process)."""

    def check(self) -> None:
        super().check()
        self.check_trajectories("buildings")
        if self.steps < 1 or self.workers < 1 or self.q_tasks < 0 or self.episodes < 1:
            raise ValueError("need steps >= 1, workers >= 1, q-tasks >= 0 and episodes >= 1")
        if self.episode_steps < 0:
            raise ValueError("episode-steps must be >= 0 (0: from --q-reach)")
        if not (math.isfinite(self.q_reach) and self.q_reach >= 1.0):
            raise ValueError("q-reach must be at least 1")
        self.check_suite()
        check_strategies(self)
        if self.candidate not in self.strategies:
            raise ValueError(f"{self.candidate} is not among the strategies run")

    def learners(self) -> tuple[str, ...]:
        """The strategies compared whose compiled form also advises a Q-learner."""
        return tuple(n for n in self.strategies if strategies.get(n).learns)


def configs(args: Args) -> list[Config]:
    return curve_configs(args)


@dataclass
class World:
    spec: MapSpec
    domain: Domain
    sim: Simulator
    goals: list[int]
    states_with_data: int
    q_steps: int


def prepare_world(args: Args, spec: MapSpec) -> World:
    domain = load_map(spec)
    source: Literal["start", "anywhere"] = "anywhere" if args.experts == "anywhere" else "start"
    prior, goal_priors = train_goal_priors(
        domain, rng_for(args.seed, "buildings-experts", spec.index), source, args.per_goal,
        args.alpha0,
    )  # fmt: skip
    sim = Simulator(domain, AdviceTables.paper(prior.theta()), goal_priors)
    goals = rng_for(args.seed, "buildings-tasks", spec.index).choice(
        np.array(domain.goals, dtype=np.int64), size=args.tasks
    )
    with_data = int((prior.pooled_increments_.sum(axis=1) > 0).sum())
    far = int(goal_moves(domain)[:, domain.start].max())
    q_steps = args.episode_steps or math.ceil(args.q_reach * far)
    return World(spec, domain, sim, goals.tolist(), with_data, q_steps)


_WORLDS: dict[tuple[Any, ...], World] = {}


def cached_world(args: Args, spec: MapSpec) -> World:
    key = (args.seed, args.experts, args.per_goal, args.alpha0, args.tasks, args.q_reach,
           args.episode_steps, spec)  # fmt: skip
    if key not in _WORLDS:
        _WORLDS.clear()
        _WORLDS[key] = prepare_world(args, spec)
    return _WORLDS[key]


def run_fixed(args: Args, spec: MapSpec, explorer: str) -> dict[str, dict[str, FloatArray]]:
    """config key -> measure -> one value per task, for one map and explorer."""
    world = cached_world(args, spec)
    out: dict[str, dict[str, FloatArray]] = {}
    for c in configs(args):
        m = {name: np.zeros(args.tasks) for name in ("success", "steps", "advice")}
        for i, goal in enumerate(world.goals):
            run = world.sim.fixed(
                explorer, goal, rng_for(args.seed, "buildings", spec.index, explorer, i),
                advised=c.advised, strategy=c.strategy, kappa=c.kappa,
                window=args.window, params=c.params, max_steps=args.steps, record_p=False,
            )  # fmt: skip
            m["success"][i] = run.success
            m["steps"][i] = run.steps
            m["advice"][i] = run.advice_count if c.advised else 0
        out[c.key] = m
    return out


def run_learning(args: Args, spec: MapSpec) -> dict[str, dict[str, FloatArray]]:
    """Q-learning: none and each strategy that advises learners, at the default kappa; per
    task the share of episodes that reached the goal, and advice per 100 steps."""
    world = cached_world(args, spec)
    out: dict[str, dict[str, FloatArray]] = {}
    base = base_params(args)
    for curve in ("none", *args.learners()):
        m = {name: np.zeros(args.q_tasks) for name in ("success", "steps", "advice")}
        for i in range(args.q_tasks):
            goal = world.goals[i % len(world.goals)]
            run = world.sim.learning(
                goal, rng_for(args.seed, "buildings-q", spec.index, i), advised=curve != "none",
                params=args.q_params(), episodes=args.episodes, max_steps=world.q_steps,
                kappa=args.kappa, window=args.window,
                strategy=DEFAULT_STRATEGY if curve == "none" else curve, strategy_params=base,
            )  # fmt: skip
            m["success"][i] = run.success.mean()
            m["steps"][i] = run.steps.sum()
            m["advice"][i] = run.advice_count.sum() if curve != "none" else 0
        out[curve] = m
    return out


def run_job(args: Args, spec: MapSpec, who: str) -> dict[str, dict[str, FloatArray]]:
    """One job of the suite: an explorer's tasks on a map, or the map's Q-learning."""
    return run_learning(args, spec) if who == "q-learning" else run_fixed(args, spec, who)


@dataclass
class Results(SuiteRuns[MapSpec]):
    """``fixed[explorer][config key][measure]`` and ``learning[curve][measure]``: one row per
    map, one column per task."""

    fixed: dict[str, dict[str, dict[str, FloatArray]]]
    learning: dict[str, dict[str, FloatArray]] = field(default_factory=dict)


def run_all(args: Args) -> Results:
    suite, todo = map_suite(args), configs(args)
    fixed = {
        e: {c.key: {m: np.zeros((len(suite), args.tasks)) for m in ("success", "steps", "advice")}
            for c in todo}
        for e in FIXED_EXPLORERS
    }  # fmt: skip
    learning = {
        c: {m: np.zeros((len(suite), args.q_tasks)) for m in ("success", "steps", "advice")}
        for c in ("none", *args.learners())
    }
    jobs: list[tuple[MapSpec, str]] = [(s, e) for s in suite for e in FIXED_EXPLORERS]
    if args.q_tasks:
        jobs += [(s, "q-learning") for s in suite]

    def done(job: tuple[MapSpec, str], got: dict[str, dict[str, FloatArray]]) -> None:
        spec, who = job
        fill(learning if who == "q-learning" else fixed[who], got, spec.index)

    run_jobs(jobs, partial(run_job, args), done, args.workers, "buildings", args.progress)
    return Results(suite, todo, fixed, learning)


# ---- the summary ------------------------------------------------------------------------------
def rate(m: dict[str, FloatArray]) -> float:
    """Advice per 100 steps: the mean over tasks of 100 x advice / moves, as in Table I."""
    return float((100.0 * m["advice"] / np.maximum(m["steps"], 1)).mean())


def rows(results: Results) -> list[dict[str, Any]]:
    """One row per map (and the whole suite), explorer and configuration."""
    out = []
    scopes = [(s.name, [s.index]) for s in results.maps]
    scopes.append(("suite", [s.index for s in results.maps]))
    for scope, idx in scopes:
        for explorer, by_key in results.fixed.items():
            none = by_key["none"]
            for c in results.configs:
                m = {k: v[idx] for k, v in by_key[c.key].items()}
                n, k = int(m["success"].size), int(m["success"].sum())
                lo, hi = wilson(k, n)
                diff = paired(m["success"], none["success"][idx])
                out.append({
                    "map": scope, "explorer": explorer, "curve": c.curve, "kappa": c.kappa,
                    "key": c.key, "default": c.default, "tasks": n, "success": k / n,
                    "success_ci_low": lo, "success_ci_high": hi,
                    "advice_per_100_steps": rate(m), "mean_steps": float(m["steps"].mean()),
                    "change_vs_none": diff[0], "change_ci_low": diff[1],
                    "change_ci_high": diff[2],
                })  # fmt: skip
    return out


def learning_rows(results: Results) -> list[dict[str, Any]]:
    out: list[dict[str, Any]] = []
    if not results.learning or results.learning["none"]["success"].shape[1] == 0:
        return out
    scopes = [(s.name, [s.index]) for s in results.maps]
    scopes.append(("suite", [s.index for s in results.maps]))
    for scope, idx in scopes:
        none = results.learning["none"]["success"][idx]
        for curve, by in results.learning.items():
            m = {k: v[idx] for k, v in by.items()}
            diff = paired(m["success"], none)
            out.append({
                "map": scope, "curve": curve, "tasks": int(m["success"].size),
                "episodes_reaching_goal": float(m["success"].mean()),
                "advice_per_100_steps": rate(m), "change_vs_none": diff[0],
                "change_ci_low": diff[1], "change_ci_high": diff[2],
            })  # fmt: skip
    return out


def find(table: list[dict[str, Any]], **match: Any) -> dict[str, Any]:
    return next(r for r in table if all(r[k] == v for k, v in match.items()))


def curve_points(table: list[dict[str, Any]], scope: str, explorer: str, curve: str) -> FloatArray:
    """(advice per 100 steps, success) of a curve's levels, sorted by advice."""
    pts = [(r["advice_per_100_steps"], r["success"]) for r in table
           if r["map"] == scope and r["explorer"] == explorer and r["curve"] == curve]  # fmt: skip
    out: FloatArray = np.array(sorted(pts), dtype=np.float64).reshape(-1, 2)
    return out


def curve_above(mine: FloatArray, other: FloatArray, tasks: int = 0) -> dict[str, Any]:
    """Whether ``mine`` lies at or above ``other`` wherever both reach (linear between
    levels, on a fine grid of the shared range of advice rates). ``min_margin`` is the
    smallest difference; with ``tasks`` > 0 a point counts as below only where the difference
    is beyond the 95% sampling error of two success rates of ``tasks`` tasks each (two
    curves that both stay at the unadvised success differ by a task or two by chance)."""
    lo = max(mine[:, 0].min(), other[:, 0].min())
    hi = min(mine[:, 0].max(), other[:, 0].max())
    if lo > hi:
        return {"shared_range": None, "min_margin": None, "above": None}
    grid = np.linspace(lo, hi, 200)
    a, b = np.interp(grid, mine[:, 0], mine[:, 1]), np.interp(grid, other[:, 0], other[:, 1])
    margin = a - b
    tol = np.zeros_like(margin)
    if tasks > 0:
        floor = 1.0 / tasks  # a rate of 0 or 1 still has a task's worth of error
        var = (np.clip(a * (1 - a), floor, None) + np.clip(b * (1 - b), floor, None)) / tasks
        tol = Z95 * np.sqrt(var)
    worst = float(margin.min())
    return {
        "shared_range": [float(lo), float(hi)], "min_margin": worst,
        "above": bool((margin + tol >= 0.0).all()), "strictly_above": worst >= 0.0,
    }  # fmt: skip


def targets(results: Results, table: list[dict[str, Any]], q: list[dict[str, Any]],
            args: Args) -> dict[str, Any]:  # fmt: skip
    cand = args.candidate
    key = next(c.key for c in results.configs if c.curve == cand and c.default)
    checks: list[dict[str, Any]] = []
    for spec in results.maps:
        for explorer, need in TARGETS.items():
            r = find(table, map=spec.name, explorer=explorer, key=key)
            ok = r["success"] >= need and r["advice_per_100_steps"] <= MAX_ADVICE_PER_100
            checks.append({
                "map": spec.name, "what": f"{explorer} >= {need:.0%} at <= 25 advice / 100",
                "value": f"{r['success']:.0%} at {r['advice_per_100_steps']:.1f}", "ok": ok,
            })  # fmt: skip
        for explorer in UNHARMED:
            r = find(table, map=spec.name, explorer=explorer, key=key)
            checks.append({
                "map": spec.name, "what": f"{explorer} not significantly worse",
                "value": f"{r['change_vs_none']:+.0%} [{r['change_ci_low']:+.0%}, "
                f"{r['change_ci_high']:+.0%}]",
                "ok": r["change_ci_high"] >= 0.0,
            })  # fmt: skip
        if q and cand in args.learners():
            r = find(q, map=spec.name, curve=cand)
            checks.append({
                "map": spec.name, "what": "Q-learning not significantly worse",
                "value": f"{r['change_vs_none']:+.1%} [{r['change_ci_low']:+.1%}, "
                f"{r['change_ci_high']:+.1%}]",
                "ok": r["change_ci_high"] >= 0.0,
            })  # fmt: skip
        for explorer in ("random", "random-avoid"):
            mine = curve_points(table, spec.name, explorer, cand)
            for other in (n for n in args.strategies if n != cand):
                tasks = find(table, map=spec.name, explorer=explorer, curve="none")["tasks"]
                c = curve_above(mine, curve_points(table, spec.name, explorer, other), tasks)
                value = (
                    "no shared range" if c["shared_range"] is None
                    else f"min margin {c['min_margin']:+.0%} over "
                    f"{c['shared_range'][0]:.1f}-{c['shared_range'][1]:.1f} / 100"
                )  # fmt: skip
                checks.append({
                    "map": spec.name,
                    "what": f"{explorer}: {cand}'s curve above {other}'s (beyond noise)",
                    "value": value, "ok": c["above"] is not False,
                })  # fmt: skip
    return {"checks": checks, "all_hold": all(c["ok"] for c in checks)}


def bug_floor(world: World) -> float:
    """The fewest pieces of advice any advisor can give the bug, per 100 moves of a shortest
    walk, averaged over the map's tasks: the moves it would not make by itself on the way
    with fewest of them (``compass_detours``), over the BFS distance. An advised bug walking
    about as far as the shortest way cannot get less advice per 100 steps than this."""
    d = world.domain
    detours, moves = compass_detours(d)[:, d.start], goal_moves(d)[:, d.start]
    floors = {g: 100.0 * int(detours[i]) / max(1, int(moves[i])) for i, g in enumerate(d.goals)}
    return float(np.mean([floors[g] for g in world.goals]))


def map_info(world: World) -> dict[str, Any]:
    d = world.domain
    return {
        **asdict(world.spec), "name": world.spec.name, **plan_of(d), "actions": d.n_actions,
        "goals": len(d.goals), "states_with_expert_data": world.states_with_data,
        "farthest_goal": int(goal_moves(d)[:, d.start].max()), "q_steps": world.q_steps,
        "bug_advice_floor_per_100": bug_floor(world),
    }  # fmt: skip


# ---- the report -------------------------------------------------------------------------------
def floors_note(maps: list[dict[str, Any]]) -> list[str]:
    """What a suite with maps of several floors counts differently, as report lines."""
    several = [m["name"] for m in maps if m["floors"] > 1]
    if not several:
        return []
    return [
        f"Maps of several floors ({', '.join(several)}): six actions (U and D the rides); "
        "distances, steps and the step limits count actions (a ride is one, its time is not "
        "counted). The KL the paper's rule and goal_aware compare with kappa, and guide's "
        "value, are multiplied by log 4 / log 6 there (AdviceTables.kl_scale), so a certain "
        "theta against a lost explorer is worth log 4 on every map and every strategy's "
        "kappa levels mean the same on one floor and on several.",
        "",
    ]


def plots(results: Results, table: list[dict[str, Any]], args: Args) -> Figure:
    """Success against advice per 100 steps as kappa varies: a panel per map (and the suite)
    and explorer, a curve per strategy; the cross is the unadvised explorer."""
    scopes = [s.name for s in results.maps] + ["suite"]
    explorers = list(FIXED_EXPLORERS)
    fig = Figure(figsize=(3.0 * len(explorers), 2.6 * len(scopes)), layout="constrained")
    axes = fig.subplots(len(scopes), len(explorers), squeeze=False, sharey=True)
    for i, scope in enumerate(scopes):
        for j, explorer in enumerate(explorers):
            ax = axes[i, j]
            for curve, colour in zip(args.strategies, itertools.cycle(PALETTE), strict=False):
                pts = curve_points(table, scope, explorer, curve)
                ax.plot(pts[:, 0], pts[:, 1], "o-", color=colour, label=curve, ms=3)
                d = find(table, map=scope, explorer=explorer, curve=curve, default=True)
                ax.plot(d["advice_per_100_steps"], d["success"], "s", color=colour, ms=6)
            base = find(table, map=scope, explorer=explorer, curve="none")
            ax.plot(0, base["success"], "kx", ms=7, label="no advice")
            ax.set_ylim(-0.03, 1.03)
            ax.grid(alpha=0.3)
            if i == 0:
                ax.set_title(explorer)
            if j == 0:
                ax.set_ylabel(f"{scope}\nsuccess")
            if i == len(scopes) - 1:
                ax.set_xlabel("advice per 100 steps")
    axes[0, 0].legend(fontsize=7, loc="lower right")
    fig.suptitle("Success against advice as kappa varies (square: the default kappa)")
    return fig


def protocol(args: Any, who: str, elapsed: float, more: str = "") -> str:
    """The report's first line: tasks, moves, experts, window (``more``), seed and time."""
    return (
        f"{args.tasks} tasks per map and {who}, at most {args.steps} moves; experts "
        f"{args.experts}, {args.per_goal} per destination; window {args.window}; {more}seed "
        f"{args.seed}; {elapsed:.0f} s."
    )


def markdown(
    table: list[dict[str, Any]], q: list[dict[str, Any]], t: dict[str, Any],
    maps: list[dict[str, Any]], args: Args, elapsed: float,
) -> str:  # fmt: skip
    lines = [
        "# Advice in buildings", "",
        protocol(args, "explorer", elapsed), "",
        markdown_table(
            ["map", "floors", "rows x cols (a floor)", "free cells", "destinations",
             "cells with expert data", "farthest destination", "Q episode length",
             "bug's advice floor / 100"],
            [[m["name"], m["floors"], f"{m['rows']} x {m['cols']}", m["states"], m["goals"],
              m["states_with_expert_data"], m["farthest_goal"], m["q_steps"],
              f"{m['bug_advice_floor_per_100']:.1f}"] for m in maps],
        ), "",
        "The bug's advice floor: the fewest pieces of advice any advisor can give the bug, per "
        "100 moves of a shortest walk (the moves it would not make by itself on the way with "
        "fewest of them, over the BFS distance), averaged over the tasks.", "",
        *floors_note(maps),
        f"## At the default kappa ({args.kappa:g}): success (advice per 100 steps)", "",
    ]  # fmt: skip
    scopes = [m["name"] for m in maps] + ["suite"]
    cand, curves = args.candidate, ("none", *args.strategies)
    head = ["explorer", "map", *curves, f"{cand} - none [95%]"]
    body = []
    for explorer in FIXED_EXPLORERS:
        for scope in scopes:
            cells = []
            for curve in curves:
                r = find(table, map=scope, explorer=explorer, curve=curve, default=True)
                rate_text = "" if curve == "none" else f" ({r['advice_per_100_steps']:.1f})"
                cells.append(f"{r['success']:.0%}{rate_text}")
            g = find(table, map=scope, explorer=explorer, curve=cand, default=True)
            change = (f"{g['change_vs_none']:+.0%} [{g['change_ci_low']:+.0%}, "
                      f"{g['change_ci_high']:+.0%}]")  # fmt: skip
            body.append([explorer, scope, *cells, change])
    lines += [markdown_table(head, body), ""]
    learners = ("none", *args.learners())
    if q and cand in learners:
        lines += [
            f"## Q-learning ({args.episodes} episodes per task, {args.q_tasks} tasks per map)",
            "", "Share of episodes that reached the goal (advice per 100 steps).", "",
            markdown_table(
                ["map", *learners, f"{cand} - none [95%]"],
                [[s,
                  *[f"{find(q, map=s, curve=c)['episodes_reaching_goal']:.1%}"
                    + ("" if c == "none" else
                       f" ({find(q, map=s, curve=c)['advice_per_100_steps']:.1f})")
                    for c in learners],
                  f"{find(q, map=s, curve=cand)['change_vs_none']:+.1%} "
                  f"[{find(q, map=s, curve=cand)['change_ci_low']:+.1%}, "
                  f"{find(q, map=s, curve=cand)['change_ci_high']:+.1%}]"]
                 for s in scopes],
            ), "",
        ]  # fmt: skip
    lines += [
        "## Targets", "",
        f"All hold: **{'yes' if t['all_hold'] else 'no'}**", "",
        markdown_table(["map", "target", "measured", "holds"],
                       [[c["map"], c["what"], c["value"], "yes" if c["ok"] else "**no**"]
                        for c in t["checks"]]),
        "", "Curves: buildings.png (success against advice per 100 steps as kappa varies).",
    ]  # fmt: skip
    return "\n".join(lines) + "\n"


def run(args: Args, out: RunDir) -> dict[str, Any]:
    """Run the suite and write JSON, CSV, markdown and PNG files."""
    args.check()
    results, elapsed = timed(run_all, args)
    table, q = rows(results), learning_rows(results)
    t = targets(results, table, q, args)
    maps = [map_info(cached_world(args, s)) for s in results.maps]
    result = {
        **header("buildings", args, elapsed), "maps": maps,
        "configs": [{"key": c.key, **asdict(c)} for c in results.configs],
        "rows": table, "learning": q, "targets": t,
    }  # fmt: skip
    out.json("buildings", result)
    out.csv("buildings", table)
    if q:
        out.csv("buildings_learning", q)
    out.markdown("buildings", markdown(table, q, t, maps, args, elapsed))
    out.figure("buildings", plots(results, table, args))
    return result
