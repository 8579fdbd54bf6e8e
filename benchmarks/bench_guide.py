"""guide's compiled batch against the paper's rule: CPU time a decision, in process.

What a service runs for a websocket or REST batch (``StreamGuide.observe_batch`` and
``StreamAdvisor.observe_batch``, one compiled call each), on generated buildings of two sizes
with 1, 2, 4 and 8 destinations: 500-event batches of one random walk, ``--batches`` of them
per run, the median of ``--repeats`` runs in CPU time (this machine's other work does not
count). The per-destination figure is the slope between 1 and 8 destinations. This is the
arithmetic behind ``bench_buildings.py``'s guide / paper websocket ratio (target >= 0.5),
without the sockets, JSON and the rest of a message around it.

    .venv/bin/python benchmarks/bench_guide.py [--repeats 7] [--write docs/PERFORMANCE.md]
    python benchmarks/compare_trees.py --before /tmp/before --runs 5 bench_guide.py
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.advice.advisor import Advisor
from app.advice.guide import GuideMap, GuideParams
from app.advice.models import AdviceTables
from app.agents.experts import train_goal_priors
from app.domain.building import Domain
from app.domain.generate import generate_building_domain
from app.strategies.stream import StreamAdvisor, StreamGuide
from benchmarks._report import arguments, command_line, machine, median_of, write_section

BATCH = 500
SIDES = (64, 256)
GOALS = (1, 2, 4, 8)

Batch = tuple[np.ndarray, np.ndarray, np.ndarray]


def walk_batches(domain: Domain, rng: np.random.Generator, n: int) -> list[Batch]:
    """``n`` consecutive 500-event batches of one random walk from the start (over the
    domain's actions)."""
    out = []
    s = domain.start
    for _ in range(n):
        actions = rng.integers(0, domain.n_actions, BATCH)
        states = np.empty(BATCH, dtype=np.int64)
        nexts = np.empty(BATCH, dtype=np.int64)
        for i, a in enumerate(actions.tolist()):
            states[i] = s
            s = int(domain.next_state[s, a])
            nexts[i] = s
        out.append((states, actions.astype(np.int64), nexts))
    return out


def per_decision(
    domain: Domain, batches: list[Batch], advisor_of: Callable[[], Advisor], repeats: int
) -> float:
    """Median CPU microseconds a decision over ``repeats`` runs of every batch in turn, by a
    new advisor of ``advisor_of`` each run."""

    def run() -> float:
        adv = advisor_of()
        adv.start(domain.start)
        adv.observe_batch(*batches[0])  # compiled code loaded before the clock starts
        t0 = time.process_time()
        for b in batches[1:]:
            adv.observe_batch(*b)
        return (time.process_time() - t0) / (BATCH * (len(batches) - 1)) * 1e6

    return median_of(run, repeats)[0]


def main() -> None:
    ap = arguments(__doc__)
    ap.add_argument("--repeats", type=int, default=7, help="runs of each figure (the median)")
    ap.add_argument("--batches", type=int, default=40, help="500-event batches a run")
    ap.add_argument("--write", type=Path, help="rewrite this markdown file's guide section")
    args = ap.parse_args()
    params = GuideParams.of()
    rows = []
    for side in SIDES:
        costs = {}
        for n_goals in GOALS:
            domain = generate_building_domain(side, side, 3, n_goals=n_goals)
            rng = np.random.default_rng(0)
            prior, goals = train_goal_priors(domain, rng, "start", 3, 1.0)
            tables = AdviceTables.paper(prior.theta())
            gmap = GuideMap.of(domain, goals)
            batches = walk_batches(domain, rng, args.batches + 1)
            costs[n_goals] = per_decision(
                domain, batches, partial(StreamGuide, tables, gmap, params=params),
                args.repeats,
            )  # fmt: skip
            rows.append((f"guide, {side} x {side}, destinations: {n_goals}",
                         f"{costs[n_goals]:.3f} us a decision", ""))  # fmt: skip
            if n_goals == GOALS[-1]:
                paper = per_decision(domain, batches, partial(StreamAdvisor, tables), args.repeats)
                rows.append((f"paper's rule, {side} x {side}, destinations: {n_goals}",
                             f"{paper:.3f} us a decision", ""))  # fmt: skip
        slope = (costs[GOALS[-1]] - costs[GOALS[0]]) / (GOALS[-1] - GOALS[0])
        rows.append((f"guide, {side} x {side}: each destination more",
                     f"{slope:.3f} us a decision", ""))  # fmt: skip
    table = "| measurement | result | note |\n|---|---|---|\n" + "\n".join(
        f"| {a} | {b} | {c} |" for a, b, c in rows
    )
    body = (
        f"### guide's compiled batch, a decision\n\nCommand: `{command_line()}` (CPU time, "
        f"median of {args.repeats} runs of {args.batches} batches of {BATCH} events; random "
        f"walks on generated buildings, seed 3; guide's default parameters)\n\n"
        f"Machine: {machine()}\n\n{table}\n"
    )
    print(body)
    if args.write:
        write_section(args.write, "bench_guide", body)


if __name__ == "__main__":
    main()
