"""Advising strategies: when to speak, with the paper's payload and cost accounting.

``paper`` is the rule of eq. (6). The others are the teacher-student literature's budgeted rules
(early, importance, mistake correcting, random) and ``always``, plus ``goal_aware``
(:mod:`app.advice.goals`). All give theta_s as advice, count kappa per piece of advice and report
the paper's KL and P(M1 | H) for comparison, whatever rule decided.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from app.advice.advisor import DEFAULT_KAPPA, DEFAULT_WINDOW, Advisor, Decision
from app.advice.goals import GoalAwareAdvisor, GoalPriors
from app.advice.models import AdviceTables
from app.domain.grid import N_ACTIONS

STRATEGIES = ("paper", "goal_aware", "early", "importance", "mistake", "random", "always")


@dataclass(frozen=True)
class StrategyParams:
    """Parameters of every strategy; each strategy reads only its own."""

    n_steps: int = 20  # early: advise during the first n_steps decisions
    threshold: float = 0.5  # importance: KL[theta_s || u] >= t; mistake: theta_s(a) < t
    rate: float = 0.1  # random: probability of advising per step
    beta: float = 0.0  # goal_aware: weight of per-goal likelihoods (0: ruling out only)
    seed: int = 0  # random: seed of its generator

    def check(self) -> None:
        if self.n_steps < 0:
            raise ValueError(f"n_steps must be >= 0, got {self.n_steps}")
        for name in ("threshold", "rate", "beta"):
            v = getattr(self, name)
            if not math.isfinite(v) or v < 0:
                raise ValueError(f"{name} must be a finite number >= 0, got {v!r}")
        if self.rate > 1 or self.beta > 1:
            raise ValueError("rate and beta must be at most 1")


class RuleAdvisor(Advisor):
    """The paper's window and posterior, with another rule deciding when to advise."""

    __slots__ = ("_last", "_rng", "params", "rule")

    def __init__(
        self,
        tables: AdviceTables,
        rule: str,
        kappa: float = DEFAULT_KAPPA,
        window: int = DEFAULT_WINDOW,
        params: StrategyParams | None = None,
    ):
        if rule not in ("early", "importance", "mistake", "random", "always"):
            raise ValueError(f"unknown rule {rule!r}")
        self.rule = rule
        self.params = params or StrategyParams()
        self.params.check()
        self._last: tuple[int, int] | None = None
        self._rng = np.random.default_rng(self.params.seed)
        super().__init__(tables, kappa, window)

    def reset(self) -> None:
        """Forget the history, the cost, the last move, and restart the random rule's draws
        (a new explorer is advised as a fresh advisor would advise it)."""
        super().reset()
        self._last = None
        self._rng = np.random.default_rng(self.params.seed)

    def observe(self, state: int, action: int, next_state: int) -> Decision:
        self.append(state, action)
        self._last = (state, action)
        return self.decide(next_state)

    def decide(self, state: int) -> Decision:
        kl, p_normal = self.divergence(state)
        th = self.tables.theta_flat
        b = state * N_ACTIONS
        row = (th[b], th[b + 1], th[b + 2], th[b + 3])
        return self.record(state, self._says(state, row), row, kl, p_normal)

    def _says(self, state: int, row: tuple[float, float, float, float]) -> bool:
        p = self.params
        if self.rule == "always":
            return True
        if self.rule == "early":
            return self.decisions < p.n_steps
        if self.rule == "random":
            return bool(self._rng.random() < p.rate)
        if self.rule == "importance":  # KL[theta_s || uniform] = log 4 + sum theta log theta
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
) -> Advisor:
    """An advisor for ``strategy`` (one of :data:`STRATEGIES`)."""
    if strategy == "paper":
        return Advisor(tables, kappa, window)
    if strategy == "goal_aware":
        if goal_priors is None:
            raise ValueError("goal_aware advice needs the experts' goals (goal priors)")
        beta = (params or StrategyParams()).beta
        return GoalAwareAdvisor(tables, goal_priors, kappa, window, beta)
    if strategy in STRATEGIES:
        return RuleAdvisor(tables, strategy, kappa, window, params)
    raise ValueError(f"unknown strategy {strategy!r}: use one of {', '.join(STRATEGIES)}")
