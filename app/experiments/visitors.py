"""Visitors as they are: the buildings suite with visitor models beside the paper's explorers.

Beyond the paper. The maps, experts and destination tasks of ``experiment buildings`` (the
same options: ``--buildings``, ``--hospitals``, ``--hospital-goals``, ``--imdf``, ``--mazes``,
``--maze``, ``--per-goal``, ``--experts``, ``--seed``, ``--tasks``): the same generated
buildings, hospitals of several floors and map files, the same expert data, the same goals.
A visitor (``--visitors``, one spec each, :class:`app.agents.explorers.Visitor`) is a walker
(random, random-avoid, left, bug, optimal, corridor, straight) with any of: ``p=P``, takes a
piece of advice with probability P (else its own move); ``q=Q``, the advisor reads its cell
one cell off with probability Q and decides on what it reads, while the visitor moves from
its true cell (``j=J``: up to J moves off); ``positions``, the advisor is fed the readings
as the service's ``/positions`` endpoint walks them (one decision per cell of the shortest
path from the last reading; run in the reference loop with the service's advisor, slower);
``r=R``, walks straight to its goal once it is in a straight line of free
cells within R moves, whatever the advice; ``anywhere``, bound for any free cell (drawn
uniformly, the start excepted), not only the map's destinations.

For every map and visitor, ``--tasks`` one-shot tasks (at most ``--steps`` moves), without
advice and advised by each strategy (``--strategies``, default guide) at the default kappa.
Every configuration sees the same tasks with the same visitor streams (a walker's stream is
the buildings experiment's for that walker, so a plain walker repeats its tasks), so every
change is paired task by task.

Reported per map and visitor: success (Wilson 95%); mean steps relative to the shortest path
(over the tasks that arrived); advice per 100 steps and per task; the share of tasks in which
the visitor was ever trapped (50 consecutive positions on at most 4 distinct cells) and how
many moves it spent so; the paired 95% interval of each change against no advice. Per map,
the floor: the mean arrival, over destinations drawn uniformly, of a walker led at every step
along the order of destinations that minimises that mean (no advisor that does not know the
goal can do better), and each strategy's mean arrival against it (destination-bound visitors;
a task that did not arrive counts as --steps). Exact up to 12 destinations (a dynamic
programme over subsets); beyond, bounded from above by the order a local search finds
(marked ``≤``). Beside it the mean arrival nearest first (guide's order beyond 10
destinations) and the largest share of the destinations a walk from the start reaches within
the moves a drift-free walker can be led in a task (--steps at 25 pieces per 100; exact up to
12 destinations, beyond the most a local search found, marked ``≥``).

    python -m app experiment visitors --mazes maps/brc202d.txt --visitors "random p=0.5"
"""

from __future__ import annotations

import itertools
import math
from dataclasses import asdict, dataclass, replace
from functools import partial
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from numpy.lib.stride_tricks import sliding_window_view

from app.advice.guide import ADVICE_RATE, MAX_TOUR
from app.agents.explorers import Visitor
from app.arrays import FloatArray, IntArray
from app.domain.building import Domain
from app.domain.tours import (
    MAX_SEARCH_ROUNDS,
    arrivals_along,
    local_search,
    nearest_order,
    searched_order,
)
from app.experiments import buildings
from app.experiments.common import CommonArgs, fill, rng_for, run_jobs, timed, wilson
from app.experiments.curves import (
    Z95,
    Config,
    SuiteRuns,
    check_strategies,
    paired,
    strategy_args,
)
from app.experiments.curves import configs as curve_configs
from app.experiments.output import RunDir, header, markdown_table
from app.experiments.suite import MapSpec, SuiteArgs, goal_moves, map_suite, plan_of

#: every model the visitors' issue names: the paper's explorers, walkers with a purpose,
#: compliance (one who ignores every piece too), positions read one cell off (with their
#: exact twins), any free cell as the goal, sight
DEFAULT_VISITORS = (
    "random", "random-avoid", "left", "bug", "optimal", "corridor", "straight",
    "random p=0.5", "corridor p=0.5", "random p=0", "corridor q=0.1", "optimal q=0.1",
    "random q=0.1", "random anywhere", "optimal anywhere", "random r=8", "corridor r=8",
)  # fmt: skip
STRATEGIES = ("guide",)
StrategyOptions = strategy_args("VisitorsStrategies", STRATEGIES, {"guide": ()})
#: trapped: TRAP_WINDOW consecutive positions on at most TRAP_CELLS distinct cells
TRAP_WINDOW, TRAP_CELLS = 50, 4
#: the most destinations the floor's exact order is searched over (2^G G^2 steps); beyond,
#: the floor is bounded above by a local search's order
MAX_FLOOR_GOALS = 12
#: the most destinations that local search (:func:`app.domain.tours.local_search`) improves on
#: the nearest-neighbour order for (each round is about 3 G^3 steps)
MAX_SEARCHED_GOALS = 100
MEASURES = ("success", "steps", "advice", "shortest", "trapped", "late_advice", "late_steps")
#: advice "late" in a task: after its first LATE_AFTER pieces (a visitor who ignores every
#: piece is to get at most 5 per 100 steps after its first 20)
LATE_AFTER = 20
PALETTE = ("tab:green", "tab:blue", "tab:red", "tab:purple", "tab:brown")


@dataclass
class Args(CommonArgs, StrategyOptions, SuiteArgs):  # type: ignore[valid-type,misc]
    """Visitors arguments (``--tasks``: tasks per map, visitor and configuration)."""

    tasks: int = 100
    """One-shot tasks per map and visitor; every configuration sees the same tasks."""
    steps: int = 5000
    """Step limit of a one-shot task."""
    visitors: tuple[str, ...] = DEFAULT_VISITORS
    """Visitor models, one spec each: a walker, then any of p=P (compliance), q=Q (position
    read one cell off), j=J (a wrong reading up to J moves off), r=R (sight), anywhere (any
    free cell as the goal), positions (readings walked as /positions walks them)."""
    workers: int = 2
    """Processes (1: run in this process)."""

    def check(self) -> None:
        super().check()
        self.check_trajectories("visitors")
        if self.steps < 1 or self.workers < 1:
            raise ValueError("need steps >= 1 and workers >= 1")
        self.check_suite()
        if not self.visitors:
            raise ValueError("no visitors: give --visitors specs, e.g. 'random p=0.5'")
        names = [v.name for v in self.models()]  # ValueError naming a bad spec
        if len(set(names)) != len(names):
            raise ValueError(f"a visitor is given twice: {', '.join(names)}")
        check_strategies(self)

    def models(self) -> list[Visitor]:
        return [Visitor.parse(spec) for spec in self.visitors]

    def suite(self) -> Any:  # buildings.Args (its bases are made at run time)
        """The buildings experiment's arguments that make the same maps, experts and tasks."""
        return buildings.Args(
            maze=self.maze, seed=self.seed, tasks=self.tasks, alpha0=self.alpha0,
            window=self.window, experts=self.experts, per_goal=self.per_goal, progress=False,
            buildings=self.buildings, hospitals=self.hospitals,
            hospital_goals=self.hospital_goals, imdf=self.imdf, mazes=self.mazes, q_tasks=0,
            workers=1,
        )  # fmt: skip


def configs(args: Args) -> list[Config]:
    return curve_configs(args)


# ---- the maps ---------------------------------------------------------------------------------
@dataclass
class Place:
    """What the visitors' tasks read of a map besides the buildings world."""

    world: buildings.World
    from_start: IntArray  # BFS distance from the start to every cell
    anywhere: list[int]  # the goal of each task of a visitor bound for any free cell


_PLACES: dict[tuple[Any, ...], Place] = {}


def place(args: Args, spec: MapSpec) -> Place:
    key = (args.seed, args.experts, args.per_goal, args.alpha0, args.tasks, spec)
    if key not in _PLACES:
        _PLACES.clear()
        world = buildings.cached_world(args.suite(), spec)
        d = world.domain
        cells = np.array([c for c in range(d.n_states) if c != d.start], dtype=np.int64)
        anywhere = rng_for(args.seed, "visitors-anywhere", spec.index).choice(cells, args.tasks)
        _PLACES[key] = Place(world, d.distances_to(d.start), anywhere.tolist())
    return _PLACES[key]


#: the moves from the start to each destination, and between destinations (``leg[i][j]``: from
#: destination i to j)
Legs = tuple[list[int], list[list[int]]]


def latency_legs(domain: Domain) -> Legs:
    """The moves from the start to each destination and between destinations (``leg[i][j]``:
    from destination i to j), BFS distances."""
    dist = goal_moves(domain)  # (G, S): moves from a cell to destination g
    n = len(domain.goals)
    leg = [[int(dist[j, domain.goals[i]]) for j in range(n)] for i in range(n)]
    return [int(dist[j, domain.start]) for j in range(n)], leg


def min_latency_order(legs: Legs) -> tuple[list[int], list[int]] | None:
    """The order of the destinations that minimises the mean arrival (over destinations drawn
    uniformly) of a walker from the start along shortest paths, and the arrival at each
    destination (by index) on it: exact, a dynamic programme over subsets (latency: each leg
    delays every destination not yet reached). None beyond MAX_FLOOR_GOALS destinations.
    ``legs``: :func:`latency_legs`."""
    first, leg = legs
    n = len(first)
    if n == 0 or n > MAX_FLOOR_GOALS:
        return None
    full = (1 << n) - 1
    best = [[math.inf] * n for _ in range(1 << n)]
    came = [[-1] * n for _ in range(1 << n)]
    for j in range(n):
        best[1 << j][j] = n * first[j]
    for mask in range(1, full + 1):
        left = n - bin(mask).count("1")  # destinations still to reach after this one
        for i in range(n):
            cost = best[mask][i]
            if cost == math.inf or not (mask >> i) & 1:
                continue
            for j in range(n):
                if (mask >> j) & 1:
                    continue
                c = cost + left * leg[i][j]
                if c < best[mask | 1 << j][j]:
                    best[mask | 1 << j][j] = c
                    came[mask | 1 << j][j] = i
    last = min(range(n), key=lambda j: best[full][j])
    order, mask = [], full
    while last >= 0:
        order.append(last)
        last, mask = came[mask][last], mask & ~(1 << last)
    order.reverse()
    return order, arrivals_along(order, first, leg)


def search_rounds(n: int) -> int:
    """The rounds of local search for ``n`` destinations: MAX_SEARCH_ROUNDS, none beyond
    MAX_SEARCHED_GOALS."""
    return MAX_SEARCH_ROUNDS if n <= MAX_SEARCHED_GOALS else 0


def searched_latency_order(legs: Legs) -> tuple[list[int], list[int]] | None:
    """An order of the destinations with a low mean arrival where the exact search is out of
    reach: the nearest-neighbour order from the start, improved by :func:`local_search` on
    the sum of the arrivals. Its mean arrival is at least the floor's: an upper bound on it.
    None without destinations."""
    first, leg = legs
    if not first:
        return None
    order = searched_order(first, leg, search_rounds(len(first)))
    return order, arrivals_along(order, first, leg)


def most_within(legs: Legs, order: list[int], budget: int) -> tuple[int, bool]:
    """The most destinations a walk from the start along shortest paths reaches within
    ``budget`` moves, and whether that is exact: a dynamic programme over subsets (the
    shortest walk through each subset, ending at each of its destinations) up to
    MAX_FLOOR_GOALS destinations; beyond, the most :func:`local_search` found from ``order``
    (the true most is at least that)."""
    first, leg = legs
    n = len(first)
    if n > MAX_FLOOR_GOALS:

        def cost(o: list[int]) -> tuple[int, int]:
            arrival = arrivals_along(o, first, leg)
            return -sum(a <= budget for a in arrival), sum(arrival)

        return -cost(local_search(order, cost, search_rounds(n)))[0], False
    walk = [[math.inf] * n for _ in range(1 << n)]
    for j in range(n):
        walk[1 << j][j] = first[j]
    most = 0
    for mask in range(1, 1 << n):
        for i in range(n):
            here = walk[mask][i]
            if here > budget:
                continue
            most = max(most, bin(mask).count("1"))
            for j in range(n):
                if not (mask >> j) & 1 and here + leg[i][j] < walk[mask | 1 << j][j]:
                    walk[mask | 1 << j][j] = here + leg[i][j]
    return most, True


# ---- the runs ---------------------------------------------------------------------------------
def trapped_moves(states: IntArray) -> int:
    """The moves made while trapped: at which the last TRAP_WINDOW positions held at most
    TRAP_CELLS distinct cells."""
    if states.size < TRAP_WINDOW:
        return 0
    windows = np.sort(sliding_window_view(states, TRAP_WINDOW), axis=1)
    distinct = 1 + (windows[:, 1:] != windows[:, :-1]).sum(axis=1)
    return int((distinct <= TRAP_CELLS).sum())


def run_job(args: Args, spec: MapSpec, spec_text: str) -> dict[str, dict[str, FloatArray]]:
    """config key -> measure -> one value per task, for one map and visitor."""
    here, v = place(args, spec), Visitor.parse(spec_text)
    world = here.world
    goals = here.anywhere if v.anywhere else world.goals
    out: dict[str, dict[str, FloatArray]] = {}
    for c in configs(args):
        m = {name: np.zeros(args.tasks) for name in MEASURES}
        for i, goal in enumerate(goals):
            run = world.sim.fixed(
                v.walker, goal, rng_for(args.seed, "buildings", spec.index, v.walker, i),
                advised=c.advised, strategy=c.strategy, kappa=c.kappa, window=args.window,
                params=c.params, max_steps=args.steps, record_p=False,
                compliance=v.compliance, noise=v.noise, sight=v.sight,
                seen_rng=rng_for(args.seed, "visitors-seen", spec.index, v.name, i),
                feed=v.feed, jump=v.jump,
            )  # fmt: skip
            m["success"][i] = run.success
            m["steps"][i] = run.steps
            m["advice"][i] = run.advice_count if c.advised else 0
            m["shortest"][i] = here.from_start[goal]
            m["trapped"][i] = trapped_moves(run.states)
            given = np.flatnonzero(run.advise) if c.advised else np.zeros(0, dtype=np.int64)
            if given.size > LATE_AFTER:  # the pieces and steps after the first LATE_AFTER
                m["late_advice"][i] = given.size - LATE_AFTER
                m["late_steps"][i] = run.steps - (int(given[LATE_AFTER - 1]) + 1)
        out[c.key] = m
    return out


@dataclass
class Results(SuiteRuns[MapSpec]):
    """``runs[visitor][config key][measure]``: one row per map, one column per task."""

    visitors: list[Visitor]
    runs: dict[str, dict[str, dict[str, FloatArray]]]


def run_all(args: Args) -> Results:
    suite, todo, models = map_suite(args.suite()), configs(args), args.models()
    runs = {
        v.name: {c.key: {m: np.zeros((len(suite), args.tasks)) for m in MEASURES} for c in todo}
        for v in models
    }
    jobs = [(s, v.name) for s in suite for v in models]

    def done(job: tuple[MapSpec, str], got: dict[str, dict[str, FloatArray]]) -> None:
        fill(runs[job[1]], got, job[0].index)

    run_jobs(jobs, partial(run_job, args), done, args.workers, "visitors", args.progress)
    return Results(suite, todo, models, runs)


# ---- the summary ------------------------------------------------------------------------------
def change(a: FloatArray, b: FloatArray) -> tuple[float, float, float]:
    """Mean of a - b over paired tasks with a 95% normal interval (nan when no pair)."""
    d = (np.asarray(a, dtype=np.float64) - b).ravel()
    if d.size == 0:
        return math.nan, math.nan, math.nan
    mean = float(d.mean())
    se = float(d.std(ddof=1)) / math.sqrt(d.size) if d.size > 1 else math.inf
    return mean, mean - Z95 * se, mean + Z95 * se


def measures(m: dict[str, FloatArray]) -> dict[str, Any]:
    """A configuration's figures over its tasks (arrays of equal length)."""
    n, k = int(m["success"].size), int(m["success"].sum())
    lo, hi = wilson(k, n)
    arrived = m["success"] > 0
    ratio = m["steps"][arrived] / np.maximum(m["shortest"][arrived], 1)
    trapped = m["trapped"] > 0
    return {
        "tasks": n, "success": k / n, "success_ci_low": lo, "success_ci_high": hi,
        "arrived": int(arrived.sum()),
        "steps_over_shortest": float(ratio.mean()) if ratio.size else math.nan,
        "mean_steps": float(m["steps"].mean()),
        "advice_per_100_steps": float((100.0 * m["advice"] / np.maximum(m["steps"], 1)).mean()),
        "advice_per_task": float(m["advice"].mean()),
        "late_advice_per_100_steps": (
            100.0 * float(m["late_advice"].sum()) / float(m["late_steps"].sum())
            if m["late_steps"].sum() > 0 else math.nan
        ),
        "trapped_share": float(trapped.mean()),
        "trapped_moves": float(m["trapped"][trapped].mean()) if trapped.any() else 0.0,
    }  # fmt: skip


def floor_of(args: Args, spec: MapSpec) -> dict[str, Any]:
    """A map's floor (mean arrival over destinations drawn uniformly), its order, whether it
    is exact (else the best order the local search found: an upper bound), the floor on the
    drawn destination tasks (the mean of their destinations' arrivals) and the largest share
    of the destinations a walk reaches within ``reach_of(args)`` moves (:func:`most_within`)."""
    world = place(args, spec).world
    d = world.domain
    legs = latency_legs(d)  # a BFS from every destination: once for each figure below
    exact = len(d.goals) <= MAX_FLOOR_GOALS
    got = min_latency_order(legs) if exact else searched_latency_order(legs)
    if got is None:
        return {"floor": None, "order": None, "floor_on_tasks": None, "floor_exact": None,
                "floor_reach": None, "floor_reach_exact": None,
                "nearest_first": None}  # fmt: skip
    order, arrival = got
    index = {g: i for i, g in enumerate(d.goals)}
    most, most_exact = most_within(legs, order, reach_of(args))
    first, leg = legs
    return {
        "nearest_first": float(np.mean(arrivals_along(nearest_order(first, leg), first, leg))),
        "floor": float(np.mean(arrival)), "order": order, "arrival": arrival,
        "floor_on_tasks": float(np.mean([arrival[index[g]] for g in world.goals])),
        "floor_exact": exact, "floor_reach": most / len(order), "floor_reach_exact": most_exact,
    }  # fmt: skip


def reach_of(args: Args) -> int:
    """The moves a walker whose own moves have no drift is led in a task at most, gaining a
    move a piece at guide's budget (ADVICE_RATE pieces a step) over the step limit."""
    return int(args.steps * ADVICE_RATE)


def map_scopes(results: Results) -> list[tuple[str, list[int]]]:
    """Each map (its name and row) and the whole suite (every row)."""
    each = [(s.name, [s.index]) for s in results.maps]
    return [*each, ("suite", [s.index for s in results.maps])]


def rows(results: Results, floor: dict[str, dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per map (and the whole suite), visitor and configuration."""
    out = []
    for scope, idx in map_scopes(results):
        for v in results.visitors:
            by_key = results.runs[v.name]
            none = {k: x[idx].ravel() for k, x in by_key["none"].items()}
            for c in results.configs:
                m = {k: x[idx].ravel() for k, x in by_key[c.key].items()}
                both = (m["success"] > 0) & (none["success"] > 0)
                ratio = m["steps"] / np.maximum(m["shortest"], 1)
                ratio0 = none["steps"] / np.maximum(none["shortest"], 1)
                ds = paired(m["success"], none["success"])
                dr = change(ratio[both], ratio0[both])
                dt = paired(
                    (m["trapped"] > 0).astype(np.float64), (none["trapped"] > 0).astype(np.float64)
                )
                f = floor.get(scope, {}).get("floor_on_tasks")
                at_floor = f is not None and not v.anywhere
                out.append({
                    "map": scope, "visitor": v.name, "walker": v.walker,
                    "compliance": v.compliance, "noise": v.noise, "sight": v.sight,
                    "jump": v.jump, "feed": v.feed,
                    "goals": v.goals, "curve": c.curve, "kappa": c.kappa, "key": c.key,
                    "default": c.default, **measures(m),
                    "change_success": ds[0], "change_success_ci_low": ds[1],
                    "change_success_ci_high": ds[2], "both_arrived": int(both.sum()),
                    "change_steps_over_shortest": dr[0],
                    "change_steps_over_shortest_ci_low": dr[1],
                    "change_steps_over_shortest_ci_high": dr[2],
                    "change_trapped_share": dt[0], "change_trapped_share_ci_low": dt[1],
                    "change_trapped_share_ci_high": dt[2],
                    "floor_on_tasks": f if at_floor else None,
                    "floor_exact": floor.get(scope, {}).get("floor_exact") if at_floor else None,
                    "arrival_over_floor": float(m["steps"].mean()) / f
                    if at_floor and f else None,
                })  # fmt: skip
    return out


def noise_rows(results: Results) -> list[dict[str, Any]]:
    """Positions read one cell off against exact positions: for every visitor with q > 0 whose
    exact twin (the same spec at q = 0) ran too, per map and advised configuration, the
    success of both and the paired change (the same tasks, the same walker's draws)."""
    out = []
    for v in results.visitors:
        exact = replace(v, noise=0.0, jump=1).name
        if v.noise == 0.0 or exact not in results.runs:
            continue
        for c in results.configs:
            if not c.advised:
                continue
            for scope, idx in map_scopes(results):
                noisy = results.runs[v.name][c.key]["success"][idx].ravel()
                base = results.runs[exact][c.key]["success"][idx].ravel()
                d = paired(noisy, base)
                out.append({
                    "map": scope, "visitor": v.name, "exact": exact, "key": c.key,
                    "success_exact": float(base.mean()), "success": float(noisy.mean()),
                    "change": d[0], "change_ci_low": d[1], "change_ci_high": d[2],
                })  # fmt: skip
    return out


def find(table: list[dict[str, Any]], **match: Any) -> dict[str, Any]:
    return next(r for r in table if all(r[k] == v for k, v in match.items()))


def map_info(args: Args, spec: MapSpec, floor: dict[str, Any]) -> dict[str, Any]:
    world = place(args, spec).world
    d = world.domain
    return {
        **asdict(spec), "name": spec.name, **plan_of(d), "goals": len(d.goals),
        "states_with_expert_data": world.states_with_data,
        "farthest_goal": int(goal_moves(d)[:, d.start].max()), **floor,
    }  # fmt: skip


# ---- the report -------------------------------------------------------------------------------
def plots(results: Results, table: list[dict[str, Any]]) -> Figure:
    """Success per map, a panel per visitor: no advice (grey) and each configuration."""
    names = [v.name for v in results.visitors]
    scopes = [s.name for s in results.maps] + ["suite"]
    cols = min(4, len(names))
    nrows = math.ceil(len(names) / cols)
    fig = Figure(figsize=(4.2 * cols, 0.22 * len(scopes) * nrows + 1.2 * nrows),
                 layout="constrained")  # fmt: skip
    axes = fig.subplots(nrows, cols, squeeze=False, sharex=True)
    keys = [c.key for c in results.configs]
    height = 0.8 / len(keys)
    for ax, name in zip(axes.ravel(), names, strict=False):
        y = np.arange(len(scopes))
        for k, (key, colour) in enumerate(zip(keys, itertools.chain(["grey"], PALETTE),
                                              strict=False)):  # fmt: skip
            vals = [find(table, map=s, visitor=name, key=key)["success"] for s in scopes]
            ax.barh(y + k * height, vals, height, color=colour, label=key)
        ax.set_yticks(y + 0.4 - height / 2, scopes, fontsize=6)
        ax.invert_yaxis()
        ax.set_xlim(0, 1)
        ax.set_title(name, fontsize=9)
        ax.grid(axis="x", alpha=0.3)
    for ax in axes.ravel()[len(names) :]:
        ax.axis("off")
    axes[0, 0].legend(fontsize=7, loc="lower right")
    fig.suptitle("Success per map and visitor, without advice and advised")
    return fig


def _ci(r: dict[str, Any], name: str, pct: bool = True) -> str:
    mean, lo, hi = r[name], r[f"{name}_ci_low"], r[f"{name}_ci_high"]
    if mean is None or not math.isfinite(mean):
        return "-"
    if pct:
        return f"{mean:+.0%} [{lo:+.0%}, {hi:+.0%}]"
    return f"{mean:+.2f} [{lo:+.2f}, {hi:+.2f}]"


def _bound(m: dict[str, Any], name: str) -> str:
    """A map's floor figure, '≤' where it is the local search's upper bound."""
    return ("" if m["floor_exact"] in (None, True) else "≤ ") + _ratio(m[name])


def _ratio(x: float, digits: int = 2) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{x:.{digits}f}"


def markdown(table: list[dict[str, Any]], maps: list[dict[str, Any]], results: Results,
             args: Args, elapsed: float) -> str:  # fmt: skip
    lines = [
        "# Visitors as they are", "",
        buildings.protocol(args, "visitor", elapsed, f"kappa {args.kappa:g}; "), "",
        markdown_table(
            ["map", "floors", "rows x cols (a floor)", "free cells", "destinations",
             "farthest destination", "floor (mean arrival)", "floor on these tasks",
             "nearest first (mean arrival)", f"destinations within {reach_of(args):,} moves",
             "order of the floor"],
            [[m["name"], m["floors"], f"{m['rows']} x {m['cols']}", m["states"], m["goals"],
              m["farthest_goal"], _bound(m, "floor"), _bound(m, "floor_on_tasks"),
              _ratio(m["nearest_first"]),
              "-" if m["floor_reach"] is None
              else ("" if m["floor_reach_exact"] else "≥ ") + f"{m['floor_reach']:.0%}",
              " ".join(f"G{j}" for j in m["order"]) if m["order"] else "-"] for m in maps],
        ), "",
        "The floor: the mean arrival, over destinations drawn uniformly, of a walker led at "
        "every step along the order of destinations that minimises it (exact, a dynamic "
        f"programme over subsets, BFS distances, up to {MAX_FLOOR_GOALS} destinations); no "
        "advisor that does not know the goal can do better. Beyond that, '≤': the best order "
        "a local search found (nearest neighbour first, then segments reversed and moved), an "
        "upper bound on the floor. 'On these tasks': the mean of that walker's arrivals at the "
        "destinations the tasks drew. 'Nearest first': the mean arrival along the destinations "
        "taken nearest first from the start (guide's target beyond "
        f"{MAX_TOUR} destinations is the nearest one not yet ruled out). 'Within': the "
        "largest share of the destinations a walk "
        f"from the start reaches within {reach_of(args):,} moves, all a walker whose own moves "
        f"have no drift can be led in {args.steps:,} steps at {ADVICE_RATE * 100:.0f} pieces "
        "per 100 (a move a piece): exact up to the same number of destinations, beyond it "
        "'≥', the most a local search found (the true largest share is at least that).", "",
        *buildings.floors_note(maps),
        "Per map and visitor: success (Wilson 95%); steps / shortest path over the tasks that "
        "arrived (the change over the tasks that arrived both ways); advice per 100 steps "
        f"and per task, and per 100 steps after a task's first {LATE_AFTER} pieces (pooled "
        f"over the tasks with more than {LATE_AFTER}); trapped: the share of tasks with 50 "
        "consecutive positions on at most 4 cells (moves spent so, per trapped task); "
        "arrival / floor: the mean steps (a task "
        "that did not arrive counts as the step limit) over the floor on these tasks, for "
        "visitors bound for the destinations ('≥' where the floor is the search's bound). "
        "Changes: paired over the tasks, 95% normal "
        "interval.", "",
    ]  # fmt: skip
    scopes = [m["name"] for m in maps] + ["suite"]
    for c in results.configs:
        if not c.advised:
            continue
        lines += [f"## {c.key} against no advice", ""]
        body = []
        for v in results.visitors:
            for scope in scopes:
                r = find(table, map=scope, visitor=v.name, key=c.key)
                r0 = find(table, map=scope, visitor=v.name, key="none")
                body.append([
                    v.name, scope,
                    f"{r0['success']:.0%} → {r['success']:.0%} "
                    f"[{r['success_ci_low']:.0%}, {r['success_ci_high']:.0%}]",
                    _ci(r, "change_success"),
                    f"{_ratio(r0['steps_over_shortest'])} → {_ratio(r['steps_over_shortest'])}",
                    _ci(r, "change_steps_over_shortest", pct=False),
                    f"{r['advice_per_100_steps']:.1f}", f"{r['advice_per_task']:.1f}",
                    _ratio(r["late_advice_per_100_steps"], 1),
                    f"{r0['trapped_share']:.0%} ({r0['trapped_moves']:.0f}) → "
                    f"{r['trapped_share']:.0%} ({r['trapped_moves']:.0f})",
                    ("≥ " if r["floor_exact"] is False else "")
                    + _ratio(r["arrival_over_floor"]),
                ])  # fmt: skip
        lines += [
            markdown_table(
                ["visitor", "map", "success: none → advised [95%]", "change [95%]",
                 "steps / shortest", "change [95%]", "advice / 100 steps", "advice / task",
                 f"after {LATE_AFTER} pieces / 100 steps", "trapped (moves)", "arrival / floor"],
                body,
            ), "",
        ]  # fmt: skip
    noise = noise_rows(results)
    if noise:
        lines += [
            "## Positions read one cell off against exact positions", "",
            "The same tasks and walker draws with exact positions and with each cell read one "
            "cell off with probability q (up to J moves off with j=J; a positions visitor's "
            "twin is fed exact positions too); success of both and the paired change [95%].", "",
            markdown_table(
                ["visitor", "map", "advised by", "exact", "read off", "change [95%]"],
                [[r["visitor"], r["map"], r["key"], f"{r['success_exact']:.0%}",
                  f"{r['success']:.0%}", _ci(r, "change")] for r in noise],
            ), "",
        ]  # fmt: skip
    lines += ["Bars: visitors.png (success per map and visitor)."]
    return "\n".join(lines) + "\n"


def run(args: Args, out: RunDir) -> dict[str, Any]:
    """Run the suite and write JSON, CSV, markdown and PNG files."""
    args.check()
    results, elapsed = timed(run_all, args)
    floor: dict[str, dict[str, Any]] = {}
    maps = []
    for s in results.maps:  # one map's world at a time, made once
        floor[s.name] = floor_of(args, s)
        maps.append(map_info(args, s, floor[s.name]))
    table = rows(results, floor)
    result = {
        **header("visitors", args, elapsed), "maps": maps,
        "visitors": [{"spec": v.name, **asdict(v)} for v in results.visitors],
        "configs": [{"key": c.key, **asdict(c)} for c in results.configs], "rows": table,
        "noise": noise_rows(results),
    }  # fmt: skip
    out.json("visitors", result)
    out.csv("visitors", table)
    out.markdown("visitors", markdown(table, maps, results, args, elapsed))
    out.figure("visitors", plots(results, table))
    return result
