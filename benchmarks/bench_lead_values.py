"""guide's lead values of one map: the compiled sweeps' wall-clock time, from any source tree.

A guide map's lead values (``GuideMap.lead``: for each destination, cell and heading the mean
moves of a walker that never turns back, led at LEAD_PRICE a piece) are the slow part of its
preparation. This times ``strategies.compiled_leads`` (``kernels.guide_lead_values``) on a
map file or a generated hospital, already compiled (one call first), the median of
``--repeats`` calls. ``--tree`` imports the project from another checkout (an older commit in
a ``git worktree``), so that two versions can be timed side by side, e.g. with farm-bench::

    .venv/bin/python benchmarks/bench_lead_values.py --hospital 5x128
    .venv/bin/python benchmarks/bench_lead_values.py --maze maps/Berlin_0_256.txt \\
        --tree /tmp/before
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

from _report import arguments, machine  # the script's own folder, whichever tree is timed


def main() -> None:
    ap = arguments(__doc__)
    ap.add_argument("--maze", type=Path, help="a map file (the project's text format)")
    ap.add_argument("--hospital", help="FLOORSxSIDE: a generated hospital (seed 1)")
    ap.add_argument("--repeats", type=int, default=3, help="timed calls")
    ap.add_argument("--tree", type=Path, default=Path(__file__).resolve().parents[1],
                    help="the source tree to import (default: this script's)")  # fmt: skip
    args = ap.parse_args()
    if (args.maze is None) == (args.hospital is None) or args.repeats < 1:
        ap.error("give one of --maze and --hospital, and --repeats >= 1")
    sys.path.insert(0, str(args.tree.resolve()))
    import numpy as np

    from app.advice.guide import GuideMap
    from app.domain.building import load_map_file
    from app.domain.floorplans import generate_floors
    from app.strategies import compiled_leads

    if args.hospital is not None:
        try:
            floors, side = (int(x) for x in args.hospital.lower().split("x"))
        except ValueError:
            ap.error(f"--hospital FLOORSxSIDE, e.g. 5x128, got {args.hospital!r}")
        domain = generate_floors(side, side, floors, np.random.default_rng(1), purpose="hospital")
    else:
        domain = load_map_file(args.maze)
    gmap = GuideMap.of(domain)
    compiled_leads(gmap.next_state, gmap.n_open, gmap.dist)  # compiled, or read from the cache
    times = []
    for _ in range(args.repeats):
        start = time.perf_counter()
        compiled_leads(gmap.next_state, gmap.n_open, gmap.dist)
        times.append(time.perf_counter() - start)
    print(f"Machine: {machine()}; tree {args.tree}\n")
    print("| map | destinations x cells | lead values (range) |\n|---|---|---|")
    print(
        f"| {domain.name} | {gmap.n_goals} x {domain.n_states:,} | "
        f"{statistics.median(times):.2f} s ({min(times):.2f}-{max(times):.2f}) |"
    )


if __name__ == "__main__":
    main()
