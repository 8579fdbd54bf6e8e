"""Table I: mean reward (1000 x success rate) of each explorer, without and with advice.

Protocol (Section V-C): each fixed-policy explorer does ``--tasks`` random one-shot tasks
(goal drawn uniformly from the map's goals, start at 'S') of at most ``--steps`` moves, once
without and once with advice (kappa 0.5). The Q-learner's row comes from the Figure 6 runs:
a task counts as solved if the learner reaches its goal in its final (5,000th) episode; the
learned greedy policy is reported beside it. 95% Wilson intervals on every success rate.

Also measured per run: advice per 100 steps, and how many failures were *trapped* in the dead
end of another goal (app/experiments/traps.py).

    python -m app experiment table1 [--tasks 200] [--experts start|anywhere|policy] ...
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from matplotlib.cm import ScalarMappable
from matplotlib.figure import Figure
from tqdm import tqdm

from app.agents.explorers import FIXED_EXPLORERS
from app.experiments.common import CommonArgs, LearningArgs, Setup, prepare, wilson
from app.experiments.mazeplot import HEAT_CMAP, draw_cells, shared_log_norm
from app.experiments.output import RunDir, header, markdown_table
from app.experiments.runs import FixedBatch, LearningBatch, run_fixed_tasks, run_learning_tasks

#: The paper's Table I (mean reward without -> with advice), quoted for comparison only.
PAPER_TABLE1: dict[str, tuple[int, int]] = {
    "random": (50, 900),
    "random-avoid": (50, 750),
    "left": (150, 750),
    "bug": (100, 800),
    "q-learning": (150, 1000),
    "optimal": (1000, 1000),
}
ROW_ORDER = ("random", "random-avoid", "left", "bug", "q-learning", "optimal")


@dataclass
class Args(CommonArgs, LearningArgs):
    """Table I arguments."""

    steps: int = 5000
    """Step limit of a one-shot task."""
    last_n: int = 500
    """A failed explorer is 'trapped' if half of its last ``last_n`` steps were spent in
    another goal's dead end."""


def learning_runs(
    args: CommonArgs, largs: LearningArgs, setup: Setup, bar: tqdm | None = None
) -> dict[bool, LearningBatch]:
    """Q-learning over every task, without and with advice (Figure 6 and Table I)."""
    return {
        advised: run_learning_tasks(setup, advised, args, largs, progress=bar)
        for advised in (False, True)
    }


def summarise(
    name: str,
    advised: bool,
    success: np.ndarray,
    batch: FixedBatch | None = None,
    learning: LearningBatch | None = None,
) -> dict[str, Any]:
    """One row: success rate with its Wilson interval, plus what the runs measured."""
    n, k = int(success.size), int(success.sum())
    lo, hi = wilson(k, n)
    row: dict[str, Any] = {
        "explorer": name,
        "advised": advised,
        "tasks": n,
        "successes": k,
        "reward": 1000.0 * k / n,
        "reward_ci_low": 1000.0 * lo,
        "reward_ci_high": 1000.0 * hi,
    }
    if batch is not None:
        failed = int(n - k)
        trapped = int((batch.trap_goal >= 0).sum())
        row |= {
            "mean_steps_when_solved": float(batch.steps[success].mean()) if k else None,
            "advice_per_100_steps": float(batch.advice_per_100.mean()),
            "benefit_per_task": float(batch.benefit.mean()),
            "failures": failed,
            "trapped": trapped,
            "trapped_share_of_failures": trapped / failed if failed else 0.0,
            "other_dead_end_share_of_steps": float(batch.other_dead_end_share.mean()),
            "failures_final_steps_without_expert_data": (
                float(batch.final_without_data[~success].mean()) if failed else None
            ),
        }
    if learning is not None:
        g = int(learning.greedy_success.sum())
        glo, ghi = wilson(g, n)
        row |= {
            "greedy_reward": 1000.0 * g / n,
            "greedy_ci_low": 1000.0 * glo,
            "greedy_ci_high": 1000.0 * ghi,
            "last100_reward": float(1000.0 * learning.success[:, -100:].mean()),
            "advice_per_100_steps": float(
                100.0 * learning.advice_count.sum() / max(1, learning.decisions.sum())
            ),
        }
    return row


def run(
    args: Args, out: RunDir, learning: dict[bool, LearningBatch] | None = None
) -> dict[str, Any]:
    """Run Table I; ``learning`` reuses Q-learning runs made with the same arguments."""
    started = time.perf_counter()
    setup = prepare(args)
    n = len(setup.goals)
    total = 2 * n * (len(FIXED_EXPLORERS) + (learning is None))
    rows: list[dict[str, Any]] = []
    task_rows: list[dict[str, Any]] = []
    with tqdm(total=total, desc="table1", unit="task", disable=not args.progress) as bar:
        batches = {
            (name, advised): run_fixed_tasks(
                setup, name, advised, args, args.steps, last_n=args.last_n, progress=bar
            )
            for name in FIXED_EXPLORERS
            for advised in (False, True)
        }
        if learning is None:
            learning = learning_runs(args, args, setup, bar)
    for name in ROW_ORDER:
        for advised in (False, True):
            if name == "q-learning":
                lb = learning[advised]
                rows.append(summarise(name, advised, lb.final_success, learning=lb))
                continue
            b = batches[name, advised]
            rows.append(summarise(name, advised, b.success, batch=b))
            for i in range(n):
                task_rows.append(
                    {
                        "explorer": name,
                        "advised": advised,
                        "task": i,
                        "goal": setup.goal_index(int(b.goals[i])),
                        "success": bool(b.success[i]),
                        "steps": int(b.steps[i]),
                        "advice_count": int(b.advice_count[i]),
                        "trapped_in_goal": int(b.trap_goal[i]),
                        "other_dead_end_share": float(b.other_dead_end_share[i]),
                    }
                )
    goal_rows = per_goal(setup, batches, learning)
    result = {
        **header("table1", args, time.perf_counter() - started),
        "goals": [list(setup.domain.cell(g)) for g in setup.domain.goals],
        "task_goals": [setup.goal_index(int(g)) for g in setup.goals],
        "rows": rows,
        "per_goal": goal_rows,
        "paper": PAPER_TABLE1,
    }
    out.json("table1", result)
    out.csv("table1", rows)
    out.csv("table1_tasks", task_rows)
    out.csv("table1_goals", goal_rows)
    out.markdown("table1", markdown(rows, args))
    out.figure("table1_failures", plot_failures(setup, batches, args))
    return result


def per_goal(
    setup: Setup,
    batches: dict[tuple[str, bool], FixedBatch],
    learning: dict[bool, LearningBatch],
) -> list[dict[str, Any]]:
    """Successes / tasks for each goal, explorer and condition."""
    out = []
    for gi, goal in enumerate(setup.domain.goals):
        row: dict[str, Any] = {
            "goal": gi,
            "cell": str(list(setup.domain.cell(goal))),
            "distance": int(setup.domain.goal_distances[gi, setup.domain.start]),
            "tasks": int((setup.goals == goal).sum()),
        }
        for name in ROW_ORDER:
            for advised in (False, True):
                if name == "q-learning":
                    success = learning[advised].final_success
                else:
                    success = batches[name, advised].success
                row[f"{name}{'+advice' if advised else ''}"] = int(
                    success[setup.goals == goal].sum()
                )
        out.append(row)
    return out


def markdown(rows: list[dict[str, Any]], args: Args) -> str:
    """Our Table I next to the paper's, with 95% intervals and the trap counts."""
    by = {(r["explorer"], r["advised"]): r for r in rows}

    def cell(r: dict[str, Any]) -> str:
        return f"{r['reward']:.0f} [{r['reward_ci_low']:.0f}, {r['reward_ci_high']:.0f}]"

    table = []
    for name in ROW_ORDER:
        off, on = by[name, False], by[name, True]
        paper = PAPER_TABLE1[name]
        trapped = "—" if "trapped" not in on else f"{on['trapped']}/{on['failures']}"
        trapped_off = "—" if "trapped" not in off else f"{off['trapped']}/{off['failures']}"
        table.append(
            [
                name,
                f"{paper[0]} → {paper[1]}",
                cell(off),
                cell(on),
                f"{on['advice_per_100_steps']:.1f}",
                trapped_off,
                trapped,
            ]
        )
    header = [
        "explorer",
        "paper",
        "ours, no advice [95% CI]",
        "ours, advised [95% CI]",
        "advice /100 steps",
        "trapped / failed (no advice)",
        "trapped / failed (advised)",
    ]
    note = (
        f"{args.tasks} tasks per explorer and condition; maze `{args.maze}`, seed {args.seed}, "
        f"kappa {args.kappa}, window {args.window}, experts `{args.experts}` "
        f"({args.per_goal} per goal), alpha0 {args.alpha0}, one-shot limit {args.steps} steps; "
        f"Q-learning: final of {args.episodes} episodes of <= {args.episode_steps} steps, "
        f"alpha {args.q_alpha}, gamma {args.q_gamma}, epsilon {args.q_epsilon}, "
        f"ties `{args.q_ties}`, advisor history kept across episodes: {args.q_keep_history}."
    )
    q = by["q-learning", True]
    q_off = by["q-learning", False]
    greedy = (
        f"Q-learning greedy policy after learning (no exploration, no advice): "
        f"{q_off['greedy_reward']:.0f} → {q['greedy_reward']:.0f}; mean reward over the last "
        f"100 episodes: {q_off['last100_reward']:.0f} → {q['last100_reward']:.0f}."
    )
    blind = ", ".join(
        f"{name} {100 * by[name, True]['failures_final_steps_without_expert_data']:.0f}%"
        for name in FIXED_EXPLORERS
        if by[name, True].get("failures_final_steps_without_expert_data") is not None
    )
    blind_note = (
        f"Advised failures: share of their final {args.last_n} steps on cells no expert "
        f"visited (theta uniform there, so no advice is possible): {blind or 'no failures'}."
    )
    parts = [markdown_table(header, table), note, greedy, blind_note]
    return "\n\n".join(parts) + "\n"


def plot_failures(setup: Setup, batches: dict[tuple[str, bool], FixedBatch], args: Args) -> Figure:
    """Where failed explorers spent their final ``last_n`` steps, without and with advice: in
    each panel the share of those steps spent in each cell, on one logarithmic scale for all
    panels (the colour bar)."""
    without_data = setup.prior.pooled_increments_.sum(axis=1) == 0
    names = [n for n in FIXED_EXPLORERS if n != "optimal"]
    shares = {
        key: b.failed_final_visits / max(1.0, b.failed_final_visits.sum())
        for key, b in batches.items()
    }
    norm = shared_log_norm([shares[name, advised] for name in names for advised in (False, True)])
    fig = Figure(figsize=(2.6 * len(names) + 1.0, 5.6), layout="constrained")
    axes = fig.subplots(2, len(names))
    for j, name in enumerate(names):
        for i, advised in enumerate((False, True)):
            failed = int((~batches[name, advised].success).sum())
            label = "advised" if advised else "no advice"
            draw_cells(axes[i, j], setup.domain, shares[name, advised], without_data=without_data,
                       title=f"{name}, {label}: {failed} failed", norm=norm)  # fmt: skip
    bar = fig.colorbar(ScalarMappable(norm=norm, cmap=HEAT_CMAP), ax=axes, shrink=0.85, pad=0.02)
    bar.set_label(f"share of the failed explorers' last {args.last_n} steps spent in the cell")
    fig.suptitle(
        f"Where failed explorers spent their last {args.last_n} steps; grey cells: no expert "
        "data; blue numbers: goals, S: the start"
    )
    return fig
