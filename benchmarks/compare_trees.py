"""Before and after, side by side: one benchmark script run from two source trees in turn.

Each run is the script of one tree (``TREE/benchmarks/SCRIPT``, which puts its own tree first
on the path), alternating after, before, before, after, after, ... (the order swaps every round)
so that the machine's drift, and any cost of coming first, falls on both. The script's markdown
rows ``| measurement | value unit | ... |`` are read and each figure is reported as the median of
its runs, with the range, and the ratio after / before of the medians. The older tree is a
checkout of an older commit (``git worktree add /tmp/before REV``).

    python benchmarks/compare_trees.py --before /tmp/before --runs 5 bench_core.py
    python benchmarks/compare_trees.py --before /tmp/before --label "commit 36317f0" \\
        --write docs/PERFORMANCE.md --section before_after_core bench_core.py
"""

from __future__ import annotations

import re
import statistics
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._report import arguments, machine, write_section

ROOT = Path(__file__).resolve().parents[1]
ROW = re.compile(r"^\|\s*([^|]+?)\s*\|\s*([0-9][0-9,]*\.?[0-9]*)\s*([^|]*?)\s*\|", re.M)


def figures(output: str) -> dict[str, tuple[float, str]]:
    """Every ``| name | number unit | ...`` row of a script's output: name -> (number, unit)."""
    return {m[1]: (float(m[2].replace(",", "")), m[3]) for m in ROW.finditer(output)}


def run(tree: Path, script: str, args: list[str]) -> dict[str, tuple[float, str]]:
    done = subprocess.run(
        [sys.executable, str(tree / "benchmarks" / script), *args],
        cwd=tree, capture_output=True, text=True, check=True,
    )  # fmt: skip
    return figures(done.stdout)


def table(runs: dict[str, list[dict[str, tuple[float, str]]]], label: str) -> str:
    names = [n for n in runs["after"][0] if all(n in r for r in runs["after"] + runs["before"])]
    lines = [
        f"| measurement | before ({label}) | after | after / before |",
        "|---|---|---|---|",
    ]
    for name in names:
        unit = runs["after"][0][name][1]
        cells = []
        for side in ("before", "after"):
            values = [r[name][0] for r in runs[side]]
            mid, low, high = statistics.median(values), min(values), max(values)
            cells.append(f"{mid:,.2f} {unit} ({low:,.2f}-{high:,.2f})")
        ratio = statistics.median(r[name][0] for r in runs["after"]) / statistics.median(
            r[name][0] for r in runs["before"]
        )
        lines.append(f"| {name} | {cells[0]} | {cells[1]} | {ratio:.2f} |")
    return "\n".join(lines)


def main() -> None:
    parser = arguments(__doc__)
    parser.add_argument("script", help="a script under benchmarks/, e.g. bench_core.py")
    parser.add_argument("script_args", nargs="*", help="its arguments (after --)")
    parser.add_argument("--before", type=Path, required=True, help="the older source tree")
    parser.add_argument("--after", type=Path, default=ROOT, help="the newer tree (this one)")
    parser.add_argument("--runs", type=int, default=5, help="runs of each tree")
    parser.add_argument("--label", default="before", help="what the older tree is")
    parser.add_argument("--write", type=Path, help="rewrite a marked section of this file")
    parser.add_argument("--section", default="before_after", help="the section's marker")
    args = parser.parse_args()
    runs: dict[str, list[dict[str, tuple[float, str]]]] = {"after": [], "before": []}
    sides = [("after", args.after), ("before", args.before)]
    for i in range(args.runs):  # the order swaps every round: the first run of a pair may be slow
        for side, tree in sides if i % 2 == 0 else sides[::-1]:
            runs[side].append(run(tree.resolve(), args.script, args.script_args))
            print(f"run {i + 1}/{args.runs} {side} done", file=sys.stderr, flush=True)
    command = " ".join(["python benchmarks/compare_trees.py", *sys.argv[1:]])
    body = (
        f"Command: `{command}` ({args.runs} runs of each tree, alternating: medians, and the "
        f"range of the runs)\n\nMachine: {machine()}\n\n{table(runs, args.label)}\n"
    )
    print(body)
    if args.write:
        write_section(args.write, args.section, body)


if __name__ == "__main__":
    main()
