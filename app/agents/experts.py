"""Simulated experts: optimal (and optionally epsilon-noisy) agents solving each goal.

The advisor learns its prior from these (Section V-B: "expert trajectories from agents moving
towards each of the eight goals"). Where they start is a choice the paper leaves open
(METHOD.md): ``"start"`` (all at the start cell), ``"anywhere"`` (uniformly random free
cells) or ``"policy"`` (the full optimal policy of each goal, every state counted).
"""

from __future__ import annotations

from typing import Literal

import numpy as np
import numpy.typing as npt

from app.advice.goals import GoalPriors
from app.advice.priors import ActionPrior
from app.domain.grid import N_ACTIONS, GridDomain

ExpertSource = Literal["start", "anywhere", "policy"]
EXPERT_SOURCES: tuple[str, ...] = ("start", "anywhere", "policy")
IntArray = npt.NDArray[np.int64]
FloatArray = npt.NDArray[np.float64]


def optimal_actions(domain: GridDomain, goal: int) -> npt.NDArray[np.bool_]:
    """``out[s, a]``: action ``a`` lies on a shortest path from ``s`` to ``goal``.

    The goal itself is terminal (no action is optimal there).
    """
    dist = domain.distances_to(goal)
    nxt = dist[domain.next_state]  # distance after each move
    out: npt.NDArray[np.bool_] = (nxt == dist[:, None] - 1) & (dist[:, None] > 0)
    return out


def optimal_policy(domain: GridDomain, goal: int) -> FloatArray:
    """pi*(s, a): uniform over the optimal actions (ties all count, METHOD.md); 0 at the goal."""
    opt = optimal_actions(domain, goal).astype(np.float64)
    n = opt.sum(axis=1, keepdims=True)
    out: FloatArray = np.divide(opt, n, out=np.zeros_like(opt), where=n > 0)
    return out


def optimal_policies(domain: GridDomain) -> FloatArray:
    """One optimal policy per goal, shape (goals, states, 4)."""
    return np.stack([optimal_policy(domain, g) for g in domain.goals])


def expert_trajectory(
    domain: GridDomain,
    start: int,
    goal: int,
    rng: np.random.Generator,
    epsilon: float = 0.0,
    max_steps: int = 10_000,
) -> IntArray:
    """(state, action) pairs of an expert from ``start`` to ``goal``: a shortest path with
    random tie-breaks; with probability ``epsilon`` per step a uniformly random move instead."""
    opt = optimal_actions(domain, goal)
    s = start
    pairs: list[tuple[int, int]] = []
    while s != goal and len(pairs) < max_steps:
        if epsilon > 0 and rng.random() < epsilon:
            a = int(rng.integers(N_ACTIONS))
        else:
            choices = np.flatnonzero(opt[s])
            a = int(choices[rng.integers(len(choices))])
        pairs.append((s, a))
        s = int(domain.next_state[s, a])
    return np.array(pairs, dtype=np.int64).reshape(-1, 2)


def expert_trajectories(
    domain: GridDomain,
    rng: np.random.Generator,
    source: Literal["start", "anywhere"] = "start",
    per_goal: int = 10,
    epsilon: float = 0.0,
) -> list[IntArray]:
    """``per_goal`` expert trajectories to each goal, starting at the start cell or anywhere."""
    if source not in ("start", "anywhere"):
        raise ValueError(f"source must be 'start' or 'anywhere' for trajectories, got {source!r}")
    if per_goal < 1:
        raise ValueError(f"per_goal must be at least 1, got {per_goal}")
    if not 0.0 <= epsilon < 1.0:
        raise ValueError(f"epsilon must be in [0, 1), got {epsilon}")
    out = []
    for goal in domain.goals:
        for _ in range(per_goal):
            start = domain.start if source == "start" else int(rng.integers(domain.n_states))
            out.append(expert_trajectory(domain, start, goal, rng, epsilon))
    return out


def train_prior(
    domain: GridDomain,
    rng: np.random.Generator,
    source: ExpertSource = "start",
    per_goal: int = 10,
    alpha0: float = 1.0,
    delta: float = 0.0,
    epsilon: float = 0.0,
) -> ActionPrior:
    """An :class:`ActionPrior` learned from simulated experts of every goal of ``domain``."""
    prior = ActionPrior(alpha0=alpha0, delta=delta)
    if source == "policy":
        return prior.fit_policies(optimal_policies(domain))
    if source not in EXPERT_SOURCES:
        raise ValueError(
            f"unknown expert source {source!r}: use one of {', '.join(EXPERT_SOURCES)}"
        )
    trajectories = expert_trajectories(domain, rng, source, per_goal, epsilon)
    return prior.fit(trajectories, domain.n_states)


def train_goal_priors(
    domain: GridDomain,
    rng: np.random.Generator,
    source: Literal["start", "anywhere"] = "start",
    per_goal: int = 10,
    alpha0: float = 1.0,
) -> tuple[ActionPrior, GoalPriors]:
    """The pooled prior and the per-goal counts (goal-aware advice) from the same experts.

    With the same ``rng`` the pooled prior is :func:`train_prior`'s: the trajectories are
    drawn in the same order (``per_goal`` for each goal in turn), and each is labelled with
    the goal it was drawn for.
    """
    trajectories = expert_trajectories(domain, rng, source, per_goal)
    labels: list[int | None] = [g for g in range(len(domain.goals)) for _ in range(per_goal)]
    prior = ActionPrior(alpha0=alpha0).fit(trajectories, domain.n_states)
    goal_priors = GoalPriors(domain.n_states, domain.goals, alpha0).add(trajectories, labels)
    return prior, goal_priors
