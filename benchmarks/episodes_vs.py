"""The compiled episode kernels of two source trees, side by side: steps per second.

Runs ``kernel_rates`` of each tree's ``benchmarks/bench_experiments.py`` (the compiled
fixed-policy kernel with an advised random explorer, the Q-learning kernel advised and not,
the plain-Python reference loop) in a fresh process per run, alternating the trees and
swapping the order every round, and reports each figure's median and range, and the ratio
after / before of the medians. The part of ``bench_experiments.py`` that a kernel change
touches, without its minutes of ``experiment all``.

    python benchmarks/episodes_vs.py --before /tmp/before --label "commit 9b417b2" \\
        [--runs 5] [--repeats 3] [--write docs/PERFORMANCE.md --section MARKER]
"""

from __future__ import annotations

import json
import statistics
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._report import arguments, machine, write_section

ROOT = Path(__file__).resolve().parents[1]
NAMES = {
    "fixed": "fixed-policy kernel, advised random explorer + advisor (steps/s)",
    "q_advised": "Q-learning kernel, advised (steps/s)",
    "q_plain": "Q-learning kernel, not advised (steps/s)",
    "reference": "plain-Python reference loop (steps/s)",
}
CALL = (
    "import json, sys; sys.path.insert(0, '.'); "
    "from benchmarks.bench_experiments import kernel_rates; "
    "print(json.dumps(kernel_rates({repeats})))"
)


def rates(tree: Path, repeats: int) -> dict[str, float]:
    done = subprocess.run(
        [sys.executable, "-c", CALL.format(repeats=repeats)],
        cwd=tree, capture_output=True, text=True, check=True,
    )  # fmt: skip
    out: dict[str, float] = json.loads(done.stdout.strip().splitlines()[-1])
    return out


def main() -> None:
    parser = arguments(__doc__)
    parser.add_argument("--before", type=Path, required=True, help="the older source tree")
    parser.add_argument("--after", type=Path, default=ROOT, help="the newer tree (this one)")
    parser.add_argument("--label", default="before", help="what the older tree is")
    parser.add_argument("--runs", type=int, default=5, help="runs of each tree")
    parser.add_argument("--repeats", type=int, default=3, help="repeats in a run (median)")
    parser.add_argument("--write", type=Path, help="rewrite a marked section of this file")
    parser.add_argument("--section", default="episodes_vs", help="the section's marker")
    args = parser.parse_args()
    runs: dict[str, list[dict[str, float]]] = {"after": [], "before": []}
    sides = [("after", args.after.resolve()), ("before", args.before.resolve())]
    for i in range(args.runs):
        for side, tree in sides if i % 2 == 0 else sides[::-1]:
            runs[side].append(rates(tree, args.repeats))
            print(f"run {i + 1}/{args.runs} {side} done", file=sys.stderr, flush=True)
    lines = [
        f"| measurement | before ({args.label}) | after | after / before |",
        "|---|---|---|---|",
    ]
    for key, name in NAMES.items():
        cells = []
        for side in ("before", "after"):
            values = [r[key] for r in runs[side]]
            mid = statistics.median(values)
            cells.append(f"{mid / 1e6:.2f} M ({min(values) / 1e6:.2f}-{max(values) / 1e6:.2f})")
        ratio = statistics.median(r[key] for r in runs["after"]) / statistics.median(
            r[key] for r in runs["before"]
        )
        lines.append(f"| {name} | {cells[0]} | {cells[1]} | {ratio:.2f} |")
    command = " ".join(["python benchmarks/episodes_vs.py", *sys.argv[1:]])
    body = (
        f"Command: `{command}` ({args.runs} runs of each tree, alternating: medians, and the "
        f"range of the runs)\n\nMachine: {machine()}\n\n" + "\n".join(lines) + "\n"
    )
    print(body)
    if args.write:
        write_section(args.write, args.section, body)


if __name__ == "__main__":
    main()
