"""What a strategy is, as one entry of the table (:mod:`app.strategies.table`).

An entry says: its name and what it does in plain words; the parameters it reads (their
defaults, bounds and meaning are :class:`~app.advice.params.StrategyParams`'); what it needs of
a domain besides the prior (:class:`Need`); its readable advisor; the form a service runs
(windows of pair keys, batches compiled; none: the readable advisor, one call an event); the
code of its compiled form in :mod:`app.kernels` (none: the experiments run the readable loop);
the cost level the experiments sweep; the largest kappa at which it still advises; and what its
advisor believes of the explorer in plain words, with the destination its advice leads to
(:mod:`app.strategies.beliefs`), which the pages show.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields, replace
from typing import Any

from app.advice.advisor import (
    DEFAULT_KAPPA,
    DEFAULT_STRATEGY,
    DEFAULT_WINDOW,
    Advisor,
    check_kappa_window,
)
from app.advice.guide import GuideMap
from app.advice.models import AdviceTables
from app.advice.params import StrategyParams
from app.advice.priors import GoalPriors
from app.strategies.beliefs import Beliefs, paper_beliefs


class Need(enum.Enum):
    """What a strategy reads of a domain besides its prior's tables."""

    #: the experts' counts per destination (:class:`~app.advice.priors.GoalPriors`)
    GOAL_PRIORS = "the experts' goals (goal priors)"
    #: distances and routes to every destination, with the experts' goal counts
    #: (:class:`~app.advice.guide.GuideMap`; made with the goal priors)
    GUIDE_MAP = "the map's destinations (a guide map)"


@dataclass(frozen=True)
class DomainData:
    """What an advisor is made from besides its settings: the tables of the prior it reads and
    what its strategy needs (None where not built)."""

    tables: AdviceTables
    goal_priors: GoalPriors | None = None
    guide_map: GuideMap | None = None

    def has(self, need: Need) -> bool:
        return (self.goal_priors if need is Need.GOAL_PRIORS else self.guide_map) is not None


@dataclass(frozen=True, slots=True)
class AdvisorSettings:
    """One advisor's settings, checked (:meth:`Strategy.settings` makes them): the strategy,
    the cost of a piece of advice, the window and the strategy's parameters."""

    strategy: str = DEFAULT_STRATEGY
    kappa: float = DEFAULT_KAPPA
    window: int = DEFAULT_WINDOW
    params: StrategyParams = field(default_factory=StrategyParams)


#: makes an advisor of a strategy from a domain's data and checked settings
Factory = Callable[[DomainData, AdvisorSettings], Advisor]


@dataclass(frozen=True)
class Level:
    """The cost level an experiment sweeps for a strategy: ``kappa`` or one of its parameters,
    and the values swept unless an experiment is told others."""

    param: str
    values: tuple[float, ...]


@dataclass(frozen=True)
class Strategy:
    """One advising strategy (see the module text)."""

    name: str
    summary: str  # what it does, in plain words (the API, the pages, --help)
    readable: Factory
    reads: tuple[str, ...] = ()
    needs: frozenset[Need] = frozenset()
    served: Factory | None = None
    kernel: int | None = None
    learns: bool = False  # its compiled form also runs in app.kernels.q_learning
    level: Level | None = None
    #: the largest kappa at which it can still advise (None: kappa prices advice, the rule
    #: decides without it)
    kappa_max: float | None = None
    #: whether a session keeps a value per destination and pair of its window
    goal_window: Callable[[StrategyParams], bool] = field(default=lambda _p: False)
    #: what a piece of its advice is, in plain words (the pages show it)
    advice: str = (
        "The experts' action prior θ for this cell: how often people who know the building "
        "moved each way here."
    )
    #: what its advisor believes of the explorer (figures in plain words, each with its
    #: symbol and a tone; the destination its advice leads to), from the advisor and the
    #: P(M1|H) of its last decision: the session answers carry it to the pages
    beliefs: Callable[[Advisor, float], Beliefs] = paper_beliefs
    #: the destination (an index into the domain's goals) its advice leads to now, if its
    #: advice leads to destinations (None: it does not): a one-event answer that advises
    #: says it
    leads_to: Callable[[Advisor], int | None] | None = None

    def __post_init__(self) -> None:
        known = {f.name for f in fields(StrategyParams)}
        unknown = sorted(set(self.reads) - known)
        if unknown:
            raise ValueError(f"strategy {self.name}: unknown parameters {', '.join(unknown)}")
        if self.level is not None and self.level.param not in ("kappa", *self.reads):
            raise ValueError(f"strategy {self.name}: its level {self.level.param} is not read")

    # ---- settings -----------------------------------------------------------------------
    def settings(
        self,
        kappa: float = DEFAULT_KAPPA,
        window: int = DEFAULT_WINDOW,
        params: StrategyParams | Mapping[str, int | float] | None = None,
    ) -> AdvisorSettings:
        """Checked settings: ValueError names a parameter this strategy does not read (when
        ``params`` is a mapping of the given ones), a value out of bounds, kappa or window."""
        check_kappa_window(kappa, window)
        if params is None or isinstance(params, StrategyParams):
            checked = params or StrategyParams()
        else:
            unread = sorted(set(params) - set(self.reads))
            if unread:
                reads = ", ".join(self.reads) or "no parameters"
                given = ", ".join(unread)
                raise ValueError(f"{self.name} does not read {given} (it reads {reads})")
            checked = replace(StrategyParams(), **dict[str, Any](params))
        checked.check()
        return AdvisorSettings(self.name, float(kappa), int(window), checked)

    def in_force(self, params: StrategyParams) -> dict[str, int | float]:
        """The parameters this strategy reads, with their values."""
        return params.values(self.reads)

    def at_level(self, settings: AdvisorSettings, value: float) -> AdvisorSettings:
        """``settings`` with the swept cost level (:attr:`level`) at ``value``."""
        if self.level is None:
            return settings
        if self.level.param == "kappa":
            return self.settings(value, settings.window, settings.params)
        whole = type(getattr(settings.params, self.level.param)) is int
        level: dict[str, Any] = {self.level.param: int(value) if whole else value}
        params = replace(settings.params, **level)
        return self.settings(settings.kappa, settings.window, params)

    # ---- advisors -----------------------------------------------------------------------
    def missing(self, data: DomainData) -> list[Need]:
        """What this strategy needs that ``data`` lacks."""
        return [n for n in sorted(self.needs, key=lambda n: n.name) if not data.has(n)]

    def _checked(self, data: DomainData, settings: AdvisorSettings) -> None:
        if settings.strategy != self.name:
            raise ValueError(f"settings of {settings.strategy} given to {self.name}")
        lacking = self.missing(data)
        if lacking:
            raise ValueError(f"{self.name} advice needs {lacking[0].value}")

    def advisor(self, data: DomainData, settings: AdvisorSettings) -> Advisor:
        """Its readable advisor (ValueError when ``data`` lacks what it needs)."""
        self._checked(data, settings)
        return self.readable(data, settings)

    def service_advisor(self, data: DomainData, settings: AdvisorSettings) -> Advisor:
        """The advisor a service runs: its served form, else the readable one."""
        self._checked(data, settings)
        return (self.served or self.readable)(data, settings)

    def describe(self) -> dict[str, Any]:
        """The entry as plain data (what ``GET /strategies`` answers)."""
        meta = {f.name: f for f in fields(StrategyParams)}
        params = []
        for name in self.reads:
            m = meta[name].metadata
            high = None if m["high"] == math.inf else m["high"]
            params.append({
                "name": name, "default": meta[name].default, "low": m["low"], "high": high,
                "description": m["doc"],
            })  # fmt: skip
        return {
            "name": self.name, "summary": self.summary, "advice": self.advice, "params": params,
            "needs": sorted(n.name.lower() for n in self.needs), "kappa_max": self.kappa_max,
            "compiled": self.kernel is not None or self.served is not None,
        }  # fmt: skip
