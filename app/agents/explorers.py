"""Explorers: the agents the advisor watches (Section V-B), as readable reference classes.

Every explorer moves on a :class:`~app.domain.grid.GridDomain` with the four compass actions
``N, E, S, W`` (0..3) and knows its own goal; the advisor does not. One step::

    action = explorer.act(state, rng, advice)   # advice: theta_s, or None when not advised
    next_state = domain.next_state[state, action]
    explorer.observe(state, action, next_state)

**Advice.** A fixed-policy explorer that is advised samples its action from the advice
(theta_s) instead of using its own rule (the paper's protocol, Section IV-A). The Q-learner
(:mod:`app.agents.qlearning`) uses the advice for exploration instead.

**Randomness.** Every random choice draws exactly one ``rng.random()`` (a uniform ``u`` in
[0, 1)) and turns it into a choice with :func:`sample_action` or :func:`uniform_choice`, only
when a choice is needed. The compiled kernels in :mod:`app.kernels` make the same draws in
the same order, so from the same ``np.random.Generator`` they follow the same trajectory.

=============  ===========================================================================
name           own rule (no advice)
=============  ===========================================================================
random         uniform over the 4 moves, walls included (a bump leaves the cell unchanged)
random-avoid   uniform over the moves that do not hit a wall
left           wall follower: keeps a heading and takes the first open direction among
               left, straight, right, back (relative to the heading); the heading becomes
               every move that changed the cell. The first heading is drawn uniformly.
bug            greedy on coordinates: of the (at most two) moves that reduce the row or
               column difference to its goal, it tries the one on the axis with the larger
               difference first (that move most reduces the straight-line distance); equal
               differences: random order. If neither is open it moves uniformly among the
               open moves (it has no memory, so it can be caught in a pocket).
optimal        a shortest path to its goal (uniform among tied shortest-path moves)
=============  ===========================================================================
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
import numpy.typing as npt

from app.arrays import BoolArray, FloatArray
from app.domain.grid import N_ACTIONS, GridDomain
from app.domain.paths import optimal_actions

#: Names of the fixed-policy explorers, in the order used by the experiments and kernels.
FIXED_EXPLORERS: tuple[str, ...] = ("random", "random-avoid", "left", "bug", "optimal")


def sample_action(weights: npt.ArrayLike, u: float, mask: npt.ArrayLike | None = None) -> int:
    """Inverse-CDF draw of an action from ``weights`` (restricted to ``mask``) with one uniform
    ``u``: the first action whose running weight exceeds ``u`` times the total."""
    w = np.asarray(weights, dtype=np.float64)
    allowed = np.ones(N_ACTIONS, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    total = 0.0
    for a in range(N_ACTIONS):
        if allowed[a]:
            total += float(w[a])
    target = u * total
    running = 0.0
    last = -1
    for a in range(N_ACTIONS):
        if allowed[a]:
            running += float(w[a])
            last = a
            if target < running:
                return a
    return last  # u * total rounded up to the total: the last allowed action


def uniform_choice(mask: npt.ArrayLike, u: float) -> int:
    """One of the actions where ``mask`` is true, uniformly, from one uniform ``u``."""
    options = np.flatnonzero(np.asarray(mask, dtype=bool))
    return int(options[int(u * len(options))])


class FixedPolicyExplorer:
    """Base class: an explorer with a fixed rule that follows advice when it is given."""

    name: ClassVar[str] = ""

    def __init__(self, domain: GridDomain):
        self.domain = domain
        self.goal = domain.goals[0]

    def reset(self, goal: int, rng: np.random.Generator) -> None:
        """Start a new task with this (hidden) ``goal``."""
        self.goal = goal

    def act(self, state: int, rng: np.random.Generator, advice: FloatArray | None = None) -> int:
        """The next action at ``state``: sampled from ``advice`` if given, else the own rule."""
        if advice is not None:
            return sample_action(advice, rng.random())
        return self.policy(state, rng)

    def policy(self, state: int, rng: np.random.Generator) -> int:
        raise NotImplementedError

    def observe(self, state: int, action: int, next_state: int) -> None:
        """What the move did (only the wall follower keeps anything)."""


class RandomExplorer(FixedPolicyExplorer):
    """Completely random: any of the four moves with probability 1/4."""

    name = "random"

    def policy(self, state: int, rng: np.random.Generator) -> int:
        return int(rng.random() * N_ACTIONS)


class RandomAvoidExplorer(FixedPolicyExplorer):
    """Random with obstacle avoidance: uniform over the moves that do not hit a wall."""

    name = "random-avoid"

    def policy(self, state: int, rng: np.random.Generator) -> int:
        return uniform_choice(self.domain.open_moves[state], rng.random())


class LeftExplorer(FixedPolicyExplorer):
    """Always turn left: the left-hand wall follower.

    Relative to its heading it tries left, straight, right, back and takes the first open
    direction. The heading is the direction of its last move that changed the cell (a move
    taken on advice counts too); the first heading is drawn uniformly at ``reset``.
    """

    name = "left"

    def __init__(self, domain: GridDomain):
        super().__init__(domain)
        self.heading = 0

    def reset(self, goal: int, rng: np.random.Generator) -> None:
        super().reset(goal, rng)
        self.heading = int(rng.random() * N_ACTIONS)

    def policy(self, state: int, rng: np.random.Generator) -> int:
        open_moves = self.domain.open_moves[state]
        for turn in (-1, 0, 1, 2):  # left, straight, right, back (actions are clockwise)
            a = (self.heading + turn) % N_ACTIONS
            if open_moves[a]:
                return a
        return self.heading  # a cell with no open move: nothing to do but bump

    def observe(self, state: int, action: int, next_state: int) -> None:
        if next_state != state:
            self.heading = action


class BugExplorer(FixedPolicyExplorer):
    """Goal-seeking bug: a move that reduces the row/column difference to its goal.

    With row difference ``dr`` and column difference ``dc``, the candidate moves are the
    vertical one towards the goal (if ``dr != 0``) and the horizontal one (if ``dc != 0``).
    It tries the axis with the larger ``|d|`` first (ties: random order from one ``u``) and
    takes the first open candidate. With no open candidate it moves uniformly among the open
    moves.
    """

    name = "bug"

    def candidates(self, state: int, rng: np.random.Generator) -> list[int]:
        """Moves towards the goal, in the order they are tried."""
        (r, c), (gr, gc) = self.domain.cell(state), self.domain.cell(self.goal)
        dr, dc = gr - r, gc - c
        vertical = [2 if dr > 0 else 0] if dr != 0 else []  # S or N
        horizontal = [1 if dc > 0 else 3] if dc != 0 else []  # E or W
        if abs(dr) > abs(dc):
            return vertical + horizontal
        if abs(dc) > abs(dr):
            return horizontal + vertical
        if dr == 0:  # at the goal's cell: nothing reduces the difference
            return []
        return vertical + horizontal if rng.random() < 0.5 else horizontal + vertical

    def policy(self, state: int, rng: np.random.Generator) -> int:
        open_moves = self.domain.open_moves[state]
        for a in self.candidates(state, rng):
            if open_moves[a]:
                return a
        return uniform_choice(open_moves, rng.random())


class OptimalExplorer(FixedPolicyExplorer):
    """A shortest path to its goal, uniform among tied shortest-path moves."""

    name = "optimal"

    def __init__(self, domain: GridDomain):
        super().__init__(domain)
        self._optimal: dict[int, BoolArray] = {}

    def reset(self, goal: int, rng: np.random.Generator) -> None:
        super().reset(goal, rng)
        if goal not in self._optimal:
            self._optimal[goal] = optimal_actions(self.domain, goal)

    def policy(self, state: int, rng: np.random.Generator) -> int:
        best = self._optimal[self.goal][state]
        if not best.any():  # at the goal (terminal): any move
            return int(rng.random() * N_ACTIONS)
        if best.sum() == 1:
            return int(np.argmax(best))
        return uniform_choice(best, rng.random())


EXPLORER_CLASSES: dict[str, type[FixedPolicyExplorer]] = {
    cls.name: cls
    for cls in (RandomExplorer, RandomAvoidExplorer, LeftExplorer, BugExplorer, OptimalExplorer)
}


def make_explorer(name: str, domain: GridDomain) -> FixedPolicyExplorer:
    """A fixed-policy explorer by name (one of :data:`FIXED_EXPLORERS`)."""
    try:
        return EXPLORER_CLASSES[name](domain)
    except KeyError:
        raise ValueError(
            f"unknown explorer {name!r}: use one of {', '.join(FIXED_EXPLORERS)}"
        ) from None
