"""guide's choice of the next destination on maps of many destinations: the compiled time.

A lost explorer is led through the destinations not yet ruled out; the first of them is
chosen when a session's target is set or passed (``kernels.guide_first_of_tour``, inside a
decision): exactly up to MAX_TOUR destinations, by local search up to MAX_SEARCHED_TOUR
(``kernels.guide_searched_order``), the nearest beyond. This times that choice, already
compiled, on a generated building of 40 x 40 cells with each ``--destinations`` count, from
``--cells`` random cells each, every destination alive: the median and the largest of those
calls, so the worst a decision that changes the target adds::

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
from app.advice.guide import GuideMap
from app.domain.generate import generate_building_domain
from benchmarks._report import arguments, machine


def main() -> None:
    ap = arguments(__doc__)
    ap.add_argument("--destinations", type=int, action="append", default=[],
                    help="destinations (repeat; default 8 10 11 24 40 48 49)")  # fmt: skip
    ap.add_argument("--cells", type=int, default=100, help="timed calls a map, each from a cell")
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


if __name__ == "__main__":
    main()
