"""The teacher-student literature's budgeted rules (Torrey & Taylor, AAMAS 2013) and ``always``:
the paper's window and posterior, with another rule deciding when to advise.

Each rule gives theta_s as its advice and reports the paper's KL and P(M1 | H) for comparison,
whatever decided; each counts kappa per piece of advice. One class a rule; their entries are
in :mod:`app.strategies`.
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np

from app.advice.advisor import DEFAULT_KAPPA, DEFAULT_WINDOW, Advisor, Decision
from app.advice.models import AdviceTables
from app.advice.params import StrategyParams


class RuleAdvisor(Advisor):
    """The paper's window and posterior; :meth:`says` decides when to advise."""

    #: the parameters of :class:`StrategyParams` the rule reads
    reads: ClassVar[tuple[str, ...]] = ()

    __slots__ = ("_last", "_params", "_rng")

    def __init__(
        self,
        tables: AdviceTables,
        kappa: float = DEFAULT_KAPPA,
        window: int = DEFAULT_WINDOW,
        params: StrategyParams | None = None,
    ):
        self._params = params or StrategyParams()
        self._params.check()
        self._last: tuple[int, int] | None = None
        self._rng: np.random.Generator | None = None
        super().__init__(tables, kappa, window)

    def params(self) -> dict[str, int | float]:
        return self._params.values(self.reads)

    def reset(self) -> None:
        """Forget the history, the cost and the last move (a new explorer is advised as a
        fresh advisor would advise it)."""
        super().reset()
        self._last = None

    def observe(self, state: int, action: int, next_state: int) -> Decision:
        self.append(state, action)
        self._last = (state, action)
        return self.decide(next_state)

    def decide(self, state: int) -> Decision:
        kl, p_normal = self.divergence(state)
        t = self.tables
        b, th = state * t.n_actions, t.theta_flat
        row = tuple(th[b : b + t.n_actions])
        return self.record(state, self.says(state), row, kl, p_normal)

    def says(self, state: int) -> bool:
        """Whether to advise the explorer now at ``state``."""
        raise NotImplementedError


class AlwaysAdvisor(RuleAdvisor):
    """Advises at every decision."""

    strategy = "always"
    __slots__ = ()

    def says(self, state: int) -> bool:
        return True


class EarlyAdvisor(RuleAdvisor):
    """Advises at the first ``n_steps`` decisions of a session."""

    strategy = "early"
    reads = ("n_steps",)
    __slots__ = ()

    def says(self, state: int) -> bool:
        return self.decisions < self._params.n_steps


class ImportanceAdvisor(RuleAdvisor):
    """Advises where the prior is sure: KL[theta_s || uniform] >= ``threshold``, whatever the
    explorer does (the KL in four actions' units: ``AdviceTables.kl_scale``)."""

    strategy = "importance"
    reads = ("threshold",)
    __slots__ = ()

    def says(self, state: int) -> bool:
        # KL[theta_s || uniform] = log A + sum theta log theta (kl_scale 1.0 for four)
        t = self.tables
        kl = (math.log(t.n_actions) + t.neg_entropy_list[state]) * t.kl_scale
        return kl >= self._params.threshold


class MistakeAdvisor(RuleAdvisor):
    """Mistake correcting: advises after an action the prior thought unlikely,
    theta_s(a) < ``threshold``."""

    strategy = "mistake"
    reads = ("threshold",)
    __slots__ = ()

    def says(self, state: int) -> bool:
        if self._last is None:
            return False
        s, a = self._last
        return self.tables.theta_flat[s * self.tables.n_actions + a] < self._params.threshold


class RandomAdvisor(RuleAdvisor):
    """Advises with probability ``rate`` at each decision, from its own generator (seeded with
    ``seed`` at every reset, so a new explorer sees the same draws)."""

    strategy = "random"
    reads = ("rate", "seed")
    __slots__ = ()

    def reset(self) -> None:
        super().reset()
        self._rng = np.random.default_rng(self._params.seed)

    def says(self, state: int) -> bool:
        assert self._rng is not None  # made at every reset
        return bool(self._rng.random() < self._params.rate)


#: the rules by name
RULES: dict[str, type[RuleAdvisor]] = {
    cls.strategy: cls
    for cls in (EarlyAdvisor, ImportanceAdvisor, MistakeAdvisor, RandomAdvisor, AlwaysAdvisor)
}
