"""Where guide's advice budget goes: per decision, advised, or not, and why.

A diagnosis, not a speed measurement: the readable advisor (``GuideAdvisor``, the reference
loop ``run_episode``) on the visitors experiment's tasks of one map, for one walker. Every
decision is counted once: advised; or not advised with the budget full (``ADVICE_BURST``
pieces saved, so a piece more would have been given at no price), by why: the walker walks
a way of its own (the purpose test), advice is held back (it ignores advice, or undid
chains), every destination is passed, or the value fell below kappa, with P(lost | H) below or
above 1/2 and the model of the largest evidence; or not advised with the budget not full
(saving for where it is worth more). A walker that takes every piece and gains a move a piece
should have its budget spent: decisions with the budget full and no advice are pieces lost.

    .venv/bin/python benchmarks/guide_budget.py --imdf --walker random --tasks 12
    .venv/bin/python benchmarks/guide_budget.py --hospital 3x64 --walker random-avoid
    .venv/bin/python benchmarks/guide_budget.py --maze maps/den020d.txt --walker random
"""

from __future__ import annotations

import collections
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app import strategies
from app.advice import guide
from app.agents.episodes import run_episode
from app.agents.explorers import Visitor, make_explorer
from app.experiments import visitors
from app.experiments.suite import map_suite
from app.strategies.entry import AdvisorSettings
from benchmarks._report import arguments


def model_name(k: int, n: int) -> str:
    """The name of evidence row ``k`` of ``n`` (L4, LO, WL, WR, each destination's D4, DO,
    C, then LA and LS)."""
    if k < guide.N_LOST:
        return ("L4", "LO", "WL", "WR")[k]
    if k >= n - 2:
        return ("LA", "LS")[k - (n - 2)]
    return ("D4", "DO", "C")[(k - guide.N_LOST) % 3]


def main() -> None:
    ap = arguments(__doc__)
    ap.add_argument("--hospital", help="a generated hospital FLOORSxSIDE, as --hospitals")
    ap.add_argument("--imdf", action="store_true", help="the project's IMDF venue")
    ap.add_argument("--maze", type=Path, help="a map file")
    ap.add_argument("--building", type=int, default=0, help="a generated building's side")
    ap.add_argument("--walker", default="random", help="a visitor spec (random, 'random p=0.5')")
    ap.add_argument("--tasks", type=int, default=12, help="the experiment's first tasks")
    args = ap.parse_args()
    which = sum([args.hospital is not None, args.imdf, args.maze is not None, args.building > 0])
    if which != 1 or args.tasks < 1:
        ap.error("give one map (--hospital, --imdf, --maze or --building) and --tasks >= 1")
    exp = visitors.Args(
        buildings=(args.building,) if args.building else (0,),
        hospitals=(args.hospital,) if args.hospital else (),
        imdf=args.imdf, mazes=(args.maze,) if args.maze else (), tasks=args.tasks,
    )  # fmt: skip
    spec = map_suite(exp.suite())[0]
    world = visitors.place(exp, spec).world
    visitor = Visitor.parse(args.walker)
    rows: list[tuple[Any, ...]] = []
    record = guide.GuideAdvisor.record

    def counted(self: guide.GuideAdvisor, state: int, advise: bool, *rest: Any) -> Any:
        ll = self._loglik
        rows.append((
            advise, 1.0 - rest[2], self._comply[guide.SAVED], self.purposeful,
            self.holding_back, any(self.alive), model_name(int(np.argmax(ll)), len(ll)),
        ))  # fmt: skip
        return record(self, state, advise, *rest)

    guide.GuideAdvisor.record = counted  # type: ignore[method-assign,assignment]
    entry = strategies.STRATEGIES["guide"]
    count: collections.Counter[str] = collections.Counter()
    arrived = steps = 0
    for t, goal in enumerate(world.goals[: args.tasks]):
        advisor = entry.advisor(world.sim.data, AdvisorSettings(strategy="guide"))
        rows.clear()
        rec = run_episode(
            world.domain, make_explorer(visitor.walker, world.domain), advisor, int(goal),
            np.random.default_rng(t), max_steps=5000, compliance=visitor.compliance,
        )  # fmt: skip
        arrived += rec.success
        steps += rec.steps
        for advise, lost, saved, purposeful, held, alive, top in rows:
            count["decisions"] += 1
            if advise:
                count["advised"] += 1
            elif saved < guide.ADVICE_BURST:
                count["not advised, budget not full"] += 1
            elif purposeful or held or not alive:
                why = "a way of its own" if purposeful else "held back" if held else "passed all"
                count[f"budget full: {why}"] += 1
            else:
                side = "P(lost) < 1/2" if lost < 0.5 else "P(lost) >= 1/2"
                count[f"budget full: value < kappa, {side}, likeliest {top}"] += 1
    print(f"{spec.name}, {args.walker}, {args.tasks} tasks: {arrived} arrived, "
          f"{steps / args.tasks:.0f} steps a task on average\n")  # fmt: skip
    print("| decisions | count | share |\n|---|---|---|")
    for key, n in sorted(count.items(), key=lambda kv: -kv[1]):
        print(f"| {key} | {n:,} | {n / count['decisions']:.3f} |")


if __name__ == "__main__":
    main()
