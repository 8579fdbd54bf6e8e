"""Advising strategies: when to speak, with the paper's payload and cost accounting.

``paper`` is the rule of eq. (6). The others are the teacher-student literature's budgeted rules
(early, importance, mistake correcting, random) and ``always``, plus ``goal_aware``
(:mod:`app.advice.goals`) and ``guide`` (:mod:`app.advice.guide`, beyond the paper: it reads the
map and its destinations). The rules give theta_s as advice and report the paper's KL and
P(M1 | H) for comparison, whatever rule decided; ``goal_aware`` and ``guide`` give their own
advice and KL. All count kappa per piece of advice.

:class:`StrategyParams` is the one definition of the strategies' parameters: names, defaults,
bounds, which strategy reads which (:data:`READS`) and what each means. The service's request
schema is made from it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np

from app.advice.advisor import DEFAULT_KAPPA, DEFAULT_WINDOW, Advisor, Decision
from app.advice.goals import GoalAwareAdvisor
from app.advice.guide import GuideAdvisor, GuideMap, GuideParams
from app.advice.models import AdviceTables
from app.advice.priors import GoalPriors
from app.domain.grid import N_ACTIONS

STRATEGIES = (
    "paper", "goal_aware", "early", "importance", "mistake", "random", "always", "guide",
)  # fmt: skip
RULES = ("early", "importance", "mistake", "random", "always")


def _param(default: float, low: float, high: float, read_by: tuple[str, ...], doc: str) -> Any:
    return field(
        default=default, metadata={"low": low, "high": high, "read_by": read_by, "doc": doc}
    )


@dataclass(frozen=True)
class StrategyParams:
    """Parameters of every strategy; each strategy reads only its own (:data:`READS`)."""

    n_steps: int = _param(
        20, 0, 2**31 - 1, ("early",), "early: advise at the first n_steps decisions."
    )
    threshold: float = _param(
        0.5, 0.0, math.inf, ("importance", "mistake"),
        "importance: advise where KL[theta_s || uniform] >= threshold (nats); mistake: after "
        "an action with theta_s(a) < threshold.",
    )  # fmt: skip
    rate: float = _param(0.1, 0.0, 1.0, ("random",), "random: P(advise) per decision.")
    beta: float = _param(
        0.0, 0.0, 1.0, ("goal_aware",),
        "goal_aware: weight of each goal's likelihood of the window (0: ruling goals out only).",
    )  # fmt: skip
    seed: int = _param(0, 0, 2**32 - 1, ("random",), "random: seed of its draws.")
    p_lost: float = _param(
        0.15, 0.001, 0.999, ("guide",),
        "guide: prior probability that an explorer is lost (the rest: heading for a destination).",
    )  # fmt: skip
    slack: float = _param(
        0.5, 0.01, 1.0, ("guide",),
        "guide: how far an explorer heading for a destination may stray: the share of its moves "
        "drawn uniformly (1: no better than lost).",
    )  # fmt: skip
    spread: float = _param(
        0.05, 0.0, 1.0, ("guide",),
        "guide: share of the advice spread evenly over the four actions (0: only moves towards "
        "the destination).",
    )  # fmt: skip

    def check(self) -> None:
        """Raise ValueError naming the first parameter outside its bounds."""
        for f in fields(self):
            v, low, high = getattr(self, f.name), f.metadata["low"], f.metadata["high"]
            whole = f.type == "int"
            if whole and (isinstance(v, bool) or not isinstance(v, int | np.integer)):
                raise ValueError(f"{f.name} must be a whole number, got {v!r}")
            if not (math.isfinite(v) and low <= v <= high):
                kind = "a whole number" if whole else "a finite number"
                bounds = f">= {low}" if high == math.inf else f"from {low} to {high}"
                raise ValueError(f"{f.name} must be {kind} {bounds}, got {v!r}")

    def read_by(self, strategy: str) -> dict[str, int | float]:
        """The parameters ``strategy`` reads, with their values (the parameters in force)."""
        return {name: getattr(self, name) for name in READS[strategy]}


#: The parameters each strategy reads.
READS: dict[str, tuple[str, ...]] = {
    s: tuple(f.name for f in fields(StrategyParams) if s in f.metadata["read_by"])
    for s in STRATEGIES
}


def strategy_params(strategy: str, given: Mapping[str, int | float]) -> StrategyParams:
    """The parameters of ``strategy`` with ``given`` set: ValueError names an unknown strategy,
    a parameter the strategy does not read, or a value out of bounds."""
    if strategy not in STRATEGIES:
        raise ValueError(f"unknown strategy {strategy!r}: use one of {', '.join(STRATEGIES)}")
    unread = sorted(set(given) - set(READS[strategy]))
    if unread:
        reads = ", ".join(READS[strategy]) or "no parameters"
        raise ValueError(f"{strategy} does not read {', '.join(unread)} (it reads {reads})")
    params = replace(StrategyParams(), **dict[str, Any](given))
    params.check()
    return params


class RuleAdvisor(Advisor):
    """The paper's window and posterior, with another rule deciding when to advise."""

    __slots__ = ("_last", "_params", "_rng", "_rule")

    def __init__(
        self,
        tables: AdviceTables,
        rule: str,
        kappa: float = DEFAULT_KAPPA,
        window: int = DEFAULT_WINDOW,
        params: StrategyParams | None = None,
    ):
        if rule not in RULES:
            raise ValueError(f"unknown rule {rule!r}: use one of {', '.join(RULES)}")
        self._rule = rule
        self._params = params or StrategyParams()
        self._params.check()
        self._last: tuple[int, int] | None = None
        self._rng = np.random.default_rng(self._params.seed)
        super().__init__(tables, kappa, window)

    @property
    def strategy(self) -> str:
        return self._rule

    def params(self) -> dict[str, int | float]:
        return self._params.read_by(self._rule)

    def reset(self) -> None:
        """Forget the history, the cost, the last move, and restart the random rule's draws
        (a new explorer is advised as a fresh advisor would advise it)."""
        super().reset()
        self._last = None
        self._rng = np.random.default_rng(self._params.seed)

    def observe(self, state: int, action: int, next_state: int) -> Decision:
        self.append(state, action)
        self._last = (state, action)
        return self.decide(next_state)

    def decide(self, state: int) -> Decision:
        kl, p_normal = self.divergence(state)
        th = self.tables.theta_flat
        b = state * N_ACTIONS
        row = (th[b], th[b + 1], th[b + 2], th[b + 3])
        return self.record(state, self._says(state), row, kl, p_normal)

    def _says(self, state: int) -> bool:
        p = self._params
        if self._rule == "always":
            return True
        if self._rule == "early":
            return self.decisions < p.n_steps
        if self._rule == "random":
            return bool(self._rng.random() < p.rate)
        if self._rule == "importance":  # KL[theta_s || uniform] = log 4 + sum theta log theta
            return math.log(N_ACTIONS) + self.tables.neg_entropy_list[state] >= p.threshold
        # mistake correcting: the action just taken was unlikely under the prior
        if self._last is None:
            return False
        s, a = self._last
        return self.tables.theta_flat[s * N_ACTIONS + a] < p.threshold


def make_advisor(
    strategy: str,
    tables: AdviceTables,
    kappa: float = DEFAULT_KAPPA,
    window: int = DEFAULT_WINDOW,
    params: StrategyParams | None = None,
    goal_priors: GoalPriors | None = None,
    guide_map: GuideMap | None = None,
) -> Advisor:
    """An advisor for ``strategy`` (one of :data:`STRATEGIES`); ``guide`` needs ``guide_map``."""
    if strategy == "paper":
        return Advisor(tables, kappa, window)
    if strategy == "goal_aware":
        if goal_priors is None:
            raise ValueError("goal_aware advice needs the experts' goals (goal priors)")
        beta = (params or StrategyParams()).beta
        return GoalAwareAdvisor(tables, goal_priors, kappa, window, beta)
    if strategy == "guide":
        if guide_map is None:
            raise ValueError("guide advice needs the map's destinations (a guide map)")
        return GuideAdvisor(tables, guide_map, kappa, window, params=guide_params(params))
    if strategy in RULES:
        return RuleAdvisor(tables, strategy, kappa, window, params)
    raise ValueError(f"unknown strategy {strategy!r}: use one of {', '.join(STRATEGIES)}")


def guide_params(params: StrategyParams | None) -> GuideParams:
    p = params or StrategyParams()
    return GuideParams(p.p_lost, p.slack, p.spread)
