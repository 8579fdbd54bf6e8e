"""Shortest paths on a map, and the simulated experts that walk them.

What the building knows of its own map: from any cell, which moves lie on a shortest path to a
destination. Simulated experts (Section V-B: "expert trajectories from agents moving towards
each of the eight goals") walk such paths; where they start is a choice the paper leaves open
(docs/METHOD.md): at the start cell (``"start"``) or at uniformly random free cells
(``"anywhere"``). The service learns a new domain's prior from them; the experiments and the
``train`` command do too (:mod:`app.agents.experts`).

In a building of several floors (:class:`~app.domain.building.Building`) a shortest path is one
of the fewest moves of time: a ride on a stair or a lift takes its ``durations`` (so experts
take the lift where it saves time, the stairs for one floor where they are quicker), every
other action one.
"""

from __future__ import annotations

from typing import Literal, NamedTuple

import numpy as np

from app.arrays import BoolArray, FloatArray, IntArray
from app.domain.building import Building, Domain

TrajectorySource = Literal["start", "anywhere"]
TRAJECTORY_SOURCES: tuple[str, ...] = ("start", "anywhere")


class ExpertTrajectory(NamedTuple):
    """An expert's walk to ``goal``: (state, action) pairs, shape (T, 2)."""

    goal: int
    pairs: IntArray


def optimal_actions(domain: Domain, goal: int) -> BoolArray:
    """``out[s, a]``: action ``a`` lies on a shortest path from ``s`` to ``goal`` (in a
    building, a quickest one: the module docstring).

    The goal itself is terminal (no action is optimal there).
    """
    if isinstance(domain, Building):
        time, cost = domain.times_to(goal), domain.durations
    else:  # every move takes one
        time, cost = domain.distances_to(goal), np.ones_like(domain.next_state)
    after = time[domain.next_state] + cost  # time to the goal through each action
    out: BoolArray = (after == time[:, None]) & (time[:, None] > 0)
    return out


def optimal_policy(domain: Domain, goal: int) -> FloatArray:
    """pi*(s, a): uniform over the optimal actions (ties all count: docs/METHOD.md); 0 at the
    goal."""
    opt = optimal_actions(domain, goal).astype(np.float64)
    n = opt.sum(axis=1, keepdims=True)
    out: FloatArray = np.divide(opt, n, out=np.zeros_like(opt), where=n > 0)
    return out


def optimal_policies(domain: Domain) -> FloatArray:
    """One optimal policy per goal, shape (goals, states, actions)."""
    return np.stack([optimal_policy(domain, g) for g in domain.goals])


def expert_trajectory(
    domain: Domain,
    start: int,
    goal: int,
    rng: np.random.Generator,
    epsilon: float = 0.0,
    max_steps: int = 10_000,
    optimal: BoolArray | None = None,
) -> IntArray:
    """(state, action) pairs of an expert from ``start`` to ``goal``: a shortest path with
    random tie-breaks; with probability ``epsilon`` per step a uniformly random move instead.
    ``optimal``: :func:`optimal_actions` of ``goal``, if already known."""
    opt = optimal_actions(domain, goal) if optimal is None else optimal
    s = start
    pairs: list[tuple[int, int]] = []
    while s != goal and len(pairs) < max_steps:
        if epsilon > 0 and rng.random() < epsilon:
            a = int(rng.integers(domain.n_actions))
        else:
            choices = np.flatnonzero(opt[s])
            a = int(choices[rng.integers(len(choices))])
        pairs.append((s, a))
        s = int(domain.next_state[s, a])
    return np.array(pairs, dtype=np.int64).reshape(-1, 2)


def expert_trajectories(
    domain: Domain,
    rng: np.random.Generator,
    source: TrajectorySource = "start",
    per_goal: int = 10,
    epsilon: float = 0.0,
) -> list[ExpertTrajectory]:
    """``per_goal`` expert trajectories to each goal in turn, starting at the start cell or
    anywhere, each with the goal it walked to."""
    if source not in TRAJECTORY_SOURCES:
        raise ValueError(f"source must be 'start' or 'anywhere' for trajectories, got {source!r}")
    if per_goal < 1:
        raise ValueError(f"per_goal must be at least 1, got {per_goal}")
    if not 0.0 <= epsilon < 1.0:
        raise ValueError(f"epsilon must be in [0, 1), got {epsilon}")
    out = []
    for goal in domain.goals:
        opt = optimal_actions(domain, goal)
        for _ in range(per_goal):
            start = domain.start if source == "start" else int(rng.integers(domain.n_states))
            pairs = expert_trajectory(domain, start, goal, rng, epsilon, optimal=opt)
            out.append(ExpertTrajectory(goal, pairs))
    return out


def walked_cells(domain: Domain, here: int, target: int, limit: int) -> list[int] | None:
    """The cells a reading at ``target`` walks from ``here``, ``here`` excluded: none for the
    same cell, the cell itself for a neighbour, else the rest of :func:`path_within`'s
    shortest path; ``None`` when ``target`` is more than ``limit`` moves away. How the
    service walks positions in metres (``/positions``) and how ``experiment visitors`` feeds
    a ``positions`` visitor's readings."""
    if target == here:
        return []
    if target in domain.next_state[here]:
        return [target]
    path = path_within(domain, here, target, limit)
    return None if path is None else path[1:]


def path_within(domain: Domain, source: int, target: int, limit: int) -> list[int] | None:
    """A shortest path ``[source, ..., target]`` of at most ``limit`` moves, or ``None`` if
    ``target`` is farther. Breadth-first from ``source``, moves tried in the order N, E, S, W
    (so the path is the same every time); it visits only cells within ``limit`` moves."""
    if source == target:
        return [source]
    parent = {source: source}
    frontier = [source]
    nxt = domain.next_state
    for _ in range(limit):
        new: list[int] = []
        for s in frontier:
            for t in nxt[s].tolist():
                if t not in parent:
                    parent[t] = s
                    if t == target:
                        path = [t]
                        while path[-1] != source:
                            path.append(parent[path[-1]])
                        return path[::-1]
                    new.append(t)
        if not new:
            return None
        frontier = new
    return None
