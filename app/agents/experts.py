"""Action priors learned from simulated experts (:mod:`app.domain.paths`) on a map.

Where the experts start is a choice the paper leaves open (docs/METHOD.md): ``"start"`` (all at the
start cell), ``"anywhere"`` (uniformly random free cells) or ``"policy"`` (the full optimal
policy of each goal, every state counted).
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from app.advice.priors import ActionPrior, GoalPriors
from app.domain.building import Domain
from app.domain.paths import TrajectorySource, expert_trajectories, optimal_policies

ExpertSource = Literal["start", "anywhere", "policy"]
EXPERT_SOURCES: tuple[str, ...] = ("start", "anywhere", "policy")


def train_prior(
    domain: Domain,
    rng: np.random.Generator,
    source: ExpertSource = "start",
    per_goal: int = 10,
    alpha0: float = 1.0,
    delta: float = 0.0,
    epsilon: float = 0.0,
) -> ActionPrior:
    """An :class:`ActionPrior` learned from simulated experts of every goal of ``domain`` (on
    a building of several floors, over its six actions: experts ride stairs and lifts)."""
    prior = ActionPrior(alpha0=alpha0, delta=delta, n_actions=domain.n_actions)
    if source == "policy":
        return prior.fit_policies(optimal_policies(domain))
    if source not in EXPERT_SOURCES:
        raise ValueError(
            f"unknown expert source {source!r}: use one of {', '.join(EXPERT_SOURCES)}"
        )
    experts = expert_trajectories(domain, rng, source, per_goal, epsilon)
    return prior.fit([e.pairs for e in experts], domain.n_states)


def train_goal_priors(
    domain: Domain,
    rng: np.random.Generator,
    source: TrajectorySource = "start",
    per_goal: int = 10,
    alpha0: float = 1.0,
) -> tuple[ActionPrior, GoalPriors]:
    """The pooled prior and the per-goal counts (goal-aware advice) from the same experts,
    each trajectory labelled with the goal it walked to, as the service's stored ``goal`` is.
    With the same ``rng`` the pooled prior is :func:`train_prior`'s (the same draws)."""
    experts = expert_trajectories(domain, rng, source, per_goal)
    pairs = [e.pairs for e in experts]
    prior = ActionPrior(alpha0=alpha0, n_actions=domain.n_actions).fit(pairs, domain.n_states)
    labels: list[int | None] = [domain.goals.index(e.goal) for e in experts]
    goal_priors = GoalPriors(domain.n_states, domain.goals, alpha0, domain.n_actions)
    goal_priors.add(pairs, labels)
    return prior, goal_priors
