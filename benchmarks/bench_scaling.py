"""How the core's cost grows: decisions/s of the compiled form (the service's advisor) and of the
readable one against window length and maze size, and of the compiled form against the number
of moves given in one call. Writes PNG curves to docs/figures/ and a section of
docs/PERFORMANCE.md.

    .venv/bin/python benchmarks/bench_scaling.py [--repeats 3] [--write docs/PERFORMANCE.md]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.advice.advisor import Advisor  # noqa: E402
from app.advice.models import AdviceTables  # noqa: E402
from app.agents.experts import train_prior  # noqa: E402
from app.domain.generate import generate_domain  # noqa: E402
from app.domain.grid import GridDomain  # noqa: E402
from benchmarks._report import command_line, machine, median_of, write_section  # noqa: E402
from benchmarks.bench_core import compiled_rate  # noqa: E402

FIGURES = ROOT / "docs" / "figures"


def batch_rate(domain: GridDomain, tables: AdviceTables, n: int, window: int, steps: int,
               repeats: int) -> float:  # fmt: skip
    """Decisions/s of the compiled form: ``n`` explorers, ``steps`` moves each in one call."""
    return compiled_rate(tables, domain, repeats, n, steps, window)


def single_rate(domain: GridDomain, tables: AdviceTables, window: int, steps: int,
                repeats: int) -> float:  # fmt: skip
    rng = np.random.default_rng(1)
    s = rng.integers(0, domain.n_states, steps + 1).tolist()
    a = rng.integers(0, 4, steps).tolist()

    def run() -> float:
        adv = Advisor(tables, window=window)
        adv.start(s[0])
        t0 = time.perf_counter()
        for k in range(steps):
            adv.observe(s[k], a[k], s[k + 1])
        return steps / (time.perf_counter() - t0)

    return median_of(run, repeats)[0]


def plot(path: Path, x: list[int], series: dict[str, list[float]], xlabel: str, title: str) -> None:
    fig, ax = plt.subplots(figsize=(6, 3.6))
    for label, y in series.items():
        ax.plot(x, np.array(y) / 1e6, marker="o", label=label)
    ax.set_xscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("million decisions / s")
    ax.set_title(title)
    ax.set_ylim(bottom=0)
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--write", type=Path)
    args = ap.parse_args()
    FIGURES.mkdir(parents=True, exist_ok=True)
    r = args.repeats
    base = generate_domain(30, 30, seed=0, braid=0.2)
    base_tables = AdviceTables.paper(train_prior(base, np.random.default_rng(0), "policy").theta())

    windows = [10, 30, 100, 300, 1000, 3000]
    by_window = {
        "compiled, 10,000 explorers": [
            batch_rate(base, base_tables, 10_000, w, max(2 * w, 200), r) for w in windows
        ],
        "single explorer": [single_rate(base, base_tables, w, 20_000, r) for w in windows],
    }
    plot(FIGURES / "scaling_window.png", windows, by_window, "window W (pairs)",
         "Decisions/s against window length")  # fmt: skip

    sizes = [30, 60, 100, 150, 200, 300]
    by_size: dict[str, list[float]] = {"compiled, 10,000 explorers": [], "single explorer": []}
    n_states = []
    for size in sizes:
        d = generate_domain(size, size, seed=0, braid=0.2)
        t = AdviceTables.paper(train_prior(d, np.random.default_rng(0), "policy").theta())
        n_states.append(d.n_states)
        by_size["compiled, 10,000 explorers"].append(batch_rate(d, t, 10_000, 300, 600, r))
        by_size["single explorer"].append(single_rate(d, t, 300, 20_000, r))
    plot(FIGURES / "scaling_maze.png", sizes, by_size, "maze side (cells)",
         "Decisions/s against maze size (window 300)")  # fmt: skip

    counts = [1, 10, 100, 1_000, 10_000]
    by_count = {
        "compiled": [
            batch_rate(base, base_tables, max(1, 2_000_000 // (n * 100)), 300, n, r) for n in counts
        ]
    }
    plot(FIGURES / "scaling_explorers.png", counts, by_count, "moves per call",
         "Compiled decisions/s against moves given in one call (window 300)")  # fmt: skip

    def row(label: str, xs: list[int], ys: dict[str, list[float]]) -> str:
        head = f"| {label} | " + " | ".join(f"{x:,}" for x in xs) + " |"
        sep = "|---" * (len(xs) + 1) + "|"
        body = "\n".join(
            f"| {k} (M/s) | " + " | ".join(f"{v / 1e6:.2f}" for v in vals) + " |"
            for k, vals in ys.items()
        )
        return f"{head}\n{sep}\n{body}"

    body = f"""## Core scaling curves

Command: `{command_line()}` (median of {r} runs per point). Machine: {machine()}

![window](figures/scaling_window.png) ![maze](figures/scaling_maze.png)
![explorers](figures/scaling_explorers.png)

{row("window W", windows, by_window)}

{row("maze side", sizes, by_size)}

(maze sides {", ".join(f"{s}: {n:,} states" for s, n in zip(sizes, n_states, strict=True))})

{row("moves per call", counts, by_count)}
"""
    print(body)
    if args.write:
        write_section(args.write, "bench_scaling", body)


if __name__ == "__main__":
    main()
