"""Figure 5: P(M1 | H) over time and reward, fixed-policy explorers, advised vs not.

The same one-shot runs as Table I (same seed, same streams): for every step t, the mean of
P(M1 | H) over the tasks still running at t, and the mean reward so far, 1000 x (tasks that
reached their goal within t steps) / tasks. Without advice the advisor still watches (its
posterior is recorded) but its advice is not passed on. Curves are smoothed with a centred
moving average of ``--smooth`` steps (the paper also smooths); the CSV has the raw means.

    python -m app experiment figure5 [--tasks 20] [--steps 5000] ...
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from tqdm import tqdm

from app.agents.explorers import FIXED_EXPLORERS
from app.experiments.common import CommonArgs, moving_average, prepare
from app.experiments.output import RunDir, header, markdown_table
from app.experiments.runs import FixedBatch, run_fixed_tasks


@dataclass
class Args(CommonArgs):
    """Figure 5 arguments."""

    steps: int = 5000
    """Step limit of a one-shot task."""
    smooth: int = 50
    """Width (steps) of the moving average drawn; 1 draws the raw means."""


def curves(b: FixedBatch) -> tuple[np.ndarray, np.ndarray]:
    """(mean P(M1 | H) over running tasks, mean reward so far) per step."""
    p = np.divide(b.p_sum, b.running, out=np.full(b.p_sum.shape, np.nan), where=b.running > 0)
    reward = 1000.0 * b.reached_by / len(b.goals)
    return p, reward


def run(args: Args, out: RunDir) -> dict[str, Any]:
    started = time.perf_counter()
    setup = prepare(args)
    n = len(setup.goals)
    with tqdm(
        total=2 * n * len(FIXED_EXPLORERS), desc="figure5", unit="task", disable=not args.progress
    ) as bar:
        batches = {
            (name, advised): run_fixed_tasks(setup, name, advised, args, args.steps, progress=bar)
            for name in FIXED_EXPLORERS
            for advised in (False, True)
        }
    rows: list[dict[str, Any]] = []
    summary: dict[str, Any] = {}
    for (name, advised), b in batches.items():
        p, reward = curves(b)
        key = f"{name}{'+advice' if advised else ''}"
        summary[key] = {
            "mean_p_normal_first_300": float(np.nanmean(p[:300])),
            "mean_p_normal_all_decisions": float(b.p_sum.sum() / max(1, b.running.sum())),
            "final_reward": float(reward[-1]),
            "steps_to_half_final_reward": int(np.searchsorted(reward, reward[-1] / 2) + 1)
            if reward[-1] > 0
            else None,
        }
        rows += [
            {
                "explorer": name,
                "advised": advised,
                "step": t,
                "p_normal": p[t],
                "running": int(b.running[t]),
                "reward": reward[t],
            }
            for t in range(args.steps)
        ]
    fig = plot(batches, args)
    result = {
        **header("figure5", args, time.perf_counter() - started),
        "summary": summary,
    }
    out.json("figure5", result)
    out.csv("figure5", rows)
    out.markdown("figure5", markdown(summary))
    out.figure("figure5", fig)
    return result


def plot(batches: dict[tuple[str, bool], FixedBatch], args: Args) -> Figure:
    """Two rows (P(M1 | H), reward) by one column per explorer; solid no advice, dotted advised."""
    fig = Figure(figsize=(3.2 * len(FIXED_EXPLORERS), 6.2), layout="constrained")
    axes = fig.subplots(2, len(FIXED_EXPLORERS), sharex=True, sharey="row")
    for j, name in enumerate(FIXED_EXPLORERS):
        for advised, style, colour in ((False, "-", "tab:red"), (True, ":", "tab:blue")):
            p, reward = curves(batches[name, advised])
            label = "advised" if advised else "no advice"
            t = np.arange(1, len(p) + 1)
            axes[0, j].plot(t, moving_average(p, args.smooth), style, color=colour, label=label)
            axes[1, j].plot(t, reward, style, color=colour, label=label)
        axes[0, j].set_title(name)
        axes[1, j].set_xlabel("step")
    axes[0, 0].set_ylabel("P(M1 | H), tasks still running")
    axes[1, 0].set_ylabel("mean reward so far")
    axes[0, 0].set_ylim(0, 1.02)
    axes[1, 0].set_ylim(0, 1020)
    axes[0, 0].legend(loc="lower right")
    fig.suptitle(
        f"P(M1|H) and reward, {len(batches[FIXED_EXPLORERS[0], False].goals)} tasks, "
        f"kappa={args.kappa}, experts={args.experts}, alpha0={args.alpha0} "
        f"(P smoothed over {args.smooth} steps)"
    )
    return fig


def markdown(summary: dict[str, Any]) -> str:
    rows = []
    for name in FIXED_EXPLORERS:
        off, on = summary[name], summary[f"{name}+advice"]
        rows.append(
            [
                name,
                f"{off['mean_p_normal_first_300']:.2f} → {on['mean_p_normal_first_300']:.2f}",
                f"{off['mean_p_normal_all_decisions']:.2f} → "
                f"{on['mean_p_normal_all_decisions']:.2f}",
                f"{off['final_reward']:.0f} → {on['final_reward']:.0f}",
            ]
        )
    header = ["explorer", r"P(M1 \| H), first 300 steps", r"P(M1 \| H), all decisions", "reward"]
    return markdown_table(header, rows) + "\n\nEach cell: no advice → advised.\n"
