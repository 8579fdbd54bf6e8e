"""Explorers: the agents the advisor watches (Section V-B), as readable reference classes.

Every explorer moves on a :class:`~app.domain.grid.GridDomain` with the four compass actions
``N, E, S, W`` (0..3) and knows its own goal; the advisor does not. Every one also walks a
building of several floors (:class:`~app.domain.building.Building`, six actions: ``U, D`` 4
and 5), as the table says: a heading is always a compass move (a ride leaves it as it was),
and the compass walkers take the stairs and lifts as below. One step::

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
random         uniform over the 4 moves, walls included (a bump leaves the cell unchanged);
               in a building over the 6 actions (up and down leave it in place off a stop)
random-avoid   uniform over the moves that do not hit a wall (in a building: up and down at
               a stop that has a floor above or below)
left           wall follower: keeps a heading and takes the first open direction among
               left, straight, right, back (relative to the heading); the heading becomes
               every move that changed the cell. The first heading is drawn uniformly. In a
               building it follows the walls of its floor and never rides (a hand on the
               wall finds no way up): it reaches another floor only when advised there.
bug            greedy on coordinates: of the (at most two) moves that reduce the row or
               column difference to its goal, it tries the one on the axis with the larger
               difference first (that move most reduces the straight-line distance); equal
               differences: random order. If neither is open it moves uniformly among the
               open moves (it has no memory, so it can be caught in a pocket). In a
               building, on another floor than its goal's, it heads the same way for the
               nearest stop of its floor with a way up (its goal above) or down
               (``Building.nearest_stops``: by row plus column difference, as a sign to the
               lifts points) and rides there, a floor at a time; with no such stop on its
               floor it moves uniformly among the open moves.
optimal        a shortest path to its goal (uniform among tied shortest-path moves; in a
               building a quickest one, rides timed: :mod:`app.domain.paths`)
corridor       never turns back but in a dead end: uniform over the open moves other than
               back (back only where nothing else is open); the heading is its last move
               that changed the cell, the first drawn uniformly. In a building a ride from
               a stop is one more way on (uniform with the others)
straight       keeps its heading while the way ahead is open; else as ``corridor`` (so it
               rides only where the way ahead is shut)
=============  ===========================================================================

The first five are the paper's explorers (:data:`FIXED_EXPLORERS`); ``corridor`` and
``straight`` are walkers with a purpose, for the visitors' experiment (:data:`WALKERS`).

**Visitors** (:class:`Visitor`): a walker and what makes it a visitor as it is. The loop
(:func:`app.agents.episodes.run_episode`, and the kernel ``episode``) does, per move:

1. the advisor has decided for the cell it read (:func:`read_position`);
2. sight r > 0: if the goal lies on a straight line of free cells from the explorer's own
   cell within r moves (:func:`in_sight`), it takes that move, whatever the advice, no draw;
3. else, if advised: compliance p < 1 draws one u from the explorer's generator and takes
   the advice (one more draw, sampled from it) iff u < p, else its own rule; p = 1 takes the
   advice without that draw (the paper's protocol, the same draws as before visitors);
4. else its own rule (its own draws), from its own cell;
5. it moves; if it is not at its goal, the advisor reads the new cell: with noise q > 0 one
   draw u from the readings' generator, and if u < q a second draw picks one of the cell's
   open moves uniformly and the reading is the cell it leads to (a cell without open moves
   reads true); q = 0 draws nothing. The advisor appends (the cell it read before the move,
   the action) and decides for the new reading. Every cell is read once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import numpy.typing as npt

from app.arrays import BoolArray, FloatArray
from app.domain.building import Building, Domain, U
from app.domain.grid import N_ACTIONS
from app.domain.paths import optimal_actions

#: Names of the fixed-policy explorers, in the order used by the experiments and kernels.
FIXED_EXPLORERS: tuple[str, ...] = ("random", "random-avoid", "left", "bug", "optimal")
#: Every walker a visitor can be: the paper's explorers, then the walkers with a purpose.
WALKERS: tuple[str, ...] = (*FIXED_EXPLORERS, "corridor", "straight")


def sample_action(weights: npt.ArrayLike, u: float, mask: npt.ArrayLike | None = None) -> int:
    """Inverse-CDF draw of an action from ``weights`` (restricted to ``mask``) with one uniform
    ``u``: the first action whose running weight exceeds ``u`` times the total."""
    w = np.asarray(weights, dtype=np.float64)
    n = len(w)  # the domain's actions: 4, or 6 in a building of several floors
    allowed = np.ones(n, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    total = 0.0
    for a in range(n):
        if allowed[a]:
            total += float(w[a])
    target = u * total
    running = 0.0
    last = -1
    for a in range(n):
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

    def __init__(self, domain: Domain):
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
    """Completely random: any of the domain's actions with probability 1/A (the four moves;
    in a building of several floors up and down too)."""

    name = "random"

    def policy(self, state: int, rng: np.random.Generator) -> int:
        return int(rng.random() * self.domain.n_actions)


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

    def __init__(self, domain: Domain):
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
        if next_state != state and action < N_ACTIONS:  # a ride keeps the heading
            self.heading = action


class BugExplorer(FixedPolicyExplorer):
    """Goal-seeking bug: a move that reduces the row/column difference to its goal.

    With row difference ``dr`` and column difference ``dc``, the candidate moves are the
    vertical one towards the goal (if ``dr != 0``) and the horizontal one (if ``dc != 0``).
    It tries the axis with the larger ``|d|`` first (ties: random order from one ``u``) and
    takes the first open candidate. With no open candidate it moves uniformly among the open
    moves. In a building, on another floor than its goal's, it heads so for the nearest stop
    with a way towards the goal's floor (:attr:`Building.nearest_stops`) and rides from it.
    """

    name = "bug"

    def aim(self, state: int) -> tuple[int, int]:
        """(the cell it heads for, the ride it takes there: ``U``, ``D`` or -1): its goal,
        or on another floor of a building the nearest stop with a way towards the goal's
        floor (-1, -1: its floor has none)."""
        d = self.domain
        if isinstance(d, Building):
            here, there = int(d.cells[state, 0]), int(d.cells[self.goal, 0])
            if here != there:
                k = 0 if there > here else 1
                return int(d.nearest_stops[state, k]), U + k
        return self.goal, -1

    def candidates(self, state: int, rng: np.random.Generator, aim: int = -1) -> list[int]:
        """Moves towards ``aim`` (the goal by default), in the order they are tried."""
        cells = self.domain.cells
        target = self.goal if aim < 0 else aim
        dr = int(cells[target, -2]) - int(cells[state, -2])  # row, column: the last two
        dc = int(cells[target, -1]) - int(cells[state, -1])
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
        aim, ride = self.aim(state)
        if aim == state and ride >= 0:  # at the stop: up or down
            return ride
        if aim >= 0:
            for a in self.candidates(state, rng, aim):
                if open_moves[a]:
                    return a
        return uniform_choice(open_moves, rng.random())


class OptimalExplorer(FixedPolicyExplorer):
    """A shortest path to its goal, uniform among tied shortest-path moves."""

    name = "optimal"

    def __init__(self, domain: Domain):
        super().__init__(domain)
        self._optimal: dict[int, BoolArray] = {}

    def reset(self, goal: int, rng: np.random.Generator) -> None:
        super().reset(goal, rng)
        if goal not in self._optimal:
            self._optimal[goal] = optimal_actions(self.domain, goal)

    def policy(self, state: int, rng: np.random.Generator) -> int:
        best = self._optimal[self.goal][state]
        if not best.any():  # at the goal (terminal): any move
            return int(rng.random() * self.domain.n_actions)
        if best.sum() == 1:
            return int(np.argmax(best))
        return uniform_choice(best, rng.random())


class CorridorExplorer(LeftExplorer):
    """A corridor walker: never turns back but in a dead end.

    Uniform over the open moves other than back (relative to its heading, the direction of its
    last move that changed the cell, the first drawn uniformly at ``reset``); back only where
    nothing else is open.
    """

    name = "corridor"

    def policy(self, state: int, rng: np.random.Generator) -> int:
        open_moves = self.domain.open_moves[state]
        back = (self.heading + 2) % N_ACTIONS
        ahead = open_moves.copy()
        ahead[back] = False
        if ahead.any():
            return uniform_choice(ahead, rng.random())
        return back if open_moves[back] else self.heading  # a dead end: back


class StraightExplorer(CorridorExplorer):
    """Straight ahead while the way is open; else as the corridor walker."""

    name = "straight"

    def policy(self, state: int, rng: np.random.Generator) -> int:
        if self.domain.open_moves[state, self.heading]:
            return self.heading
        return super().policy(state, rng)


EXPLORER_CLASSES: dict[str, type[FixedPolicyExplorer]] = {
    cls.name: cls
    for cls in (
        RandomExplorer, RandomAvoidExplorer, LeftExplorer, BugExplorer, OptimalExplorer,
        CorridorExplorer, StraightExplorer,
    )
}  # fmt: skip


def check_walker(name: str, domain: Domain) -> None:
    """ValueError unless ``name`` is one of :data:`WALKERS` (each walks ``domain``, whatever
    its floors)."""
    if name not in EXPLORER_CLASSES:
        raise ValueError(f"unknown explorer {name!r}: use one of {', '.join(WALKERS)}")


def make_explorer(name: str, domain: Domain) -> FixedPolicyExplorer:
    """A fixed-policy explorer by name (:func:`check_walker`)."""
    check_walker(name, domain)
    return EXPLORER_CLASSES[name](domain)


def in_sight(domain: Domain, state: int, goal: int, reach: int) -> int | None:
    """The move along a straight line of free cells from ``state`` that reaches ``goal``
    within ``reach`` moves (N, E, S, W tried in turn: on its floor in a building), or None."""
    for a in range(N_ACTIONS):
        x = state
        for _ in range(reach):
            y = int(domain.next_state[x, a])
            if y == x:
                break
            if y == goal:
                return a
            x = y
    return None


def read_position(
    domain: Domain, state: int, noise: float, rng: np.random.Generator, jump: int = 1
) -> int:
    """The cell an advisor reads for an explorer at ``state``: with probability ``noise``
    (one draw) a uniformly drawn open neighbour (a second draw), else ``state``; no draw
    at all when ``noise`` is 0. With ``jump`` J > 1 a wrong reading is a walk of k random
    open moves, k drawn from 1 to J first (so up to J moves off; it may come back)."""
    if noise <= 0.0:
        return state
    open_moves = domain.open_moves[state]
    if rng.random() >= noise or not open_moves.any():
        return state
    k = 1 if jump <= 1 else 1 + min(int(rng.random() * jump), jump - 1)
    for _ in range(k):
        move = uniform_choice(domain.open_moves[state], rng.random())
        state = int(domain.next_state[state, move])
    return state


#: where a visitor's goal is drawn from: the map's destinations, or any free cell
GOAL_SETS: tuple[str, ...] = ("destinations", "anywhere")
#: how the advisor is fed: events (the cell as read and the visitor's action), or positions
#: (the readings walked as the service's /positions endpoint walks them)
FEEDS: tuple[str, ...] = ("events", "positions")


@dataclass(frozen=True)
class Visitor:
    """A walker and what makes it a visitor as it is (see the module's docstring).

    Written as a spec: the walker, then any of ``p=P`` (compliance, 0 to 1: takes a piece of
    advice with probability P), ``q=Q`` (position noise, 0 to 1: each cell is read one cell
    off with probability Q), ``r=R`` (sight, an integer >= 0: walks to its goal once it is in
    a straight line of free cells within R moves; 0 off), ``anywhere`` (bound for any free
    cell, not only the map's destinations), ``positions`` (the advisor is fed the readings as
    the service's ``/positions`` endpoint walks them: one decision per cell of the shortest
    path from the last reading, none for a reading in the same cell; the visitor acts on the
    last decision) and ``j=J`` (a wrong reading is up to J moves off, an integer >= 1).
    ``"random p=0.5"``, ``"optimal anywhere"``, ``"corridor q=0.1"``, ``"random r=8"``,
    ``"random q=0.1 j=2 positions"``. Defaults: p=1, q=0, r=0, destinations, events, j=1,
    which is the paper's explorer.
    """

    walker: str
    compliance: float = 1.0
    noise: float = 0.0
    sight: int = 0
    goals: str = "destinations"
    feed: str = "events"
    jump: int = 1

    def __post_init__(self) -> None:
        if self.walker not in WALKERS:
            raise ValueError(f"unknown walker {self.walker!r}: use one of {', '.join(WALKERS)}")
        for name, v in (("p (compliance)", self.compliance), ("q (position noise)", self.noise)):
            if not (isinstance(v, int | float) and math.isfinite(v) and 0.0 <= v <= 1.0):
                raise ValueError(f"{name} must be a number from 0 to 1, got {v}")
        if not (isinstance(self.sight, int) and self.sight >= 0):
            raise ValueError(f"r (sight) must be an integer >= 0, got {self.sight}")
        if self.goals not in GOAL_SETS:
            raise ValueError(f"goals must be one of {', '.join(GOAL_SETS)}, got {self.goals!r}")
        if self.feed not in FEEDS:
            raise ValueError(f"feed must be one of {', '.join(FEEDS)}, got {self.feed!r}")
        if not (isinstance(self.jump, int) and self.jump >= 1):
            raise ValueError(f"j (jump) must be an integer >= 1, got {self.jump}")
        if self.jump > 1 and self.feed != "positions":
            raise ValueError("j (jump) > 1 is for a visitor fed positions: add 'positions'")

    @classmethod
    def parse(cls, spec: str) -> Visitor:
        """A visitor from its spec (ValueError naming what is wrong and what is allowed)."""
        words = spec.split()
        if not words:
            raise ValueError("an empty visitor spec: give a walker, e.g. 'random p=0.5'")
        given: dict[str, Any] = {}
        for word in words[1:]:
            key, eq, value = word.partition("=")
            if not eq and word in GOAL_SETS:
                key, value = "goals", word
            elif not eq and word in FEEDS:
                key, value = "feed", word
            elif key not in _SPEC_KEYS or not eq:
                raise ValueError(
                    f"visitor {spec!r}: {word!r} is not one of p=P, q=Q, r=R, j=J, "
                    f"{', '.join(GOAL_SETS + FEEDS)}"
                )
            field_name = _SPEC_KEYS[key]
            if field_name in given:
                raise ValueError(f"visitor {spec!r}: {key} given twice")
            try:
                given[field_name] = (
                    value
                    if key in ("goals", "feed")
                    else int(value)
                    if key in ("r", "j")
                    else float(value)
                )
            except ValueError:
                raise ValueError(f"visitor {spec!r}: {word!r} is not a number") from None
        return cls(words[0], **given)

    @property
    def name(self) -> str:
        """The spec in its usual form: the walker, then what differs from the defaults."""
        parts = [self.walker]
        if self.compliance != 1.0:
            parts.append(f"p={self.compliance:g}")
        if self.noise != 0.0:
            parts.append(f"q={self.noise:g}")
        if self.sight:
            parts.append(f"r={self.sight}")
        if self.jump != 1:
            parts.append(f"j={self.jump}")
        if self.goals != "destinations":
            parts.append(self.goals)
        if self.feed != "events":
            parts.append(self.feed)
        return " ".join(parts)

    @property
    def anywhere(self) -> bool:
        return self.goals == "anywhere"


_SPEC_KEYS = {
    "p": "compliance", "q": "noise", "r": "sight", "j": "jump", "goals": "goals", "feed": "feed",
}  # fmt: skip
