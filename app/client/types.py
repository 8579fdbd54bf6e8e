"""The shapes the service answers with, as TypedDicts (the client needs no server code)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Literal, NotRequired, TypedDict

Cell = tuple[int, int] | list[int]
ActionName = Literal["N", "E", "S", "W"]


class Advice(TypedDict):
    N: float
    E: float
    S: float
    W: float


class Cost(TypedDict):
    advice_count: int
    total: float
    benefit: float


class Decision(TypedDict):
    step: int
    state: list[int]
    advise: bool
    advice: Advice | None
    kl: float
    p_normal: float
    cost: Cost


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
