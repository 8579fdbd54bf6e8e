"""How hard the maze is without advice, computed exactly where possible.

* random and random-avoid walkers are Markov chains: with goal ``g`` absorbing and ``Q`` the
  transitions among the other states, P(reach g within T moves) = 1 - (Q^T 1)[start] and the
  expected number of moves is ((I - Q)^-1 1)[start]. Exact, no sampling.
* the wall follower is deterministic once its first heading is drawn: all 4 headings are run.
* the bug's only randomness is in ties and escapes: ``--tasks`` simulated runs per goal.

Averaged over the goals (tasks draw goals uniformly) these are the expected no-advice rows of
Table I; the simulated Table I should agree within its intervals.

    python -m app experiment difficulty [--maze FILE] [--steps 5000]
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from app.agents.explorers import LeftExplorer
from app.arrays import FloatArray
from app.domain.grid import GridDomain
from app.experiments.common import CommonArgs, prepare, rng_for
from app.experiments.output import RunDir, header, markdown_table
from app.experiments.traps import dead_end_masks


@dataclass
class Args(CommonArgs):
    """Difficulty arguments (``--tasks``: simulated bug runs per goal)."""

    steps: int = 5000
    """Step limit of a one-shot task."""
    episode_steps: int = 200
    """Step limit of a Q-learning episode (the random walker's chance within it is shown)."""


def walker_weights(domain: GridDomain, avoid_walls: bool) -> FloatArray:
    """P(action | state) of the random walker (``avoid_walls``: random-avoid), (S, 4)."""
    n = domain.n_states
    weights = domain.open_moves.astype(np.float64) if avoid_walls else np.ones((n, 4))
    out: FloatArray = weights / weights.sum(axis=1, keepdims=True)
    return out


def hitting(domain: GridDomain, weights: FloatArray, goal: int, steps: int) -> tuple[float, float]:
    """(P(reach ``goal`` from the start within ``steps`` moves), expected moves to reach it).

    The probability sums the mass absorbed at each move (all terms positive, so small
    probabilities keep their precision); the expectation solves (I - Q) h = 1.
    """
    n = domain.n_states
    src = np.repeat(np.arange(n), 4)
    dst = domain.next_state.ravel()
    w = weights.ravel()
    v = np.zeros(n)
    v[domain.start] = 1.0
    hit = 0.0
    for _ in range(steps):
        v = np.bincount(dst, weights=v[src] * w, minlength=n).astype(np.float64)
        hit += v[goal]
        v[goal] = 0.0
    p = np.zeros((n, n))
    np.add.at(p, (src, dst), w)
    keep = np.arange(n) != goal
    q = p[np.ix_(keep, keep)]
    h = np.linalg.solve(np.eye(n - 1) - q, np.ones(n - 1))
    return float(hit), float(h[int(np.flatnonzero(keep).tolist().index(domain.start))])


def left_success(domain: GridDomain, goal: int, steps: int) -> float:
    """Share of the 4 first headings with which the wall follower reaches ``goal``."""
    wins = 0
    rng = np.random.default_rng(0)  # unused by the wall follower's own rule
    for heading in range(4):
        walker = LeftExplorer(domain)
        walker.reset(goal, rng)
        walker.heading = heading
        s = domain.start
        for _ in range(steps):
            a = walker.policy(s, rng)
            s2 = int(domain.next_state[s, a])
            walker.observe(s, a, s2)
            s = s2
            if s == goal:
                wins += 1
                break
    return wins / 4


def run(args: Args, out: RunDir) -> dict[str, Any]:
    started = time.perf_counter()
    setup = prepare(args, n_tasks=1)
    d = setup.domain
    walkers = {"random": walker_weights(d, False), "random-avoid": walker_weights(d, True)}
    masks = dead_end_masks(d)
    rows: list[dict[str, Any]] = []
    for gi, goal in enumerate(d.goals):
        row: dict[str, Any] = {
            "goal": gi,
            "cell": str(list(d.cell(goal))),
            "distance": int(d.goal_distances[gi, d.start]),
            "dead_end_cells": int(masks[gi].sum()),
        }
        for name, w in walkers.items():
            prob, expected = hitting(d, w, goal, args.steps)
            row[f"{name}_p_success"] = prob
            row[f"{name}_expected_steps"] = expected
        # a Q-learner acts as the random walker until its first reward (Q = 0, ties uniform)
        row["random_p_in_episode"] = hitting(d, walkers["random"], goal, args.episode_steps)[0]
        row["left_p_success"] = left_success(d, goal, args.steps)
        bug = [
            setup.sim.fixed(
                "bug",
                goal,
                rng_for(args.seed, "difficulty", gi, i),
                advised=False,
                max_steps=args.steps,
            ).success
            for i in range(args.tasks)
        ]
        row["bug_p_success"] = float(np.mean(bug))
        rows.append(row)
    degree = d.open_moves.sum(axis=1)
    edges = int(d.open_moves.sum()) // 2
    maze = {
        "shape": d.shape,
        "states": d.n_states,
        "dead_ends": int((degree == 1).sum()),
        "junctions": int((degree >= 3).sum()),
        "independent_loops": edges - d.n_states + 1,
        "goals": len(d.goals),
    }
    prior = prior_reach(setup.tables.theta, setup.prior.summary()["states_with_data"], args)
    expected_rows = {
        name: 1000.0 * float(np.mean([r[f"{name}_p_success"] for r in rows]))
        for name in ("random", "random-avoid", "left", "bug")
    }
    result = {
        **header("difficulty", args, time.perf_counter() - started),
        "maze": maze,
        "prior": prior,
        "expected_reward_without_advice": expected_rows,
        "goals": rows,
    }
    out.json("difficulty", result)
    out.csv("difficulty", rows)
    out.markdown("difficulty", markdown(rows, maze, expected_rows, args) + prior_note(prior))
    return result


def prior_reach(theta: FloatArray, with_data: int, args: CommonArgs) -> dict[str, Any]:
    """Where advice is possible at all. P(A | s, H) mixes theta_s and uniform, and KL is
    convex in its second argument, so KL[theta_s || P(A | s, H)] <= KL[theta_s || uniform]:
    a state with KL[theta_s || uniform] < kappa is never advised, whatever the explorer does."""
    kl_uniform = (theta * np.log(theta * theta.shape[1])).sum(axis=1)
    return {
        "experts": args.experts,
        "per_goal": args.per_goal,
        "alpha0": args.alpha0,
        "kappa": args.kappa,
        "states": int(theta.shape[0]),
        "states_with_expert_data": int(with_data),
        "advisable_states": int((kl_uniform >= args.kappa).sum()),
        "mean_kl_theta_uniform": float(kl_uniform.mean()),
    }


def prior_note(prior: dict[str, Any]) -> str:
    return (
        f"\nPrior (experts `{prior['experts']}`, {prior['per_goal']} per goal, alpha0 "
        f"{prior['alpha0']}): {prior['states_with_expert_data']}/{prior['states']} states have "
        f"expert data; advice is possible (KL[theta_s || uniform] >= kappa = {prior['kappa']}) "
        f"in {prior['advisable_states']} of them.\n"
    )


def markdown(
    rows: list[dict[str, Any]], maze: dict[str, Any], expected: dict[str, float], args: Args
) -> str:
    header = [
        "goal",
        "cell",
        "BFS distance",
        "dead-end cells",
        "random P",
        "random E[steps]",
        "random-avoid P",
        "random-avoid E[steps]",
        "left P",
        "bug P",
        f"random P in {args.episode_steps}",
    ]
    table = [
        [
            r["goal"],
            r["cell"],
            r["distance"],
            r["dead_end_cells"],
            f"{r['random_p_success']:.3g}",
            f"{r['random_expected_steps']:.0f}",
            f"{r['random-avoid_p_success']:.3g}",
            f"{r['random-avoid_expected_steps']:.0f}",
            f"{r['left_p_success']:.2f}",
            f"{r['bug_p_success']:.2f}",
            f"{r['random_p_in_episode']:.1e}",
        ]
        for r in rows
    ]
    summary = ", ".join(f"{k} {v:.0f}" for k, v in expected.items())
    return (
        markdown_table(header, table)
        + f"\n\nP: probability of reaching the goal within {args.steps} moves (exact for random "
        f"and random-avoid, all 4 first headings for left, {args.tasks} runs per goal for bug); "
        f"last column: the same for the random walker within one Q-learning episode, which is "
        f"how a Q-learner without advice acts until its first reward. "
        f"Expected Table I reward without advice, goals uniform: {summary}.\n\n"
        f"Maze: {maze['shape'][0]}x{maze['shape'][1]}, {maze['states']} free cells, "
        f"{maze['dead_ends']} dead ends, {maze['junctions']} junctions, "
        f"{maze['independent_loops']} independent loops.\n"
    )
