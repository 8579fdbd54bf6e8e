"""Figure 7: how much advice each explorer gets as the cost kappa varies.

Protocol (Section V-C): for each kappa in ``--kappa-min``..``--kappa-max`` (step
``--kappa-step``) and each explorer, ``--trajectories`` advised trajectories of at most
``--steps`` moves (random goals; a trajectory ends at its goal). The Q-learner is a fresh
learner running episodes of at most ``--episode-steps`` moves until ``--steps`` moves in
total (its first 1,000 steps of learning). Reported: advice per 100 steps (advice given at
the states it acted in / moves x 100), mean and standard deviation over the trajectories.
kappa = 0 advises at every step; above log 4 = 1.386 nats nothing is ever advised.

    python -m app experiment figure7 [--trajectories 10] [--steps 1000] ...
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from tqdm import tqdm

from app.agents.explorers import FIXED_EXPLORERS
from app.experiments.common import CommonArgs, LearningArgs, prepare, rng_for
from app.experiments.output import RunDir, header, markdown_table

EXPLORERS = (*FIXED_EXPLORERS, "q-learning")


@dataclass
class Args(CommonArgs, LearningArgs):
    """Figure 7 arguments (``--tasks`` is not used: see ``trajectories``)."""

    trajectories: int = 10
    """Advised trajectories per explorer and kappa."""
    steps: int = 1000
    """Length of a trajectory (it ends earlier at the explorer's goal)."""
    kappa_min: float = 0.0
    """Smallest kappa of the sweep."""
    kappa_max: float = 1.4
    """Largest kappa of the sweep."""
    kappa_step: float = 0.1
    """Step of the sweep."""

    def kappas(self) -> np.ndarray:
        n = round((self.kappa_max - self.kappa_min) / self.kappa_step) + 1
        return np.round(self.kappa_min + self.kappa_step * np.arange(n), 10)


def run(args: Args, out: RunDir) -> dict[str, Any]:
    started = time.perf_counter()
    setup = prepare(args, n_tasks=args.trajectories)
    kappas = args.kappas()
    if kappas.size == 0 or kappas.min() < 0:
        raise ValueError("the kappa sweep must be non-empty and >= 0")
    rate = np.zeros((len(EXPLORERS), kappas.size, args.trajectories))
    total = rate.size
    with tqdm(total=total, desc="figure7", unit="traj", disable=not args.progress) as bar:
        for e, name in enumerate(EXPLORERS):
            for k, kappa in enumerate(kappas.tolist()):
                for i, goal in enumerate(setup.goals.tolist()):
                    rng = rng_for(args.seed, "figure7", name, k, i)
                    if name == "q-learning":
                        lr = setup.sim.learning(
                            goal,
                            rng,
                            advised=True,
                            params=args.q_params(),
                            episodes=args.steps,
                            max_steps=args.episode_steps,
                            keep_history=args.q_keep_history,
                            kappa=kappa,
                            window=args.window,
                            step_budget=args.steps,
                        )
                        count, moves = lr.advice_count.sum(), lr.steps.sum()
                    else:
                        run_ = setup.sim.fixed(
                            name,
                            goal,
                            rng,
                            advised=True,
                            kappa=kappa,
                            window=args.window,
                            max_steps=args.steps,
                        )
                        count, moves = run_.advice_count, run_.steps
                    rate[e, k, i] = 100.0 * count / max(1, moves)
                    bar.update()
    rows = [
        {
            "explorer": name,
            "kappa": float(kappa),
            "advice_per_100_mean": rate[e, k].mean(),
            "advice_per_100_sd": rate[e, k].std(ddof=1) if args.trajectories > 1 else 0.0,
            **{f"trajectory_{i}": rate[e, k, i] for i in range(args.trajectories)},
        }
        for e, name in enumerate(EXPLORERS)
        for k, kappa in enumerate(kappas.tolist())
    ]
    result = {
        **header("figure7", args, time.perf_counter() - started),
        "kappas": kappas,
        "advice_per_100_mean": {name: rate[e].mean(axis=1) for e, name in enumerate(EXPLORERS)},
    }
    out.json("figure7", result)
    out.csv("figure7", rows)
    out.markdown("figure7", markdown(kappas, rate))
    out.figure("figure7", plot(kappas, rate, args))
    return result


def plot(kappas: np.ndarray, rate: np.ndarray, args: Args) -> Figure:
    fig = Figure(figsize=(7, 4.5), layout="constrained")
    ax = fig.subplots()
    for e, name in enumerate(EXPLORERS):
        mean, sd = rate[e].mean(axis=1), rate[e].std(axis=1)
        ax.plot(kappas, mean, marker="o", ms=3, label=name)
        ax.fill_between(kappas, mean - sd, mean + sd, alpha=0.12)
    ax.axvline(np.log(4), color="grey", lw=0.8, ls="--")
    ax.text(np.log(4), 95, " log 4", color="grey", fontsize=8)
    ax.set(
        xlabel="kappa (cost of one piece of advice, nats)",
        ylabel="advice per 100 steps",
        ylim=(0, 101),
        title=f"Advice vs kappa: {args.trajectories} trajectories of "
        f"{args.steps} steps per explorer and kappa",
    )
    ax.legend()
    return fig


def markdown(kappas: np.ndarray, rate: np.ndarray) -> str:
    """Mean advice per 100 steps, one row per kappa."""
    rows = [
        [f"{kappa:.2f}", *(f"{rate[e, k].mean():.1f}" for e in range(len(EXPLORERS)))]
        for k, kappa in enumerate(kappas.tolist())
    ]
    return markdown_table(["kappa", *EXPLORERS], rows) + "\n"
