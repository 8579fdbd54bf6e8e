"""Ablations: Table I's advised rows as one setting at a time moves away from the defaults.

Settings varied (everything else at the defaults): alpha0, the expert source, expert
trajectories per goal, kappa, the window W; for the Q-learner also the tie rule, whether the
advisor's history is kept across episodes, epsilon and its step size. Without advice the
fixed-policy explorers do not depend on any of these (the advisor only watches, and every
task has its own random stream), so their no-advice row is run once. Q-learning is costlier
(``--episodes`` x ``--episode-steps`` per task), so it uses ``q_tasks`` tasks.

    python -m app experiment ablations [--tasks 200]
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Any

from tqdm import tqdm

from app.agents.explorers import FIXED_EXPLORERS
from app.experiments.common import prepare
from app.experiments.difficulty import prior_reach
from app.experiments.output import RunDir, header, markdown_table
from app.experiments.runs import run_fixed_tasks, run_learning_tasks
from app.experiments.table1 import Args as Table1Args
from app.experiments.table1 import summarise

#: (setting, values) varied one at a time for the fixed-policy explorers.
FIXED_GRID: tuple[tuple[str, tuple[Any, ...]], ...] = (
    ("alpha0", (0.1, 1.0, 10.0, 100.0)),
    ("experts", ("start", "anywhere", "policy")),
    ("per_goal", (1, 10, 50)),
    ("kappa", (0.0, 0.25, 0.5, 1.0)),
    ("window", (30, 100, 300, 1000)),
)
#: ... and for the Q-learner.
LEARNING_GRID: tuple[tuple[str, tuple[Any, ...]], ...] = (
    ("q_ties", ("advice", "uniform")),
    ("q_keep_history", (True, False)),
    ("q_epsilon", (0.05, 0.1, 0.2)),
    ("q_alpha", (0.1, 0.5)),
    ("experts", ("start", "anywhere", "policy")),
    ("alpha0", (1.0, 10.0)),
)
#: settings that change what the Q-learner does without advice
UNADVISED_Q_SETTINGS = ("q_epsilon", "q_alpha")


@dataclass
class Args(Table1Args):
    """Ablation arguments: Table I's, with more tasks."""

    tasks: int = 200
    """Tasks per fixed-policy explorer and setting."""
    q_tasks: int = 20
    """Tasks per Q-learning setting."""


def fixed_rows(args: Args, bar: tqdm) -> list[dict[str, Any]]:
    rows = []
    base = prepare(args)
    for name in FIXED_EXPLORERS:
        b = run_fixed_tasks(base, name, False, args, args.steps, last_n=args.last_n, progress=bar)
        rows.append({"setting": "no advice", "value": "", **summarise(name, False, b.success, b)})
    for setting, values in FIXED_GRID:
        for value in values:
            a = replace(args, **{setting: value})
            setup = prepare(a)
            reach = prior_reach(setup.tables.theta, setup.prior.summary()["states_with_data"], a)
            for name in FIXED_EXPLORERS:
                b = run_fixed_tasks(setup, name, True, a, a.steps, last_n=a.last_n, progress=bar)
                rows.append(
                    {
                        "setting": setting,
                        "value": value,
                        **summarise(name, True, b.success, b),
                        "states_with_expert_data": reach["states_with_expert_data"],
                        "advisable_states": reach["advisable_states"],
                    }
                )
    return rows


def learning_rows(args: Args, bar: tqdm) -> list[dict[str, Any]]:
    rows = []
    for setting, values in LEARNING_GRID:
        for value in values:
            a = replace(args, tasks=args.q_tasks, **{setting: value})
            setup = prepare(a)
            # without advice only where the setting changes the unadvised learner, plus once
            # for the defaults
            new_unadvised = setting in UNADVISED_Q_SETTINGS and value != getattr(args, setting)
            first = setting == LEARNING_GRID[0][0] and value == LEARNING_GRID[0][1][0]
            conditions = (False, True) if new_unadvised or first else (True,)
            for advised in conditions:
                lb = run_learning_tasks(setup, advised, a, a, progress=bar)
                default = setting == LEARNING_GRID[0][0]
                rows.append(
                    {
                        "setting": setting if advised else "no advice",
                        "value": value
                        if advised
                        else ("defaults" if default else f"{setting}={value}"),
                        **summarise("q-learning", advised, lb.final_success, learning=lb),
                    }
                )
    return rows


def run(args: Args, out: RunDir) -> dict[str, Any]:
    started = time.perf_counter()
    n_fixed = len(FIXED_EXPLORERS) * args.tasks * (1 + sum(len(v) for _, v in FIXED_GRID))
    n_q = args.q_tasks * (
        sum(len(v) for _, v in LEARNING_GRID)
        + sum(len(v) - 1 for k, v in LEARNING_GRID if k in UNADVISED_Q_SETTINGS)
        + 1
    )
    with tqdm(total=n_fixed + n_q, desc="ablations", unit="task", disable=not args.progress) as bar:
        fixed = fixed_rows(args, bar)
        learning = learning_rows(args, bar)
    result = {
        **header("ablations", args, time.perf_counter() - started),
        "fixed": fixed,
        "learning": learning,
    }
    out.json("ablations", result)
    out.csv("ablations_fixed", fixed)
    out.csv("ablations_learning", learning)
    out.markdown("ablations", markdown(fixed, learning, args))
    return result


def _ci(r: dict[str, Any]) -> str:
    return f"{r['reward']:.0f} [{r['reward_ci_low']:.0f}, {r['reward_ci_high']:.0f}]"


def markdown(fixed: list[dict[str, Any]], learning: list[dict[str, Any]], args: Args) -> str:
    keys: dict[tuple[str, str], dict[str, dict[str, Any]]] = {}
    for r in fixed:
        keys.setdefault((r["setting"], str(r["value"])), {})[r["explorer"]] = r
    header = [
        "setting",
        "value",
        *FIXED_EXPLORERS,
        "advice /100 (random)",
        "trapped / failed (all)",
        "advisable states (with expert data)",
    ]
    table = []
    for (setting, value), by in keys.items():
        r0 = by["random"]
        reach = (
            f"{r0['advisable_states']} ({r0['states_with_expert_data']})"
            if "advisable_states" in r0
            else ""
        )
        trapped = sum(r["trapped"] for r in by.values())
        failed = sum(r["failures"] for r in by.values())
        table.append(
            [
                setting,
                value,
                *(_ci(by[n]) for n in FIXED_EXPLORERS),
                f"{by['random']['advice_per_100_steps']:.1f}",
                f"{trapped}/{failed}",
                reach,
            ]
        )
    q_header = [
        "setting",
        "value",
        "final episode [95% CI]",
        "greedy policy",
        "last 100 episodes",
        "advice /100 steps",
    ]
    q_table = [
        [
            r["setting"],
            r["value"],
            _ci(r),
            f"{r['greedy_reward']:.0f}",
            f"{r['last100_reward']:.0f}",
            f"{r['advice_per_100_steps']:.1f}",
        ]
        for r in learning
    ]
    return (
        f"Fixed-policy explorers, advised, {args.tasks} tasks each (mean reward [95% Wilson "
        f"CI]); one setting changed at a time from: experts `{args.experts}`, {args.per_goal} "
        f"per goal, alpha0 {args.alpha0}, kappa {args.kappa}, window {args.window}.\n\n"
        + markdown_table(header, table)
        + "\n\n(The no-advice row's advice column is what the advisor would have advised. "
        "Advisable states: KL[theta_s || uniform] >= kappa, the only states where advice can "
        "ever be given; see app/experiments/difficulty.py.)"
        + f"\n\nQ-learning, {args.q_tasks} tasks each, {args.episodes} episodes of <= "
        f"{args.episode_steps} steps; advised unless marked.\n\n"
        + markdown_table(q_header, q_table)
        + "\n"
    )
