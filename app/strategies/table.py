"""The advising strategies, one entry each (:class:`~app.strategies.entry.Strategy`), in one
table: the service's routes, websocket and MQTT bridge, the Redis codec, the experiments and
the command line read it, and none of them asks a strategy's name for anything else.

``paper`` is the rule of eq. (6). ``goal_aware`` narrows the paper's advice by a posterior over
the experts' goals (:mod:`app.advice.goals`); ``guide`` leads explorers that look lost to a
destination of the map (:mod:`app.advice.guide`, beyond the paper: it reads the map and its
destinations). ``early``, ``importance``, ``mistake``, ``random`` and ``always`` are the
budgeted rules of the teacher-student literature (:mod:`app.advice.rules`). Every one costs
kappa a piece of advice.

A new strategy is one :func:`register` call (docs/ARCHITECTURE.md, "A new strategy").
"""

from __future__ import annotations

import math

from app import kernels
from app.advice.advisor import DEFAULT_KAPPA, DEFAULT_WINDOW, Advisor
from app.advice.goals import GoalAwareAdvisor
from app.advice.guide import (
    LEAD_PRICE,
    LEAD_SWEEPS,
    LEAD_TOL,
    GuideAdvisor,
    GuideMap,
    GuideParams,
)
from app.advice.models import AdviceTables
from app.advice.params import StrategyParams
from app.advice.priors import GoalPriors
from app.advice.rules import (
    AlwaysAdvisor,
    EarlyAdvisor,
    ImportanceAdvisor,
    MistakeAdvisor,
    RandomAdvisor,
    RuleAdvisor,
)
from app.arrays import Float32Array, IntArray
from app.strategies.beliefs import guide_beliefs, guide_target
from app.strategies.entry import AdvisorSettings, DomainData, Level, Need, Strategy
from app.strategies.stream import StreamAdvisor, StreamGoalAware, StreamGuide, keyed

#: the largest KL[theta_s || P(A | s, H)] of the paper's two models: KL[theta_s || uniform]
KL_MAX = math.log(4.0)
#: guide's value is the KL of its advice (at most about 1.19 nats at the default spread)
#: weighted by the stake (at most 2): it stays below about 2.4
GUIDE_KAPPA_MAX = 2.4

STRATEGIES: dict[str, Strategy] = {}


def register(entry: Strategy) -> Strategy:
    """Add ``entry`` to the table (ValueError if its name is taken)."""
    if entry.name in STRATEGIES:
        raise ValueError(f"a strategy named {entry.name!r} is registered already")
    STRATEGIES[entry.name] = entry
    return entry


def unregister(name: str) -> None:
    """Remove the strategy ``name`` (tests that register their own)."""
    STRATEGIES.pop(name, None)


def names() -> tuple[str, ...]:
    """The strategies' names, in the order they were registered."""
    return tuple(STRATEGIES)


def get(name: str) -> Strategy:
    """The entry of ``name`` (ValueError naming the known ones)."""
    entry = STRATEGIES.get(name)
    if entry is None:
        raise ValueError(f"unknown strategy {name!r}: use one of {', '.join(STRATEGIES)}")
    return entry


def compiled_leads(next_state: IntArray, n_open: IntArray, dist: IntArray) -> Float32Array:
    """A guide map's lead values (``GuideMap.of``'s ``leads``), compiled without the GIL:
    the sweeps of :func:`app.advice.guide.lead_values`."""
    return kernels.guide_lead_values(next_state, n_open, dist, LEAD_PRICE, LEAD_TOL, LEAD_SWEEPS)


def make_advisor(
    strategy: str, tables: AdviceTables, kappa: float = DEFAULT_KAPPA,
    window: int = DEFAULT_WINDOW, params: StrategyParams | None = None,
    goal_priors: GoalPriors | None = None, guide_map: GuideMap | None = None,
) -> Advisor:  # fmt: skip
    """The readable advisor of ``strategy`` on ``tables`` (with the goal priors and the guide
    map the strategies that need them read); ValueError says what is wrong or missing."""
    entry = get(strategy)
    data = DomainData(tables, goal_priors, guide_map)
    return entry.advisor(data, entry.settings(kappa, window, params))


def _paper(data: DomainData, s: AdvisorSettings) -> Advisor:
    return Advisor(data.tables, s.kappa, s.window)


def _paper_served(data: DomainData, s: AdvisorSettings) -> Advisor:
    return StreamAdvisor(data.tables, s.kappa, s.window)


def _goal_aware(data: DomainData, s: AdvisorSettings) -> Advisor:
    assert data.goal_priors is not None  # the entry's needs are checked first
    return GoalAwareAdvisor(data.tables, data.goal_priors, s.kappa, s.window, s.params.beta)


def _goal_aware_served(data: DomainData, s: AdvisorSettings) -> Advisor:
    assert data.goal_priors is not None
    return StreamGoalAware(data.tables, data.goal_priors, s.kappa, s.window, s.params.beta)


def _guide(data: DomainData, s: AdvisorSettings) -> Advisor:
    assert data.guide_map is not None
    p = GuideParams.of(s.params)
    return GuideAdvisor(data.tables, data.guide_map, s.kappa, s.window, params=p)


def _guide_served(data: DomainData, s: AdvisorSettings) -> Advisor:
    assert data.guide_map is not None
    p = GuideParams.of(s.params)
    return StreamGuide(data.tables, data.guide_map, s.kappa, s.window, params=p)


def _rule(
    name: str, summary: str, cls: type[RuleAdvisor], kernel: int, level: Level | None
) -> Strategy:
    served = keyed(cls)
    return Strategy(
        name, summary,
        readable=lambda data, s: cls(data.tables, s.kappa, s.window, s.params),
        reads=cls.reads,
        served=lambda data, s: served(data.tables, s.kappa, s.window, s.params),
        kernel=kernel, level=level,
    )  # fmt: skip


register(Strategy(
    "paper",
    "The paper's rule: advise the experts' prior theta_s where the explorer's expected "
    "behaviour is far from it, KL[theta_s || P(A|s,H)] >= kappa.",
    readable=_paper, served=_paper_served, kernel=kernels.PAPER, learns=True,
    level=Level("kappa", (0.25, 0.5, 0.75, 1.0)), kappa_max=KL_MAX,
))  # fmt: skip
register(Strategy(
    "goal_aware",
    "The paper's rule with the prior narrowed by a posterior over the experts' goals "
    "(goals the explorer passed are ruled out).",
    readable=_goal_aware, reads=("beta",), needs=frozenset({Need.GOAL_PRIORS}),
    served=_goal_aware_served, kernel=kernels.GOAL_AWARE,
    level=Level("kappa", (0.0, 0.25, 0.5, 0.75, 1.0)), kappa_max=KL_MAX,
    goal_window=lambda p: p.beta > 0.0,
    advice="The experts' prior for this cell, narrowed to the destinations you may still be "
    "heading for.",
))  # fmt: skip
for _name, _summary, _cls, _kernel, _level in (
    ("early", "Advise at the first n_steps decisions of a session.", EarlyAdvisor,
     kernels.EARLY, Level("n_steps", (20, 100, 500, 2000))),
    ("importance", "Advise where the prior is sure of the way, KL[theta_s || uniform] >= "
     "threshold, whatever the explorer does.", ImportanceAdvisor, kernels.IMPORTANCE,
     Level("threshold", (0.25, 0.5, 0.75, 1.0))),
    ("mistake", "Advise after a move the prior thought unlikely, theta_s(a) < threshold.",
     MistakeAdvisor, kernels.MISTAKE, Level("threshold", (0.05, 0.15, 0.25, 0.5))),
    ("random", "Advise at random, with probability rate at each step.", RandomAdvisor,
     kernels.RANDOM_RULE, Level("rate", (0.02, 0.05, 0.1, 0.2, 0.4))),
    ("always", "Advise at every step.", AlwaysAdvisor, kernels.ALWAYS, None),
):  # fmt: skip
    register(_rule(_name, _summary, _cls, _kernel, _level))
register(Strategy(
    "guide",
    "Beyond the paper, the one to deploy in a building: leads explorers that look lost to a "
    "destination of the map along shortest paths, advice in every cell, ruling out "
    "destinations passed.",
    readable=_guide, reads=("p_lost", "slack", "spread"), needs=frozenset({Need.GUIDE_MAP}),
    served=_guide_served, kernel=kernels.GUIDE, learns=True,
    level=Level("kappa", (0.1, 0.25, 0.5, 0.75, 1.0, 1.25, 1.4, 1.6)), kappa_max=GUIDE_KAPPA_MAX,
    advice="The way to the destination you most likely want (or the nearest one left): the "
    "moves along a shortest path there.",
    beliefs=guide_beliefs, leads_to=guide_target,
))  # fmt: skip
