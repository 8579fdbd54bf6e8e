"""The shapes the service answers with, as TypedDicts (the client needs no server code)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Literal, NotRequired, TypedDict

#: a cell: ``[row, col]``, or ``[floor, row, col]`` on a map of several floors
Cell = tuple[int, int] | tuple[int, int, int] | list[int]
#: an action: ``U`` and ``D`` (up, down where a stair or lift is) on a map of several floors
ActionName = Literal["N", "E", "S", "W", "U", "D"]


class Advice(TypedDict):
    N: float
    E: float
    S: float
    W: float
    U: NotRequired[float]  # on a map of several floors only
    D: NotRequired[float]


class Cost(TypedDict):
    advice_count: int
    total: float
    benefit: float


class Destination(TypedDict):
    """A destination of the map: its index in the domain's goals, its cell, its name."""

    goal: int
    cell: list[int]
    name: str | None


class Decision(TypedDict):
    step: int
    state: list[int]
    advise: bool
    advice: Advice | None
    kl: float
    p_normal: float
    cost: Cost
    #: guide, answering one event (or opening a session) with advice: where it leads
    leads_to: NotRequired[Destination]


class Figure(TypedDict):
    """One thing the advisor believes: a plain name, the paper's symbol, how likely, and how
    it reads (``good``, ``neutral``: the advisor is handling it, ``bad``)."""

    name: str
    symbol: str
    p: float
    tone: Literal["good", "neutral", "bad"]


class Beliefs(TypedDict):
    """What the advisor believes of the explorer, as its strategy reads it."""

    figures: list[Figure]
    headline: int  # the index of the figure that says most now
    leads_to: Destination | None


#: An event or a trajectory step as the client accepts it: any mapping with the fields of
#: :class:`Event` / :class:`Step` (plain dict literals are fine).
EventLike = Mapping[str, Any]


class Event(TypedDict):
    state: Cell
    action: NotRequired[ActionName | int | None]
    next_state: NotRequired[Cell | None]


class Step(TypedDict):
    state: Cell
    action: ActionName | int


class TrajectoryIn(TypedDict):
    steps: list[Step]
    agent_type: NotRequired[str | None]
    goal: NotRequired[Cell | None]


# ---- answers (the service's response models, as the client sees them) ------------------------
class Health(TypedDict):
    status: Literal["ok"]
    version: str
    database: str
    domains: int
    sessions: int
    uptime_seconds: float


class Floor(TypedDict):
    """A floor of a map of several floors."""

    index: int  # a cell's first coordinate (0 the lowest)
    ordinal: int
    name: str
    elevation: float | None
    map: list[str]


class Connection(TypedDict):
    """Stairs, a lift, an escalator or a ramp: its stops [floor, row, col], lowest first."""

    kind: str
    name: str
    cost: int
    stops: list[list[int]]


class DomainInfo(TypedDict):
    name: str
    rows: int
    cols: int
    map: list[str]  # on a map of several floors the lowest floor's rows
    floors: NotRequired[list[Floor]]  # a map of several floors only
    connections: NotRequired[list[Connection]]
    resolution: float | None
    origin: list[float] | None
    start: list[int]
    goals: list[list[int]]
    goal_names: NotRequired[list[str | None]]  # each goal's name (None: unnamed)
    actions: list[ActionName]
    alpha0: float
    n_states: int
    trajectories: int
    agent_types: list[str]
    created_at: str
    updated_at: str


class Accepted(TypedDict):
    accepted: int
    pairs: int


class Prior(TypedDict):
    domain: str
    agent_type: str | None
    table: str
    actions: list[ActionName]
    alpha0: float
    trajectories: int
    theta: list[list[list[float] | None]]


class GoalBelief(TypedDict):
    goal: list[int]
    p: float
    ruled_out: bool


class BudgetInfo(TypedDict):
    total: int | None
    per_minute: int | None
    left: int | None
    left_this_minute: int | None


class SessionInfo(TypedDict):
    session_id: str
    domain: str
    agent_type: str | None
    prior_table: str
    kappa: float
    window: int
    strategy: str
    params: dict[str, int | float]
    goals: list[GoalBelief] | None
    steps: int
    position: list[int]
    p_normal: float
    advice_count: int
    total_cost: float
    benefit: float
    advice_per_100: float
    idle_seconds: float
    created_at: str
    muted: bool
    budget: BudgetInfo | None
    beliefs: NotRequired[Beliefs | None]


class SessionList(TypedDict):
    total: int
    sessions: list[SessionInfo]


class Overview(TypedDict):
    role: NotRequired[Literal["admin", "operator"] | None]  # which key asked
    domains: list[dict[str, Any]]
    total_sessions: int
    sessions: list[dict[str, Any]]
