"""Batches of compiled runs shared by the experiments: many tasks of one explorer, summarised.

Every task gets its own generator ``rng_for(seed, stream, explorer, advised, task)``: one-shot
tasks draw from :data:`ONE_SHOT_STREAM` (Table I and Figure 5 see the same runs), Q-learning from
:data:`LEARNING_STREAM` (Table I's Q-learning row is Figure 6's).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

from app.agents.qlearning import QLearningExplorer
from app.arrays import BoolArray, FloatArray, IntArray
from app.experiments.common import CommonArgs, LearningArgs, Setup, rng_for
from app.experiments.traps import LAST_N, dead_end_masks, other_dead_end_share, trap_goal

ONE_SHOT_STREAM = "one-shot"
LEARNING_STREAM = "learning"


@dataclass
class FixedBatch:
    """One fixed-policy explorer over the tasks, advised or not; arrays have one entry per task
    except the traces, which have one entry per step (for Figure 5)."""

    explorer: str
    advised: bool
    goals: IntArray
    success: BoolArray
    steps: IntArray
    advice_count: IntArray
    benefit: FloatArray
    trap_goal: IntArray  # -1, or the other goal whose dead end held the failed explorer
    other_dead_end_share: FloatArray
    final_without_data: FloatArray  # share of the last ``last_n`` steps on cells no expert saw
    failed_final_visits: FloatArray  # (states,) visits in the last ``last_n`` steps of failures
    p_sum: FloatArray  # sum over running tasks of P(M1 | H) at each step
    running: IntArray  # tasks still running at each step
    reached_by: IntArray  # tasks that reached their goal within t + 1 steps

    @property
    def advice_per_100(self) -> FloatArray:
        out: FloatArray = 100.0 * self.advice_count / np.maximum(self.steps, 1)
        return out


def run_fixed_tasks(
    setup: Setup,
    explorer: str,
    advised: bool,
    args: CommonArgs,
    max_steps: int,
    *,
    last_n: int = LAST_N,
    progress: tqdm | None = None,
) -> FixedBatch:
    """Every task of ``setup`` for one explorer (seed, kappa and window from ``args``), from the
    one-shot stream; ``progress`` is advanced once per task."""
    n = len(setup.goals)
    masks = dead_end_masks(setup.domain)
    without_data = setup.prior.pooled_increments_.sum(axis=1) == 0
    out = FixedBatch(
        explorer=explorer,
        advised=advised,
        goals=setup.goals.copy(),
        success=np.zeros(n, bool),
        steps=np.zeros(n, np.int64),
        advice_count=np.zeros(n, np.int64),
        benefit=np.zeros(n),
        trap_goal=np.full(n, -1, np.int64),
        other_dead_end_share=np.zeros(n),
        final_without_data=np.zeros(n),
        failed_final_visits=np.zeros(setup.domain.n_states),
        p_sum=np.zeros(max_steps),
        running=np.zeros(max_steps, np.int64),
        reached_by=np.zeros(max_steps, np.int64),
    )
    for i, goal in enumerate(setup.goals.tolist()):
        rng = rng_for(args.seed, ONE_SHOT_STREAM, explorer, advised, i)
        run = setup.sim.fixed(
            explorer, goal, rng, advised=advised, kappa=args.kappa, window=args.window,
            max_steps=max_steps,
        )  # fmt: skip
        gi = setup.goal_index(goal)
        out.success[i], out.steps[i] = run.success, run.steps
        out.advice_count[i], out.benefit[i] = run.advice_count, run.benefit
        out.trap_goal[i] = trap_goal(run.states, run.success, gi, masks, last_n)
        out.other_dead_end_share[i] = other_dead_end_share(run.states, gi, masks)
        out.final_without_data[i] = without_data[run.states[-last_n:]].mean()
        if not run.success:
            np.add.at(out.failed_final_visits, run.states[-last_n:], 1.0)
        out.p_sum[: run.steps] += run.p_normal
        out.running[: run.steps] += 1
        if run.success:
            out.reached_by[run.steps - 1 :] += 1
        if progress is not None:
            progress.update()
    return out


@dataclass
class LearningBatch:
    """Q-learning over the tasks, advised or not: arrays (tasks, episodes) unless noted."""

    advised: bool
    goals: IntArray
    success: BoolArray
    steps: IntArray
    advice_count: IntArray
    decisions: IntArray
    p_normal_mean: FloatArray
    greedy_success: BoolArray  # (tasks,): the learned greedy policy, no advice, reaches the goal

    @property
    def final_success(self) -> BoolArray:
        out: BoolArray = self.success[:, -1]
        return out


def greedy_reaches_goal(
    setup: Setup, q: FloatArray, goal: int, rng: np.random.Generator, max_steps: int
) -> bool:
    """Run the learned policy without exploration or advice (ties uniform) from the start."""
    learner = QLearningExplorer(setup.domain)
    learner.q = q
    s = setup.domain.start
    for _ in range(max_steps):
        s = int(setup.domain.next_state[s, learner.greedy_action(s, rng)])
        if s == goal:
            return True
    return False


def run_learning_tasks(
    setup: Setup,
    advised: bool,
    args: CommonArgs,
    learner: LearningArgs,
    *,
    progress: tqdm | None = None,
) -> LearningBatch:
    """Every task of ``setup`` learned from scratch by a Q-learner (``learner``'s settings;
    seed, kappa and window from ``args``), from the learning stream."""
    episodes, max_steps = learner.episodes, learner.episode_steps
    n = len(setup.goals)
    shape = (n, episodes)
    out = LearningBatch(
        advised=advised,
        goals=setup.goals.copy(),
        success=np.zeros(shape, bool),
        steps=np.zeros(shape, np.int64),
        advice_count=np.zeros(shape, np.int64),
        decisions=np.zeros(shape, np.int64),
        p_normal_mean=np.zeros(shape),
        greedy_success=np.zeros(n, bool),
    )
    for i, goal in enumerate(setup.goals.tolist()):
        rng = rng_for(args.seed, LEARNING_STREAM, "q-learning", advised, i)
        run = setup.sim.learning(
            goal, rng, advised=advised, params=learner.q_params(), episodes=episodes,
            max_steps=max_steps, keep_history=learner.q_keep_history, kappa=args.kappa,
            window=args.window,
        )  # fmt: skip
        out.success[i], out.steps[i] = run.success, run.steps
        out.advice_count[i], out.decisions[i] = run.advice_count, run.decisions
        out.p_normal_mean[i] = run.p_normal_mean
        out.greedy_success[i] = greedy_reaches_goal(setup, run.q, goal, rng, max_steps)
        if progress is not None:
            progress.update()
    return out
