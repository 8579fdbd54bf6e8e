"""Figure 6: a Q-learner with and without advice, reward per episode averaged over tasks.

Protocol (Section V-C): for each of ``--tasks`` random goals a fresh epsilon-greedy Q-learner
runs ``--episodes`` episodes of at most ``--episode-steps`` moves from the start (reward
1000 at its goal), once advised and once not (app/agents/qlearning.py for the rules). The
curve is the mean reward per episode over the tasks, smoothed over ``--smooth`` episodes; the
second panel shows how much advice it took (advice per 100 steps) and P(M1 | H).

    python -m app experiment figure6 [--tasks 20] [--episodes 5000] [--q-ties uniform] ...
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from tqdm import tqdm

from app.experiments.common import CommonArgs, LearningArgs, moving_average, prepare
from app.experiments.output import RunDir, header, markdown_table
from app.experiments.runs import LearningBatch
from app.experiments.table1 import learning_runs


@dataclass
class Args(CommonArgs, LearningArgs):
    """Figure 6 arguments."""

    smooth: int = 50
    """Width (episodes) of the moving average drawn."""


def first_success(b: LearningBatch) -> list[int | None]:
    """Per task, the first episode (1-based) that reached the goal, or None."""
    hit = b.success.argmax(axis=1)
    return [int(h) + 1 if b.success[i, h] else None for i, h in enumerate(hit)]


def run(args: Args, out: RunDir) -> tuple[dict[str, Any], dict[bool, LearningBatch]]:
    """Run Figure 6; also returns the runs so Table I can reuse them."""
    started = time.perf_counter()
    setup = prepare(args)
    with tqdm(
        total=2 * len(setup.goals), desc="figure6", unit="task", disable=not args.progress
    ) as bar:
        batches = learning_runs(args, args, setup, bar)
    rows: list[dict[str, Any]] = []
    for advised, b in batches.items():
        reward = 1000.0 * b.success.mean(axis=0)
        steps = b.steps.mean(axis=0)
        advice = 100.0 * b.advice_count.sum(axis=0) / np.maximum(b.decisions.sum(axis=0), 1)
        p_normal = b.p_normal_mean.mean(axis=0)
        rows += [
            {
                "advised": advised,
                "episode": e + 1,
                "reward": reward[e],
                "steps": steps[e],
                "advice_per_100_steps": advice[e],
                "p_normal": p_normal[e],
            }
            for e in range(args.episodes)
        ]
    tasks = [
        {
            "advised": advised,
            "task": i,
            "goal": setup.goal_index(int(g)),
            "first_success_episode": fs,
            "episodes_solved": int(b.success[i].sum()),
            "final_success": bool(b.success[i, -1]),
            "greedy_success": bool(b.greedy_success[i]),
            "advice_total": int(b.advice_count[i].sum()),
        }
        for advised, b in batches.items()
        for i, (g, fs) in enumerate(zip(b.goals, first_success(b), strict=True))
    ]
    summary = {
        ("advised" if advised else "no_advice"): {
            "mean_reward_all_episodes": float(1000.0 * b.success.mean()),
            "mean_reward_last_100": float(1000.0 * b.success[:, -100:].mean()),
            "tasks_ever_solved": int(b.success.any(axis=1).sum()),
            "median_first_success_episode": _median([f for f in first_success(b) if f]),
            "advice_per_100_steps": float(100.0 * b.advice_count.sum() / max(1, b.decisions.sum())),
        }
        for advised, b in batches.items()
    }
    result = {
        **header("figure6", args, time.perf_counter() - started),
        "summary": summary,
    }
    out.json("figure6", result)
    out.csv("figure6", rows)
    out.csv("figure6_tasks", tasks)
    out.markdown("figure6", markdown(summary, len(setup.goals)))
    out.figure("figure6", plot(batches, args))
    return result, batches


def _median(values: list[int]) -> float | None:
    return float(np.median(values)) if values else None


def plot(batches: dict[bool, LearningBatch], args: Args) -> Figure:
    fig = Figure(figsize=(11, 4.2), layout="constrained")
    ax_r, ax_a = fig.subplots(1, 2)
    for advised, style, colour in ((False, "-", "tab:red"), (True, ":", "tab:blue")):
        b = batches[advised]
        episodes = np.arange(1, b.success.shape[1] + 1)
        label = "advised" if advised else "no advice"
        reward = 1000.0 * b.success.mean(axis=0)
        ax_r.plot(episodes, reward, color=colour, alpha=0.25, lw=0.6, label=f"{label}, per episode")
        ax_r.plot(
            episodes,
            moving_average(reward, args.smooth),
            style,
            color=colour,
            label=f"{label}, {args.smooth}-episode mean",
        )
        ax_a.plot(
            episodes,
            moving_average(b.p_normal_mean.mean(axis=0), args.smooth),
            style,
            color=colour,
            label=f"P(M1|H), {label}",
        )
        if advised:
            advice = b.advice_count.sum(axis=0) / np.maximum(b.decisions.sum(axis=0), 1)
            ax_a.plot(
                episodes,
                moving_average(advice, args.smooth),
                "--",
                color="tab:green",
                label="advice per decision, advised",
            )
    ax_r.set(
        xlabel="episode",
        ylabel="mean reward per episode",
        ylim=(0, 1020),
        title=f"Q-learning, {len(batches[True].goals)} tasks, kappa={args.kappa}",
    )
    ax_a.set(
        xlabel="episode",
        ylabel="probability; advice per decision",
        ylim=(0, 1.02),
        title="advisor's view (mean over tasks)",
    )
    # below the axes: the curves fill any corner a legend inside could take
    for ax in (ax_r, ax_a):
        ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=2, frameon=False)
    return fig


def markdown(summary: dict[str, Any], tasks: int) -> str:
    header = ["condition", "mean reward, all episodes", "last 100 episodes",
              f"tasks ever solved (of {tasks})", "median first success (episode)",
              "advice /100 steps (advisor's decisions)"]  # fmt: skip
    rows = [
        [key.replace("_", " "), f"{v['mean_reward_all_episodes']:.0f}",
         f"{v['mean_reward_last_100']:.0f}", v["tasks_ever_solved"],
         "—" if v["median_first_success_episode"] is None
         else f"{v['median_first_success_episode']:.0f}",
         f"{v['advice_per_100_steps']:.1f}"]
        for key, v in summary.items()
    ]  # fmt: skip
    return markdown_table(header, rows) + "\n"
