"""A building's guide map, searched as the experiments search it and as the service does.

What a PUT of a map of several floors builds in its worker thread for ``guide``
(:meth:`app.advice.guide.GuideMap.of`): the BFS distances from every destination, the compass
detours to each (the building's compass: the nearest stop towards the destination's floor,
and the ride there) and the landmarks' distances; and then, timed apart, its lead values
(compiled, as the simulator and the service make them). Measured two ways on a generated hospital
(``maze generate --kind building --floors F --purpose hospital``): the numpy searches the
experiments use and the compiled ones the service
uses (``kernels.guide_distances`` and ``guide_detours``, compiled ``nogil``, so the
event loop runs while they do). The two maps are checked equal, array by array, before
anything is timed; the compiled searches are compiled (or read from numba's cache) first.
Each figure is the median of ``--repeats`` runs, the two ways in turn within each.

    .venv/bin/python benchmarks/bench_guide_map.py [--floors 5] [--side 128] [--goals 8]
        [--repeats 3] [--write docs/PERFORMANCE.md]
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app import kernels
from app.advice.guide import GuideMap
from app.domain.building import Building
from app.domain.floorplans import generate_floors
from app.service.data.domains import compiled_searches
from app.strategies import compiled_leads
from benchmarks._report import arguments, command_line, machine, write_section


def compiled(building: Building) -> GuideMap:
    return GuideMap.of(building, searches=compiled_searches, distances=kernels.guide_distances)


def main() -> None:
    ap = arguments(__doc__)
    ap.add_argument("--floors", type=int, default=5, help="floors of the hospital (2-...)")
    ap.add_argument("--side", type=int, default=128, help="rows = columns of each floor")
    ap.add_argument("--goals", type=int, default=8, help="destinations a floor")
    ap.add_argument("--repeats", type=int, default=3, help="runs of each way")
    ap.add_argument("--write", type=Path, help="rewrite this markdown file's section")
    args = ap.parse_args()
    if args.floors < 2 or args.side < 32 or args.goals < 1 or args.repeats < 1:
        ap.error("need --floors >= 2, --side >= 32, --goals >= 1 and --repeats >= 1")
    building = generate_floors(
        args.side, args.side, args.floors, np.random.default_rng(1), purpose="hospital",
        n_goals=args.goals,
    )  # fmt: skip
    _ = building.nearest_stops  # the building's own tables, made once, as a PUT has them
    plain, fast = GuideMap.of(building), compiled(building)
    for a, b in zip(plain.arrays, fast.arrays, strict=True):
        if isinstance(a, np.ndarray) and not np.array_equal(a, np.asarray(b)):
            raise SystemExit("the compiled guide map differs from the numpy one")
    got: dict[str, list[float]] = {"numpy": [], "compiled": []}
    for _ in range(args.repeats):
        for way, make in (("numpy", GuideMap.of), ("compiled", compiled)):
            start = time.perf_counter()
            make(building)
            got[way].append(time.perf_counter() - start)
    leads: list[float] = []  # the lead values, compiled (already compiled: the check above)
    compiled_leads(fast.next_state, fast.n_open, fast.dist)
    for _ in range(args.repeats):
        start = time.perf_counter()
        compiled_leads(fast.next_state, fast.n_open, fast.dist)
        leads.append(time.perf_counter() - start)
    med = {k: statistics.median(v) for k, v in got.items()}
    lead = statistics.median(leads)
    body = (
        "## A building's guide map: the numpy searches and the compiled ones\n\n"
        f"Command: `{command_line()}` (the median of {args.repeats} runs of each way, in turn)\n\n"
        f"Machine: {machine()}\n\n"
        f"Domain: a generated hospital of {args.floors} floors of {args.side} x {args.side} "
        f"(seed 1; {building.n_states:,} free cells, {len(building.goals)} destinations, "
        f"{len(building.connections)} stairs and lifts). The two maps are equal, array by "
        "array.\n\n"
        "| searches | wall-clock time (range) |\n|---|---|\n"
        f"| numpy (the experiments') | {med['numpy']:.2f} s ({min(got['numpy']):.2f}-"
        f"{max(got['numpy']):.2f}) |\n"
        f"| compiled, without the GIL (the service's PUT) | {med['compiled']:.3f} s "
        f"({min(got['compiled']):.3f}-{max(got['compiled']):.3f}) |\n\n"
        f"The compiled searches take {med['compiled'] / med['numpy']:.2f} times the numpy "
        "searches' time.\n\n"
        "Besides the searches, both build the map's lead values (`GuideMap.lead`, compiled "
        f"`kernels.guide_lead_values`, {len(building.goals)} x {building.n_states:,} x 4): "
        f"{lead:.1f} s ({min(leads):.1f}-{max(leads):.1f}).\n"
    )
    print(body)
    if args.write:
        write_section(args.write, "bench_guide_map", body)


if __name__ == "__main__":
    main()
