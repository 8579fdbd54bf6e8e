"""guide's choice of the next destination on maps of many destinations: the compiled time.

A lost explorer is led through the destinations not yet ruled out; the first of them is
chosen when a session's target is set or passed (``kernels.guide_first_of_tour``, inside a
decision): exactly up to MAX_TOUR destinations, by local search up to MAX_SEARCHED_TOUR
(``kernels.guide_searched_order``), the nearest beyond. This times that choice, already
compiled, on a generated building of 40 x 40 cells with each ``--destinations`` count, from
``--cells`` random cells each, every destination alive: the median and the largest of those
calls, so the worst a decision that changes the target adds. Then a client's worst case: a
session (``StreamGuide``, as the service runs it) fed a batch of ``--events`` events that
move onto its current target (reported beside it) and off it in turn, so that every other
event sets off a choice (a destination left is set aside, and once all are, brought back);
the batch run in
the service's slices (``batch_slice``): the events a slice and its time, median and largest::

    .venv/bin/python benchmarks/bench_tour.py
    .venv/bin/python benchmarks/bench_tour.py --destinations 40 --destinations 64 --cells 200
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app import kernels
from app.advice import guide
from app.advice.guide import GuideMap, GuideParams
from app.advice.models import AdviceTables
from app.advice.params import StrategyParams
from app.agents.experts import train_goal_priors
from app.domain.generate import generate_building_domain
from app.strategies.stream import StreamGuide
from benchmarks._report import arguments, machine


def main() -> None:
    ap = arguments(__doc__)
    ap.add_argument("--destinations", type=int, action="append", default=[],
                    help="destinations (repeat; default 8 10 11 24 40 48 49)")  # fmt: skip
    ap.add_argument("--cells", type=int, default=100, help="timed calls a map, each from a cell")
    ap.add_argument("--events", type=int, default=400, help="events of the worst-case batch")
    a = ap.parse_args()
    counts = a.destinations or [8, 10, 11, 24, 40, 48, 49]
    if a.cells < 1 or any(n < 1 for n in counts):
        ap.error("--cells and --destinations at least 1")
    print(f"Machine: {machine()}\n")
    print("| destinations | how | median | largest |\n|---|---|---|---|")
    for n in counts:
        d = generate_building_domain(40, 40, 1, n_goals=n)
        dist = GuideMap.of(d).dist
        goals = np.array(d.goals, dtype=np.int64)
        alive = np.ones(n, dtype=np.bool_)
        cells = np.random.default_rng(n).integers(d.n_states, size=a.cells)
        limits = (guide.MAX_TOUR, True, guide.MAX_SEARCHED_TOUR, guide.TOUR_ROUNDS)
        kernels.guide_first_of_tour(dist, goals, alive, True, int(cells[0]), *limits)  # compiled
        times = []
        for s in cells:
            start = time.perf_counter()
            kernels.guide_first_of_tour(dist, goals, alive, True, int(s), *limits)
            times.append(time.perf_counter() - start)
        how = (
            "exact" if n <= guide.MAX_TOUR
            else "searched" if n <= guide.MAX_SEARCHED_TOUR else "nearest"
        )  # fmt: skip
        print(
            f"| {n} | {how} | {1e3 * statistics.median(times):.3f} ms | "
            f"{1e3 * max(times):.3f} ms |",
            flush=True,
        )
    print(
        "\n| destinations | events that changed the target | events a slice | slice: median "
        "| slice: largest |\n|---|---|---|---|---|"
    )
    for n in counts:
        changed, slice_, times = worst_batch(n, a.events)
        print(
            f"| {n} | {changed} of {a.events} | {slice_} | "
            f"{1e3 * statistics.median(times):.3f} ms | {1e3 * max(times):.3f} ms |",
            flush=True,
        )


def worst_batch(n: int, events: int) -> tuple[int, int, list[float]]:
    """A batch of ``events`` events each landing on the session's target (one session makes
    it, event by event), then run by a fresh session in ``batch_slice`` slices: (the events
    after which the target changed, the slice, each slice's time)."""
    d = generate_building_domain(40, 40, 1, n_goals=n)
    prior, goal_priors = train_goal_priors(d, np.random.default_rng(0), "start", 1, 1.0)
    tables, gmap = AdviceTables.paper(prior.theta()), GuideMap.of(d, goal_priors)

    def session() -> StreamGuide:
        return StreamGuide(tables, gmap, 0.5, 50, params=GuideParams.of(StrategyParams()))

    maker, s = session(), int(d.start)
    maker.start(s)
    states, actions, nexts, changed = [], [], [], 0
    for _ in range(events):
        t = maker.target if maker.target >= 0 else 0
        goal = int(d.goals[t])
        if s == goal:  # on it: step off (leaving it rules it out)
            a = next(b for b in range(d.n_actions) if int(d.next_state[s, b]) != s)
        else:  # a report beside it, and a move onto it (a jump onto it rules nothing out)
            s, a = next(
                (int(d.next_state[goal, b]), c)
                for b in range(d.n_actions)
                for c in range(d.n_actions)
                if int(d.next_state[int(d.next_state[goal, b]), c]) == goal
                and int(d.next_state[goal, b]) != goal
            )
        s2 = int(d.next_state[s, a])
        states.append(s)
        actions.append(a)
        nexts.append(s2)
        maker.observe(s, a, s2)
        changed += maker.target != t
        s = s2
    moves = [np.array(x, dtype=np.int64) for x in (states, actions, nexts)]
    warm = session()  # compiled code loaded before the clock starts
    warm.start(int(d.start))
    warm.observe_batch(*[x[:2] for x in moves])
    timed = session()
    timed.start(int(d.start))
    step = timed.batch_slice()
    times = []
    for lo in range(0, events, step):
        part = [x[lo : lo + step] for x in moves]
        start = time.perf_counter()
        timed.observe_batch(*part)
        times.append(time.perf_counter() - start)
    return changed, step, times


if __name__ == "__main__":
    main()
