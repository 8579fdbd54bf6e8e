"""What the viewer reads: plain snapshots of domains and live sessions.

The viewer is a consumer of state. It never reaches into the service; something else (the
service's ``GET /viewer/snapshot`` read by :mod:`app.viewer.remote`, or a test) hands it a
:class:`Snapshot` through a :data:`Feed`, a callable the pump calls at a fixed rate.
Snapshots are cheap to make (references to arrays the owner does not mutate, short lists) and
carry version numbers so the viewer redraws only what changed.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

from app.advice.advisor import DEFAULT_STRATEGY
from app.arrays import FloatArray
from app.domain.building import Domain

#: a cell as the service gives it: (row, col), or (floor, row, col) on a building
Cell = tuple[int, ...]
Probabilities = tuple[float, ...]


class Figure(NamedTuple):
    """One thing the advisor believes of the explorer, as its strategy says it: a plain
    ``name``, the paper's ``symbol``, how likely (``p``), and how it reads (``tone``: good,
    neutral, bad)."""

    name: str
    symbol: str
    p: float
    tone: str


class Destination(NamedTuple):
    """A destination of the map: its index among the goals, its cell, its name (if any)."""

    goal: int
    cell: Cell
    name: str | None

    @property
    def label(self) -> str:
        return f"{self.name} (G{self.goal})" if self.name else f"G{self.goal}"


@dataclass(frozen=True, eq=False)
class DomainView:
    """A domain (a one-floor map or a building) and its current prior ``theta`` (states x
    actions: 4, or 6 on a building); ``prior_version`` changes with it."""

    domain: Domain
    theta: FloatArray
    prior_version: int = 0

    @property
    def name(self) -> str:
        return self.domain.name


class AdviceGiven(NamedTuple):
    """Advice the advisor gave at ``cell``: theta of that cell, in the order N, E, S, W (and
    U, D on a building).

    A named tuple: feeds build many of these per tick, and tuples are cheap to make."""

    step: int
    cell: Cell
    probabilities: Probabilities


@dataclass(frozen=True)
class SessionView:
    """One live explorer as the viewer draws it (recent history only).

    ``p_normal_history`` holds P(M1 | H) after each of the last decisions, the newest last; the
    newest belongs to decision ``steps``. ``advice`` holds (step, cell, theta of the cell)
    triples, oldest first: :class:`AdviceGiven` or plain tuples of that shape.
    """

    session_id: str
    domain: str
    steps: int
    position: Cell
    p_normal: float
    advice_count: int
    total_cost: float
    kappa: float
    path: Sequence[Cell] = ()
    p_normal_history: Sequence[float] = ()
    advice: Sequence[tuple[int, Cell, Probabilities]] = ()
    agent_type: str | None = None
    strategy: str = DEFAULT_STRATEGY
    # goal_aware: (goal cell, P(goal | H), ruled out) for each goal of the map
    goals: Sequence[tuple[Cell, float, bool]] | None = None
    #: what its advisor believes, in a fixed order, and the index of the one that says most
    figures: Sequence[Figure] = ()
    headline: int = 0
    #: the destination its advice leads to (guide)
    leads_to: Destination | None = None

    @property
    def version(self) -> tuple[int, int]:
        """Changes whenever there is something new to draw."""
        return (self.steps, self.advice_count)


@dataclass(frozen=True)
class Snapshot:
    """Everything the viewer shows, at one instant. ``sessions`` come most recently active
    first (the service's snapshot gives them so); the viewer's picker keeps that order."""

    domains: dict[str, DomainView] = field(default_factory=dict)
    sessions: Sequence[SessionView] = ()
    #: the largest kappa at which any strategy of the service advises (None: not said)
    kappa_max: float | None = None

    def sessions_of(self, domain: str) -> list[SessionView]:
        return [s for s in self.sessions if s.domain == domain]


Feed = Callable[[], Snapshot]
