"""What measuring a walk costs guide: CPU time a decision of the compiled episode, per visitor.

A visitor whose last 24 (48) moves the map's bound (``GuideMap.apart``) does not show to be a
shortest path has its walk measured (``GuideAdvisor._walked_apart``: a look along the walk,
then a search of at most ``PURPOSE_SEARCH`` cells, ``kernels.guide_within``). Timed here: the
compiled episodes of ``experiment visitors`` (``Simulator.fixed``, strategy guide at the
default kappa, 5,000 moves at most) on a generated building of the suite (64 x 64, seed
693612370) and a generated hospital (3 floors of 64 x 64, seed 1, 8 destinations a floor),
for walkers bound for a destination (straight-ahead, corridor, random) and the optimal walker
bound for any free cell, ``--tasks`` each: CPU time over all their moves, the best of
``--repeats`` runs. And the most a search can cost: ``guide_within`` between cells 48 moves
apart whose bound falls 6 moves short or more, asked for a walk of 47 (none exists, so it
searches until its budget or the cells run out), the mean over 200 such pairs (a decision
searches at most twice).

    .venv/bin/python benchmarks/bench_purpose.py [--tasks 40] [--repeats 3]
        [--write docs/PERFORMANCE.md]
    python benchmarks/compare_trees.py --before /work/wt-base --runs 3 bench_purpose.py
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app import kernels
from app.advice import guide
from app.advice.guide import GuideMap
from app.advice.models import AdviceTables
from app.agents.experts import train_goal_priors
from app.agents.simulate import Simulator
from app.domain.building import Domain
from app.domain.floorplans import generate_floors
from app.domain.generate import generate_building_domain
from benchmarks._report import arguments, command_line, machine, write_section

WALKERS = ("straight", "corridor", "random", "optimal anywhere")


def per_move(sim: Simulator, walker: str, goals: list[int], repeats: int) -> float:
    """CPU time a move (us) of ``walker``'s compiled guide episodes to ``goals``, the best of
    ``repeats`` runs (a first run compiles, or reads numba's cache)."""
    name = walker.split()[0]

    def run() -> tuple[float, int]:
        moves = 0
        t = time.process_time()
        for i, goal in enumerate(goals):
            rng = np.random.default_rng(i)
            moves += sim.fixed(
                name, goal, rng, advised=True, strategy="guide", record_p=False
            ).steps
        return time.process_time() - t, moves

    run()
    return min(t / n for t, n in (run() for _ in range(repeats))) * 1e6


def search_cost(d: Domain, gm: GuideMap, pairs: int = 200) -> tuple[float, float] | None:
    """The mean CPU time (us) of one search at the budget between cells 48 moves apart, and
    the share given up; None where the tree has no such search."""
    within = getattr(kernels, "guide_within", None)
    if within is None:
        return None
    rng = np.random.default_rng(0)
    budget, most = guide.PURPOSE_SEARCH, guide.PURPOSE_LONG - 1
    found: list[tuple[int, int]] = []
    for _ in range(50 * pairs):  # pairs whose bound falls short (else no search is made)
        u = int(rng.integers(d.n_states))
        far = [v for v in np.flatnonzero(d.distances_to(u) == most + 1).tolist()
               if gm.apart(v, u) <= most - guide.PURPOSE_LONG_SLACK]  # fmt: skip
        if far:
            found.append((far[int(rng.integers(len(far)))], u))
        if len(found) == pairs:
            break
    if not found:
        return None
    args = (gm.next_state, gm.cells, gm.dist, gm.marks, gm.cells_bound)
    within(*args, found[0][0], found[0][1], most, budget)  # compiled before timing
    t = time.process_time()
    out = [within(*args, u, v, most, budget) for u, v in found]
    return (time.process_time() - t) / len(found) * 1e6, out.count(-1) / len(found)


def main() -> None:
    ap = arguments(__doc__)
    ap.add_argument("--tasks", type=int, default=40, help="tasks per walker and map")
    ap.add_argument("--repeats", type=int, default=3, help="runs of each measurement")
    ap.add_argument("--write", type=Path, help="rewrite this markdown file's section")
    args = ap.parse_args()
    if args.tasks < 1 or args.repeats < 1:
        ap.error("need --tasks >= 1 and --repeats >= 1")
    maps: dict[str, Domain] = {
        "building 64 x 64": generate_building_domain(64, 64, 693612370),
        "hospital 3 x 64 x 64": generate_floors(
            64, 64, 3, np.random.default_rng(1), purpose="hospital", n_goals=8
        ),
    }
    lines = []
    for name, d in maps.items():
        prior, goal_priors = train_goal_priors(d, np.random.default_rng(0), "start", 10, 1.0)
        sim = Simulator(d, AdviceTables.paper(prior.theta()), goal_priors)
        rng = np.random.default_rng(1)
        cells = [s for s in range(d.n_states) if s != d.start]
        for walker in WALKERS:
            if walker.endswith("anywhere"):
                goals = rng.choice(cells, args.tasks).tolist()
            else:
                goals = [d.goals[i % len(d.goals)] for i in range(args.tasks)]
            us = per_move(sim, walker, goals, args.repeats)
            lines.append(f"| {name}: {walker} | {us:.2f} us a move |")
        cost = search_cost(d, GuideMap.of(d, goal_priors))
        if cost is not None:
            lines.append(
                f"| {name}: one search at the budget ({guide.PURPOSE_SEARCH} cells) | "
                f"{cost[0]:.2f} us a search ({cost[1]:.0%} given up) |"
            )
    body = (
        "## Measuring a walk: what it costs guide\n\n"
        f"Command: `{command_line()}` ({args.tasks} tasks a walker, CPU time, the best of "
        f"{args.repeats} runs)\n\nMachine: {machine()}\n\n"
        "| map: walker (guide's compiled episode) | CPU time |\n|---|---|\n"
        + "\n".join(lines)
        + "\n"
    )
    print(body)
    if args.write:
        write_section(args.write, "bench_purpose", body)


if __name__ == "__main__":
    main()
