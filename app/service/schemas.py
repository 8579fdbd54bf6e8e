"""Request and response bodies, in families (``XCreate`` in, ``XPublic`` out).

States are ``[row, col]`` cells; actions ``"N" | "E" | "S" | "W"`` (or 0-3 on input). The hot
inputs (events, trajectory steps) are TypedDicts: pydantic-core validates them straight from
the JSON bytes without building model objects.
"""

from __future__ import annotations

import math
from dataclasses import fields
from datetime import datetime
from typing import TYPE_CHECKING, Annotated, Any, Literal, NotRequired

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    StringConstraints,
    create_model,
    model_validator,
    with_config,
)
from typing_extensions import TypedDict

from app import strategies
from app.advice.advisor import DEFAULT_KAPPA, DEFAULT_STRATEGY, DEFAULT_WINDOW
from app.advice.params import StrategyParams as CoreStrategyParams
from app.domain.grid import NAME_MAX
from app.domain.grid import NAME_RULE as NAME_RULE_DESTINATION

NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$"
NAME_RULE = "1-64 characters: letters, digits, '_', '.', '-' (starting with a letter or digit)"

Coordinate = Annotated[int, Field(strict=True, ge=0, lt=2**31)]
Cell = Annotated[
    list[Coordinate],
    Field(
        min_length=2, max_length=3, examples=[[28, 1]],
        description="A cell as [row, col]; row 0 is the top row. On a map of several floors "
        "[floor, row, col], floor the index of the map's floor (0 the lowest).",
    ),
]  # fmt: skip
ActionName = Literal["N", "E", "S", "W", "U", "D"]
ActionIn = Annotated[
    ActionName
    | Annotated[int, Field(strict=True, ge=0, le=5)],  # strict: true and 1.0 are not moves
    Field(
        description='A move: "N", "E", "S", "W" (or 0-3 in that order); on a map of several '
        'floors also "U" and "D" (4, 5): up or down where a stair or lift is.'
    ),
]
ACTION_BRANCHES = frozenset({"literal['N','E','S','W','U','D']", "constrained-int"})
#: an action as the schema reads it -> its code (-1: none given)
ACTION_CODE: dict[str | int | None, int] = {
    "N": 0, "E": 1, "S": 2, "W": 3, "U": 4, "D": 5, 0: 0, 1: 1, 2: 2, 3: 3, 4: 4, 5: 5,
    None: -1,
}  # fmt: skip
ACTION_RULE = (
    "an action is 'N', 'E', 'S', 'W' or an integer 0-3 ('U', 'D' or 4, 5 on a map of several "
    "floors)"
)
Name = Annotated[str, StringConstraints(pattern=NAME_PATTERN), Field(examples=["default"])]


def _absent(v: object) -> bool:
    """A field written only when it has a value (``exclude_if``): fields added to an answer
    leave the answers of the clients that never see them as they were."""
    return v is None


AgentType = Annotated[
    str,
    StringConstraints(pattern=NAME_PATTERN),
    Field(description=f"A kind of agent ({NAME_RULE}).", examples=["visitor"]),
]
#: the largest kappa a request may ask for (no strategy advises above a few nats: each
#: strategy's own range is ``kappa_max`` in ``GET /strategies``)
KAPPA_LIMIT = 1e6
Kappa = Annotated[
    float,
    Field(
        strict=True, ge=0.0, le=KAPPA_LIMIT, allow_inf_nan=False,
        description="Cost of one piece of advice (nats); 0 always advises. At most 1e6 (a KL "
        "over four actions is at most log 4 = 1.39 nats), so that a session's total cost, "
        "kappa x advice count, stays a finite number.",
    ),
]  # fmt: skip
Window = Annotated[int, Field(strict=True, ge=1, description="History window W (pairs).")]
Metres = Annotated[float, Field(strict=True, allow_inf_nan=False, ge=-1e9, le=1e9)]
RESOLUTION_MAX = 1e4
#: alpha0 bounds: beyond them theta over- or underflows (4 alpha0 is inf, alpha0 / count is 0)
#: and a prior's tables cannot be built; the store must never hold such a domain.
ALPHA0_MIN, ALPHA0_MAX = 1e-6, 1e6
#: names a PUT body may give at most (a map with more goals names them in its text)
MAX_DESTINATION_NAMES = 100_000


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


# ---- errors and health ----------------------------------------------------------------------
class ErrorPublic(BaseModel):
    detail: str = Field(description="What was wrong, in words.")
    errors: list[dict[str, object]] | None = Field(None, description="Each validation problem.")


class DependencyPublic(BaseModel):
    state: str = Field(
        description="up, down or not used (the database, Redis); connected, not connected, "
        "standby (another worker runs it) or off (the MQTT bridge); listening, not listening "
        "or off (the viewer)."
    )
    required: bool = Field(description="Whether readiness fails (503) while it is not up.")
    detail: str | None = Field(None, description="Why it is not up, in words.")


class HealthPublic(BaseModel):
    status: Literal["ok"]
    version: str
    database: str
    domains: int
    sessions: int
    uptime_seconds: float
    dependencies: dict[str, DependencyPublic] | None = Field(
        None,
        description="database, redis, mqtt, viewer: the state of each (only the database "
        "and Redis, when used, can fail readiness).",
    )


class LivePublic(BaseModel):
    status: Literal["ok"]
    version: str
    uptime_seconds: float


class NotReadyPublic(BaseModel):
    detail: str = Field(description="What the service cannot work without that is down.")
    status: Literal["unavailable"]
    dependencies: dict[str, DependencyPublic]


# ---- domains ---------------------------------------------------------------------------------
class DestinationIn(Strict):
    """A destination's name: its cell (a 'G' of the map) and what people call it."""

    cell: Cell
    name: str = Field(
        max_length=4 * NAME_MAX,  # checked against the rule with the map, naming its index
        description=f"{NAME_RULE_DESTINATION}.",
        examples=["Lecture hall B"],
    )


class DomainBase(Strict):
    map: list[str] | None = Field(
        None,
        description="ASCII map, one string per row: '#' wall, '.' free, 'S' start, 'G' goal. "
        "Give it or text.",
        examples=[["#####", "#S.G#", "#####"]],
        min_length=1,
    )
    text: str | None = Field(
        None,
        description="The map file's text as `maze import` and `maze generate` write it: header "
        "lines (`resolution: M`, `origin: X Y YAW`, `destination: ROW COL NAME`) if any, then "
        "one row a line. Its header gives the resolution, origin and destinations' names (not "
        "the fields). Give it or map; errors name the line and column of the text, as `maze "
        "check` does.",
        examples=["resolution: 0.5\norigin: -12.0 4.5 0.0\n#####\n#S.G#\n#####"],
    )
    alpha0: float = Field(
        1.0,
        strict=True,  # true is not a number
        ge=ALPHA0_MIN,
        le=ALPHA0_MAX,
        allow_inf_nan=False,
        description=f"Dirichlet hyperprior alpha0 ({ALPHA0_MIN:g} to {ALPHA0_MAX:g}).",
    )

    resolution: float | None = Field(
        None,
        strict=True,  # true is not a length
        gt=0,
        le=RESOLUTION_MAX,
        allow_inf_nan=False,
        description="Metres per cell side. With it the domain's sessions also take positions in "
        "metres (POST /sessions/{id}/positions).",
        examples=[0.5],
    )
    origin: list[Metres] | None = Field(
        None,
        min_length=2,
        max_length=3,
        description="x and y in metres of the lower-left corner of the lower-left cell, and "
        "the grid's yaw in radians (default 0): ROS map_server's convention, y up. Needs "
        "resolution; default [0, 0, 0].",
        examples=[[-12.0, 4.5, 0.0]],
    )

    destinations: list[DestinationIn] | None = Field(
        None,
        max_length=MAX_DESTINATION_NAMES,
        description="Names of the map's destinations ('G' cells), any of them (optional): "
        f"each name is {NAME_RULE_DESTINATION}, each cell and name (ignoring case) once. "
        "With text, the names are its header's `destination: ROW COL NAME` lines.",
        examples=[[{"cell": [1, 3], "name": "Lecture hall B"}]],
    )

    @model_validator(mode="after")
    def _origin_needs_resolution(self) -> DomainBase:
        if (self.map is None) == (self.text is None):
            raise ValueError(
                "give the map as map (a list of rows) or as text (the map file's text), one of them"
            )
        if self.text is not None and self.destinations is not None:
            raise ValueError(
                "with text, the destinations' names are the text's header lines "
                "(destination: ROW COL NAME), not a field"
            )
        if self.text is not None and (self.resolution, self.origin) != (None, None):
            raise ValueError(
                "with text, the resolution and origin are the text's header lines "
                "(resolution: M, origin: X Y YAW), not fields"
            )
        if self.origin is not None and self.resolution is None:
            raise ValueError("origin needs resolution (the cell side in metres)")
        return self


class ExpertsIn(Strict):
    """Simulated experts: for every goal, ``per_goal`` walks along shortest paths (random
    tie-breaks) from the start (``start``) or from uniformly random cells (``anywhere``)."""

    source: Literal["start", "anywhere"] = Field("start", description="Where experts start.")
    per_goal: int = Field(10, strict=True, ge=1, le=1000, description="Walks per goal.")
    seed: int = Field(0, strict=True, ge=0, le=2**32 - 1, description="Random seed.")


class DomainPut(DomainBase):
    """Create or replace a domain. A new map drops the old map's trajectories; the same map
    keeps them (only ``alpha0``, ``resolution`` or ``origin`` change)."""

    experts: ExpertsIn | None = Field(
        None,
        description="Learn the prior from simulated experts on the map, stored as ordinary "
        "trajectories with their goals: done when the domain's prior is empty after this PUT "
        "(a new domain or a new map), so repeating the PUT adds nothing.",
        examples=[{"source": "anywhere", "per_goal": 10, "seed": 0}],
    )


class FloorPublic(BaseModel):
    """One floor of a map of several floors."""

    index: int = Field(description="Its index: a cell's first coordinate (0 the lowest).")
    ordinal: int = Field(description="Its ordinal (0 the ground floor, negative below).")
    name: str
    elevation: float | None = Field(description="Metres above ordinal 0 (null: not known).")
    map: list[str] = Field(description="Its rows, as a one-floor map's.")


class ConnectionPublic(BaseModel):
    """Stairs, a lift, an escalator or a ramp between floors."""

    kind: str
    name: str
    cost: int = Field(description="Moves of time a ride takes per floor travelled.")
    stops: list[Cell] = Field(description="Its stops, [floor, row, col], lowest first.")


class DomainPublic(BaseModel):
    name: str
    rows: int
    cols: int
    map: list[str] = Field(
        description="The map's rows; on a map of several floors its lowest floor's (floors "
        "holds each)."
    )
    floors: list[FloorPublic] | None = Field(
        None, exclude_if=_absent, description="A map of several floors: each, lowest first."
    )
    connections: list[ConnectionPublic] | None = Field(
        None, exclude_if=_absent, description="A map of several floors: its connections."
    )
    resolution: float | None = Field(description="Metres per cell side (null: cells only).")
    origin: list[float] | None = Field(
        description="x, y (metres) of the lower-left corner of the lower-left cell, yaw."
    )
    start: Cell
    goals: list[Cell]
    goal_names: list[str | None] = Field(
        description="Each goal's name, in the order of goals (null: the map names it not)."
    )
    actions: list[ActionName]
    alpha0: float
    n_states: int
    trajectories: int = Field(description="Expert trajectories in the pooled prior.")
    agent_types: list[str] = Field(description="Agent types with their own prior.")
    created_at: datetime
    updated_at: datetime


# ---- trajectories and priors -----------------------------------------------------------------
@with_config(ConfigDict(extra="forbid"))
class StepIn(TypedDict):
    state: Cell
    action: ActionIn


class TrajectoryIn(Strict):
    agent_type: AgentType | None = None
    steps: list[StepIn] = Field(
        min_length=1, description="Each step's state is where the last led."
    )
    goal: Cell | None = Field(None, description="The goal or end cell, if known.")


class TrajectoriesCreate(Strict):
    trajectories: list[TrajectoryIn] = Field(min_length=1)


class TrajectoriesAccepted(BaseModel):
    accepted: int = Field(description="Trajectories stored.")
    pairs: int = Field(description="(state, action) pairs in them.")


class PriorPublic(BaseModel):
    domain: str
    agent_type: str | None = Field(description="The agent type asked for.")
    table: str = Field(description="The table that serves it ('*' = pooled over all types).")
    actions: list[ActionName]
    alpha0: float
    trajectories: int
    theta: list[list[list[float] | None]] | list[list[list[list[float] | None]]] = Field(
        description="theta_s(a) as rows x cols x 4 (N, E, S, W); null for walls. On a map of "
        "several floors floors x rows x cols x 6 (N, E, S, W, U, D)."
    )


# ---- sessions, events and decisions ----------------------------------------------------------
def _known_strategy(name: str) -> str:
    if name not in strategies.STRATEGIES:
        raise ValueError(f"unknown strategy {name!r}: use one of {', '.join(strategies.names())}")
    return name


def _strategy_schema(schema: dict[str, Any]) -> None:
    """The strategies registered when the schema is made, with what each does."""
    schema["enum"] = list(strategies.names())
    schema["description"] = (
        STRATEGY_DOC
        + " "
        + "; ".join(f"'{e.name}': {e.summary}" for e in strategies.STRATEGIES.values())
    )


STRATEGY_DOC = (
    "When to advise (GET /strategies lists each strategy with its parameters; "
    "docs/ARCHITECTURE.md, 'Advising strategies'). Every strategy costs kappa per piece of "
    "advice."
)
#: a strategy of the table (:mod:`app.strategies`), checked when a request is read
StrategyName = Annotated[
    str, AfterValidator(_known_strategy), Field(json_schema_extra=_strategy_schema)
]


def _strategy_params_fields() -> dict[str, Any]:
    """The request's strategy parameters, made from the core's one definition
    (:class:`app.advice.params.StrategyParams`: names, defaults, bounds, meaning; which
    strategy reads which is its entry's, :mod:`app.strategies`)."""
    out: dict[str, Any] = {}
    for f in fields(CoreStrategyParams):
        m = f.metadata
        kind: type = int if f.type == "int" else float
        bounds: dict[str, Any] = {"ge": m["low"]}
        if m["high"] != math.inf:
            bounds["le"] = m["high"]
        if kind is float:
            bounds["allow_inf_nan"] = False
        doc = f"{m['doc']} Default {f.default}."
        out[f.name] = (kind | None, Field(None, strict=True, description=doc, **bounds))
    return out


if TYPE_CHECKING:  # the model is made at import time; type checkers see its base
    StrategyParams = Strict
else:
    StrategyParams = create_model(
        "StrategyParams",
        __base__=Strict,
        __doc__="Parameters of the advising strategy; a strategy refuses any it does not read "
        "(422). Omitted ones take their defaults.",
        **_strategy_params_fields(),
    )


class BudgetIn(Strict):
    """An advice budget: how much advice the session may give at most (omitted: no limit)."""

    total: int | None = Field(
        None, strict=True, ge=0, le=2**31 - 1, description="Pieces of advice in all."
    )
    per_minute: int | None = Field(
        None, strict=True, ge=1, le=2**31 - 1,
        description="Pieces of advice in any minute (a bucket of that many, refilled at that "
        "rate).",
    )  # fmt: skip


class BudgetPublic(BaseModel):
    total: int | None = Field(description="Pieces of advice in all (null: no limit).")
    per_minute: int | None = Field(description="Pieces in any minute (null: no limit).")
    left: int | None = Field(description="Pieces left in all (null: no limit).")
    left_this_minute: int | None = Field(
        description="Pieces the minute's bucket holds now (null: no limit)."
    )


class MuteIn(Strict):
    muted: bool = Field(True, strict=True, description="True: no more advice; false: advice again.")


class SessionCreate(Strict):
    kappa: Kappa = DEFAULT_KAPPA
    window: Window = DEFAULT_WINDOW
    agent_type: AgentType | None = None
    start: Cell | None = Field(None, description="Start cell (default: the domain's start).")
    strategy: StrategyName = Field(DEFAULT_STRATEGY, description=STRATEGY_DOC)
    params: StrategyParams | None = Field(
        None, description="The strategy's parameters: only those it reads (see StrategyParams)."
    )
    budget: BudgetIn | None = Field(
        None, description="At most this much advice (in all, per minute); a decision past it "
        "does not advise.",
    )  # fmt: skip


ParamsInForce = Annotated[
    dict[str, int | float],
    Field(description="The parameters the strategy reads, with the values in force."),
]


class GoalBelief(BaseModel):
    """goal_aware sessions: what the advisor believes of one goal of the map."""

    goal: Cell
    p: float = Field(description="P(goal | H), the weight of this goal's prior in the advice.")
    ruled_out: bool = Field(
        description="The explorer stood on this goal and went on. guide: a first visit (what "
        "a position read off and walked looks like) only sets it aside; it is reported ruled "
        "out until every goal is out, then it comes back, and a second visit rules it out."
    )


class DestinationPublic(BaseModel):
    """A destination of the map (one of its goals)."""

    goal: int = Field(description="Its index in the domain's goals (G0, G1, ... on the maps).")
    cell: Cell
    name: str | None = Field(description="Its name, if the map names it.")


class FigurePublic(BaseModel):
    """One thing the advisor believes of the explorer."""

    name: str = Field(
        description="In plain words: 'moves like someone who knows the building', 'looks "
        "lost', 'on its way'.",
    )
    symbol: str = Field(description="The same in the paper's notation: 'P(M1|H)', 'P(M2|H)'.")
    p: float = Field(description="How likely, 0 to 1.")
    tone: Literal["good", "neutral", "bad"] = Field(
        description="How it reads, as the strategy decides: good (nothing to do), neutral "
        "(the advisor is handling it: guide leading a lost explorer), bad (it looks lost and "
        "the advisor cannot help now)."
    )


class BeliefsPublic(BaseModel):
    """What the advisor believes of the explorer, as its strategy reads it: the pages show
    these rather than reading P(M1|H) themselves."""

    figures: list[FigurePublic] = Field(description="In an order fixed per strategy.")
    headline: int = Field(description="The index of the figure that says most now.")
    leads_to: DestinationPublic | None = Field(
        description="The destination its advice leads to now (guide), else null."
    )


class CostPublic(BaseModel):
    advice_count: int
    total: float = Field(description="kappa x advice_count.")
    benefit: float = Field(description="Sum of KL at advised states (eq. (3)).")


class AdvicePublic(BaseModel):
    """theta_s, one number per action; ``U`` and ``D`` on a map of several floors only."""

    N: float
    E: float
    S: float
    W: float
    U: float | None = Field(None, exclude_if=_absent, description="Up (several floors only).")
    D: float | None = Field(None, exclude_if=_absent, description="Down (several floors only).")


class DecisionPublic(BaseModel):
    """The advisor's answer for the cell the explorer is now in."""

    step: int = Field(description="Moves observed so far (0 for the start).")
    state: Cell
    advise: bool
    advice: AdvicePublic | None = Field(description="theta_s when advising, else null.")
    kl: float = Field(description="KL[theta_s || P(A | s, H)] in nats.")
    p_normal: float = Field(description="P(M1 | H), the posterior of the normal model.")
    cost: CostPublic
    leads_to: DestinationPublic | None = Field(
        None,
        exclude_if=_absent,  # absent, not null: the answers before it stay as they were
        description="The destination the advice leads to (guide), in the answer to one event "
        "that advises and in a new session's first decision; absent otherwise (a batch's "
        "decisions: the session's beliefs.leads_to says it).",
    )


EventStep = Annotated[
    int,
    Field(
        strict=True, ge=1, lt=2**53,
        description="The session step this event is meant to be (the first event of a session "
        "is step 1): a step already applied is answered again with its decision and not "
        "applied twice; a step that is not the next one is refused (409). Retries send it.",
    ),
]  # fmt: skip


@with_config(ConfigDict(extra="forbid"))
class EventIn(TypedDict):
    """The explorer at ``state`` took ``action`` and reached ``next_state``."""

    state: Cell
    action: NotRequired[ActionIn | None]
    next_state: NotRequired[Cell | None]
    step: NotRequired[EventStep]


Point = Annotated[
    list[Metres],
    Field(
        min_length=2,
        max_length=3,
        examples=[[3.2, 7.9]],
        description="[x, y] in metres; on a map of several floors [x, y, floor], floor the "
        "index of the floor it was read on (0 the lowest).",
    ),
]


class PositionsIn(Strict):
    """Where the explorer was seen, in metres, oldest first (a positioning system's readings)."""

    positions: list[Point] = Field(min_length=1)


class SessionCreated(BaseModel):
    session_id: str
    token: str = Field(description="Send as 'Authorization: Bearer <token>' or ?token=.")
    domain: str
    agent_type: str | None
    prior_table: str
    kappa: float
    window: int
    strategy: StrategyName
    params: ParamsInForce
    decision: DecisionPublic


class SessionBase(BaseModel):
    """What every view of a live session shows."""

    session_id: str
    domain: str
    agent_type: str | None
    kappa: float
    strategy: StrategyName
    goals: list[GoalBelief] | None = Field(description="goal_aware sessions only, else null.")
    steps: int
    position: Cell
    floor: str | None = Field(
        None,
        exclude_if=_absent,
        description="On a map of several floors, the name of the floor the explorer is on.",
    )
    p_normal: float
    advice_count: int
    total_cost: float
    advice_per_100: float
    muted: bool = Field(False, description="The visitor asked for no more advice.")
    budget: BudgetPublic | None = Field(None, description="Its advice budget (null: none).")
    beliefs: BeliefsPublic | None = Field(
        None, description="What the advisor believes of the explorer, in plain words."
    )


class SessionPublic(SessionBase):
    """A session's figures, for its token or the admin key."""

    prior_table: str = Field(description="The prior table advising it ('*' = pooled).")
    window: int
    params: ParamsInForce
    benefit: float
    idle_seconds: float
    created_at: datetime


class SessionList(BaseModel):
    total: int
    sessions: list[SessionPublic]


# ---- overview (public) -----------------------------------------------------------------------
class AdviceGiven(BaseModel):
    step: int
    state: Cell
    advice: AdvicePublic


class OverviewDomain(BaseModel):
    name: str
    rows: int
    cols: int
    n_states: int
    trajectories: int
    sessions: int = Field(description="Live sessions on it.")
    steps: int = Field(description="Moves its live sessions reported, in all.")
    advice_count: int = Field(description="Advice its live sessions were given, in all.")
    advice_per_100: float = Field(description="Advice per 100 decisions over its sessions.")
    looking_lost: int = Field(description="Live sessions whose P(M1 | H) is below 1/2.")


class OverviewSession(SessionBase):
    """A live session as the overview shows it to an operator (no token, no parameters)."""

    last_advice: AdviceGiven | None
    path: list[Cell] = Field(description="Recent cells, oldest first.")
    p_normal_history: list[float] = Field(description="Recent P(M1 | H), oldest first.")


class Overview(BaseModel):
    detail: bool = Field(
        description="Whether live sessions are listed: for the admin key or the read-only "
        "operator key (X-API-Key) only; anyone else sees the figures per domain."
    )
    role: Literal["admin", "operator"] | None = Field(
        None,
        description="Which key asked: admin (reads live sessions, and ends them), operator "
        "(reads only), null (no key). The dashboard offers what the key may do.",
    )
    domains: list[OverviewDomain]
    total_sessions: int
    sessions: list[OverviewSession] = Field(
        description="Most recently active first, with where each explorer is and was (the "
        "last cells within the retention); empty without an operator's key."
    )


# ---- the viewer's feed (operator key) --------------------------------------------------------
class ViewerDomain(BaseModel):
    name: str
    updated_at: datetime = Field(description="Changes when the domain is PUT again.")
    prior_version: int = Field(description="Changes whenever its prior does.")


class ViewerSession(SessionBase):
    """A live session as the viewer draws it."""

    path: list[Cell] = Field(description="Recent cells within the retention, oldest first.")
    p_normal_history: list[float]
    advice: list[tuple[int, Cell, list[float]]] = Field(
        description="(step, cell, advice as N, E, S, W, and U, D on a map of several floors) "
        "of the recent advice, oldest first."
    )


class ViewerSnapshot(BaseModel):
    domains: list[ViewerDomain]
    sessions: list[ViewerSession] = Field(description="Most recently active first.")
    kappa_max: float = Field(
        description="The largest kappa at which any strategy of this service still advises "
        "(the viewer's kappa slider goes up to it)."
    )


class ViewerStatus(BaseModel):
    enabled: bool = Field(description="Whether `serve` starts the viser viewer beside the API.")
    running: bool = Field(
        description="Whether it runs now: false when it is not enabled, or its process (which "
        "`serve` started) has exited."
    )
    port: int | None = Field(description="Its port (null when not enabled).")
    host: str | None = Field(description="The interface it listens on (null when not enabled).")


# ---- the strategies (public) -----------------------------------------------------------------
class StrategyParamPublic(BaseModel):
    name: str
    default: float
    low: float
    high: float | None = Field(description="null: no upper bound.")
    description: str


class StrategyPublic(BaseModel):
    """One advising strategy a session may ask for (``strategy``), and what it reads."""

    name: str
    summary: str = Field(description="What it does, in plain words.")
    advice: str = Field(description="What a piece of its advice is, in plain words.")
    params: list[StrategyParamPublic] = Field(description="The parameters it reads (params).")
    needs: list[str] = Field(
        description="What it reads of a domain besides the prior: 'goal_priors' (the experts' "
        "goals), 'guide_map' (the map's destinations); built at a domain's first such session."
    )
    kappa_max: float | None = Field(
        description="The largest kappa at which it can still advise (null: kappa only prices "
        "its advice; the rule decides without it)."
    )
    compiled: bool = Field(description="Whether a compiled form runs its batches.")
