"""A decision on a building of several floors against one on a floor of as many cells.

Target (issue 29): a multi-floor domain costs at most 1.6 x the per-decision cost of a
one-floor domain of as many cells (six actions instead of four). The building is a generated
hospital (``maze generate --kind building --floors F``: F floors of N x N, lifts and stairs);
the one-floor domain a generated building whose side is N x sqrt(F), so that both have about
as many free cells (the table gives both counts). On each, the paper's tables from experts
walking from every cell (``anywhere``, 10 per destination), then the measurements of
``bench_core.py``: the readable core's observe + decide for one explorer, and the compiled form
the service runs (``StreamAdvisor.observe_batch``: 10,000 explorers x 600 random moves a
call, window 300; each move from a random state, and again with each explorer walking, as
explorers move: random states miss the caches, and six actions' tables miss them more); and
guide's compiled batch (``bench_guide.py``'s: 500-event batches of one random walk, CPU
time), the one-floor building with as many destinations as the hospital.
The two domains are measured in turn within each repeat (this machine is shared and noisy);
each figure is the median over ``--repeats``, and each ratio the median of the repeats'
ratios.

    .venv/bin/python benchmarks/bench_floors.py [--floors 4] [--side 64] [--repeats 5]
        [--write docs/PERFORMANCE.md]
"""

from __future__ import annotations

import math
import statistics
import sys
from functools import partial
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.advice.guide import GuideMap, GuideParams
from app.advice.models import AdviceTables
from app.agents.experts import train_goal_priors, train_prior
from app.domain.building import Domain
from app.domain.floorplans import generate_floors
from app.domain.generate import generate_building_domain
from app.strategies.stream import StreamGuide
from benchmarks._report import arguments, command_line, machine, write_section
from benchmarks.bench_core import bench_single, compiled_rate
from benchmarks.bench_guide import per_decision, walk_batches

#: the cost ratio the issue allows a building of several floors
MOST = 1.6


def tables_of(domain: Domain) -> AdviceTables:
    prior = train_prior(domain, np.random.default_rng(0), "anywhere", per_goal=10)
    return AdviceTables.paper(prior.theta())


def main() -> None:
    ap = arguments(__doc__)
    ap.add_argument("--floors", type=int, default=4, help="floors of the building (2-...)")
    ap.add_argument("--side", type=int, default=64, help="rows = columns of each floor")
    ap.add_argument("--repeats", type=int, default=5, help="runs of each measurement")
    ap.add_argument("--write", type=Path, help="rewrite this markdown file's floors section")
    args = ap.parse_args()
    if args.floors < 2 or args.side < 32 or args.repeats < 1:
        ap.error("need --floors >= 2, --side >= 32 and --repeats >= 1")
    building = generate_floors(
        args.side, args.side, args.floors, np.random.default_rng(1), purpose="hospital"
    )
    side = round(args.side * math.sqrt(args.floors))
    flat = generate_building_domain(side, side, 1, n_goals=len(building.goals))
    domains: dict[str, Domain] = {"one floor": flat, "building": building}
    tables = {k: tables_of(d) for k, d in domains.items()}
    guides = {}
    for k, d in domains.items():  # guide's compiled batch, as bench_guide.py measures it
        rng = np.random.default_rng(0)
        prior, goals = train_goal_priors(d, rng, "start", 3, 1.0)
        make = partial(StreamGuide, AdviceTables.paper(prior.theta()), GuideMap.of(d, goals),
                       params=GuideParams.of())  # fmt: skip
        guides[k] = (make, walk_batches(d, rng, 21))
    rows = ("single", "call", "batch", "walks", "guide")
    got: dict[str, dict[str, list[float]]] = {k: {m: [] for m in rows} for k in domains}
    for k, d in domains.items():  # compiled (or read from numba's cache) before timing
        compiled_rate(tables[k], d, 1, n=10, steps=10)
    for _ in range(args.repeats):
        for k, d in domains.items():  # in turn, within each repeat
            run, call = bench_single(tables[k], d, 1)
            got[k]["single"].append(run)
            got[k]["call"].append(call)
            got[k]["batch"].append(1e6 / compiled_rate(tables[k], d, 1))  # us a decision
            got[k]["walks"].append(1e6 / compiled_rate(tables[k], d, 1, walk=True))
            make, batches = guides[k]
            got[k]["guide"].append(per_decision(d, batches, make, 1))
    med = {k: {m: statistics.median(v) for m, v in by.items()} for k, by in got.items()}
    ratio = {
        m: statistics.median(
            b / f for b, f in zip(got["building"][m], got["one floor"][m], strict=True)
        )
        for m in rows
    }
    what = {
        "single": "readable core, observe + decide (mean per call)",
        "call": "readable core, observe + decide (median of 20k timed calls)",
        "batch": "compiled, 10,000 explorers x 600 moves a call (CPU time per decision)",
        "walks": "the same, each explorer walking (each state the last one's next)",
        "guide": f"guide, compiled, 20 batches of 500 moves, {len(building.goals)} destinations",
    }
    lines = [
        f"| {what[m]} | {med['one floor'][m]:.3f} us | {med['building'][m]:.3f} us | "
        f"{ratio[m]:.2f} | <= {MOST} |"
        for m in rows
    ]
    table = (
        "| per decision | one floor | building | ratio | target |\n|---|---|---|---|---|\n"
        + "\n".join(lines)
    )
    body = (
        "## A building of several floors against one floor of as many cells\n\n"
        f"Command: `{command_line()}` (each figure the median of {args.repeats} runs, the two "
        "domains in turn within each; each ratio the median of the runs' ratios)\n\n"
        f"Machine: {machine()}\n\n"
        f"Domains: a generated hospital of {args.floors} floors of {args.side} x {args.side} "
        f"(seed 1; {building.n_states:,} free cells, 6 actions, "
        f"{len(building.goals)} destinations) and a generated one-floor building of {side} x "
        f"{side} (seed 1; {flat.n_states:,} free cells, 4 actions, {len(flat.goals)} "
        "destinations); the paper's tables from experts walking from every cell (guide's from "
        "experts walking from the start, 3 a destination).\n\n"
        f"{table}\n"
    )
    print(body)
    if args.write:
        write_section(args.write, "bench_floors", body)


if __name__ == "__main__":
    main()
