"""Typed wrappers around the compiled kernels (:mod:`app.kernels`): one call, one task.

>>> sim = Simulator(domain, AdviceTables.paper(prior.theta()))
>>> run = sim.fixed("random", goal, np.random.default_rng(0), advised=True, kappa=0.5)
>>> run.success, run.steps, run.advice_count

Every advising strategy of :mod:`app.strategies` with a compiled form runs in the same kernel
(``strategy=``; one without runs the reference loop); ``goal_aware`` and ``guide`` need the
per-goal counts (``goal_priors``). A visitor's compliance, position noise and sight are
keywords of :meth:`Simulator.fixed` (defaults: the paper's explorer). From equal generators a
run makes the draws, moves and decisions of the reference loop
(:func:`app.agents.episodes.run_episode`), which ``tests/agents/test_simulate.py`` checks.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from app import kernels, strategies
from app.advice.advisor import DEFAULT_KAPPA, DEFAULT_STRATEGY, DEFAULT_WINDOW, resync_period
from app.advice.guide import GuideError, GuideMap, GuideParams, kernel_params
from app.advice.models import AdviceTables
from app.advice.params import StrategyParams
from app.advice.priors import GoalPriors
from app.agents.episodes import run_episode
from app.agents.explorers import FEEDS, check_walker, make_explorer
from app.agents.qlearning import TIE_RULES
from app.arrays import BoolArray, FloatArray, IntArray
from app.domain.building import Building, Domain
from app.domain.paths import optimal_actions
from app.strategies import AdvisorSettings, DomainData, Need, Strategy, compiled_leads

#: the kernels' codes for the explorers and the strategies, by name
EXPLORER_CODES = {
    "random": kernels.RANDOM, "random-avoid": kernels.RANDOM_AVOID, "left": kernels.LEFT,
    "bug": kernels.BUG, "optimal": kernels.OPTIMAL, "corridor": kernels.CORRIDOR,
    "straight": kernels.STRAIGHT,
}  # fmt: skip
_NOTHING = np.zeros(0)
_DEFAULTS = StrategyParams()
_UNUSED_RNG = np.random.default_rng(0)  # the random rule's generator, for the other rules
_NO_GUIDE: kernels.GuideArrays = (
    np.zeros((0, 4), dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros((0, 2), dtype=np.int64),
    np.zeros((0, 0), dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros((0, 0)),
    np.zeros((0, 0), dtype=np.int64), np.zeros((0, 0), dtype=np.int64),
    np.zeros(0, dtype=np.int64), np.zeros((0, 0), dtype=np.uint8), True, 0,
    np.zeros((0, 0, 4), dtype=np.float32),
)  # fmt: skip
_NO_GOALS = np.zeros(0, dtype=np.int64)
_NO_OPTIMAL = np.zeros((0, 4), dtype=np.bool_)  # read by the optimal explorer only
#: what the episode kernel reads of the domain (:func:`app.kernels.episode`'s ``world``)
World = tuple[IntArray, BoolArray, IntArray, BoolArray, IntArray]
_UNREAD_RNG = np.random.default_rng(0)  # the readings' generator where nothing is misread


def guide_arrays(window: int, params: StrategyParams) -> kernels.GuideParams:
    """guide's parameters as the kernels read them."""
    return kernel_params(window, GuideParams.of(params))


@dataclass(frozen=True)
class FixedRun:
    """One task of a fixed-policy explorer; per-step arrays have one entry per move."""

    success: bool
    steps: int
    advice_count: int
    benefit: float  # sum of the deciding KL at advised states (the paper's KL for peer rules)
    goals_ruled_out: int  # goal_aware only (0 otherwise)
    states: IntArray  # the explorer's cell before each move (the advisor may read another)
    p_normal: FloatArray  # P(M1 | H) at each decision the explorer acted on (if recorded)
    advise: BoolArray  # the advisor's decision there (given to the explorer only if advised)

    @property
    def advice_per_100(self) -> float:
        return 100.0 * self.advice_count / max(1, self.steps)


@dataclass(frozen=True)
class QParams:
    """Q-learner settings (see app.agents.qlearning)."""

    alpha: float = 0.1
    gamma: float = 0.95
    epsilon: float = 0.1
    ties: str = "advice"

    def __post_init__(self) -> None:
        if not (0 < self.alpha <= 1 and 0 <= self.gamma <= 1 and 0 <= self.epsilon <= 1):
            raise ValueError(
                "need 0 < alpha <= 1, 0 <= gamma <= 1, 0 <= epsilon <= 1; got "
                f"alpha={self.alpha}, gamma={self.gamma}, epsilon={self.epsilon}"
            )
        if self.ties not in TIE_RULES:
            raise ValueError(f"ties must be one of {', '.join(TIE_RULES)}, got {self.ties!r}")


@dataclass(frozen=True)
class LearningRun:
    """Episodes of one Q-learning task; one entry per episode."""

    steps: IntArray
    success: BoolArray
    advice_count: IntArray
    decisions: IntArray
    p_normal_mean: FloatArray
    q: FloatArray  # the learned table

    @property
    def reward(self) -> FloatArray:
        out: FloatArray = np.where(self.success, 1000.0, 0.0)
        return out


def goal_tables(domain: Domain, priors: GoalPriors | None) -> kernels.GoalTables:
    """The per-goal counts as the kernels read them (no goals when ``priors`` is None)."""
    s = domain.n_states
    of_state = np.full(s, -1, dtype=np.int64)
    if priors is None:
        empty = np.zeros((domain.n_actions * s, 0))
        return of_state, 1.0, np.zeros(domain.n_actions * s), empty, empty
    g = priors.n_goals
    of_state[list(priors.goals)] = np.arange(g)
    return (
        of_state,
        priors.alpha0,
        np.ascontiguousarray(priors.unknown_counts.reshape(-1)),
        np.ascontiguousarray(priors.goal_counts.reshape(g, -1).T),
        np.ascontiguousarray(priors.goal_log_theta().reshape(g, -1).T),
    )


class Simulator:
    """A domain, the advisor's tables (and the per-goal counts goal-aware advice narrows theta
    with), prepared once for many runs: compiled where the strategy has a compiled form
    (:attr:`Strategy.kernel`), else the readable loop with its readable advisor."""

    def __init__(self, domain: Domain, tables: AdviceTables, goal_priors: GoalPriors | None = None):
        if tables.n_states != domain.n_states:
            raise ValueError(f"tables have {tables.n_states} states, the maze {domain.n_states}")
        if tables.n_actions != domain.n_actions:
            raise ValueError(
                f"tables of {tables.n_actions} actions, the maze has {domain.n_actions}"
            )
        if goal_priors is not None and goal_priors.n_states != domain.n_states:
            raise ValueError("goal priors and maze must have the same states")
        self.domain = domain
        self.tables = tables
        self.goal_priors = goal_priors
        self.goals = goal_tables(domain, goal_priors)
        self._no_guide: GuideError | None = None  # why the map cannot be guided
        try:
            self.guide: GuideMap | None = GuideMap.of(domain, goal_priors, leads=compiled_leads)
        except GuideError as exc:
            self.guide, self._no_guide = None, exc
        self.data = DomainData(tables, goal_priors, self.guide)
        self.next_state = np.ascontiguousarray(domain.next_state)
        # writeable as a one-floor map's are: numba compiles read-only arrays anew
        self.open_moves = np.require(domain.open_moves, requirements=["C", "W"])
        self.cells = np.require(domain.cells, requirements=["C", "W"])
        self.stops = (  # the bug's way to another floor; not read on one floor
            np.require(domain.nearest_stops, requirements=["C", "W"])
            if isinstance(domain, Building) else np.zeros((0, 2), dtype=np.int64)
        )  # fmt: skip
        self._worlds: dict[int, World] = {}

    def settings(
        self, strategy: str, kappa: float, window: int, params: StrategyParams | None
    ) -> tuple[Strategy, AdvisorSettings]:
        """The entry of ``strategy`` and checked settings; ValueError when this domain lacks
        what it needs (a map that cannot be guided says why)."""
        entry = strategies.get(strategy)
        settings = entry.settings(kappa, window, params)
        lacking = entry.missing(self.data)
        if lacking:
            if Need.GUIDE_MAP in lacking and self._no_guide is not None:
                raise self._no_guide
            raise ValueError(f"{strategy} advice needs {lacking[0].value}")
        return entry, settings

    def _guide(
        self, entry: Strategy, settings: AdvisorSettings
    ) -> tuple[kernels.GuideArrays, kernels.GuideParams, IntArray]:
        params = guide_arrays(settings.window, settings.params)
        if Need.GUIDE_MAP in entry.needs and self.guide is not None:
            goals = np.array(self.guide.goals, dtype=np.int64)
            return self.guide.arrays, params, goals
        return _NO_GUIDE, params, _NO_GOALS

    def optimal(self, goal: int) -> BoolArray:
        return self._world(goal)[3]

    def _walls(self) -> World:
        """The world of every explorer but the optimal one (which alone reads the optimal
        moves to its goal): no search per goal, so any free cell can be a goal."""
        return (self.next_state, self.open_moves, self.cells, _NO_OPTIMAL, self.stops)

    def _world(self, goal: int) -> World:
        """What the episode kernel reads of the maze for ``goal`` (made once per goal)."""
        if goal not in self._worlds:
            optimal = np.ascontiguousarray(optimal_actions(self.domain, goal))
            self._worlds[goal] = (self.next_state, self.open_moves, self.cells, optimal, self.stops)
        return self._worlds[goal]

    def fixed(
        self,
        explorer: str,
        goal: int,
        rng: np.random.Generator,
        *,
        advised: bool,
        strategy: str = DEFAULT_STRATEGY,
        kappa: float = DEFAULT_KAPPA,
        window: int = DEFAULT_WINDOW,
        params: StrategyParams | None = None,
        rule_rng: np.random.Generator | None = None,
        max_steps: int = 5000,
        record_p: bool = True,
        compliance: float = 1.0,
        noise: float = 0.0,
        sight: int = 0,
        seen_rng: np.random.Generator | None = None,
        feed: str = "events",
        jump: int = 1,
    ) -> FixedRun:
        """One task of ``explorer`` (a name in WALKERS) from the start cell to ``goal`` (any
        free cell but the start), watched by the advisor of ``strategy``. ``rule_rng`` is the
        ``random`` rule's own generator (default: seeded with ``params.seed``, as the reference
        advisor seeds its own). A visitor (:class:`app.agents.explorers.Visitor`): takes a
        piece of advice with probability ``compliance``; is read one cell off with probability
        ``noise`` (drawn from ``seen_rng``, needed then); walks to its goal once it is in sight
        within ``sight`` cells (0: never). ``feed="positions"`` feeds the readings (up to
        ``jump`` moves off) as the service's /positions walks them: the reference loop
        (:func:`app.agents.episodes.run_episode` with ``positions``) with the service's
        advisor; without ``advised`` the compiled run (the explorer's moves and draws are the
        same, the advisor's watching is not reported)."""
        check_walker(explorer, self.domain)
        entry, settings = self.settings(strategy, kappa, window, params)
        if max_steps < 1:
            raise ValueError(f"max_steps must be at least 1, got {max_steps}")
        if not (0 <= goal < self.domain.n_states) or goal == self.domain.start:
            raise ValueError(f"goal must be a free cell other than the start, got {goal}")
        for name, v in (("compliance", compliance), ("noise", noise)):
            if not (math.isfinite(v) and 0.0 <= v <= 1.0):
                raise ValueError(f"{name} must be a number from 0 to 1, got {v}")
        if sight < 0:
            raise ValueError(f"sight must be >= 0, got {sight}")
        if noise > 0.0 and seen_rng is None:
            raise ValueError("position noise needs seen_rng, the readings' generator")
        if feed not in FEEDS or jump < 1 or (jump > 1 and feed != "positions"):
            raise ValueError(
                f"feed must be one of {', '.join(FEEDS)}, and jump >= 1 (> 1 with positions only)"
            )
        visitor = (float(compliance), float(noise), int(sight))
        readings = _UNREAD_RNG if seen_rng is None else seen_rng
        if feed == "positions" and advised:  # unadvised, what the advisor is fed changes nothing
            return self._fixed_readable(
                entry,
                settings,
                explorer,
                goal,
                rng,
                advised,
                max_steps,
                visitor,
                readings,
                positions=True,
                jump=jump,
            )
        if entry.kernel is None:
            return self._fixed_readable(
                entry, settings, explorer, goal, rng, advised, max_steps, visitor, readings
            )
        p = settings.params
        if rule_rng is None:  # a fresh generator only where the random rule draws from it
            rule_rng = np.random.default_rng(p.seed) if "seed" in entry.reads else _UNUSED_RNG
        states = np.empty(max_steps, dtype=np.int64)
        p_out = np.empty(max_steps) if record_p else _NOTHING
        advise = np.empty(max_steps, dtype=np.bool_)
        world = self._world(goal) if explorer == "optimal" else self._walls()
        steps, success, count, benefit, ruled_out = kernels.episode(
            EXPLORER_CODES[explorer],
            visitor,
            world,
            self.domain.start,
            goal,
            max_steps,
            advised,
            entry.kernel,
            settings.kappa,
            settings.window,
            resync_period(settings.window),
            (int(p.n_steps), float(p.threshold), float(p.rate), float(p.beta)),
            self.tables.arrays,
            self.goals,
            self._guide(entry, settings),
            rng,
            rule_rng,
            readings,
            (states, p_out, advise),
        )
        return FixedRun(
            bool(success), int(steps), int(count), float(benefit), int(ruled_out),
            states[:steps], p_out[:steps], advise[:steps],
        )  # fmt: skip

    def _fixed_readable(
        self, entry: Strategy, settings: AdvisorSettings, explorer: str, goal: int,
        rng: np.random.Generator, advised: bool, max_steps: int,
        visitor: kernels.VisitorParams, readings: np.random.Generator,
        positions: bool = False, jump: int = 1,
    ) -> FixedRun:  # fmt: skip
        """:meth:`fixed` in the reference loop: for a strategy without a compiled form, or
        fed ``positions`` (walked, with the advisor the service runs)."""
        make = entry.service_advisor if positions else entry.advisor
        advisor = make(self.data, settings)
        compliance, noise, sight = visitor
        rec = run_episode(
            self.domain, make_explorer(explorer, self.domain), advisor, goal, rng,
            advised=advised, max_steps=max_steps, compliance=compliance, noise=noise,
            sight=sight, seen_rng=readings, positions=positions, jump=jump,
        )  # fmt: skip
        beliefs = advisor.goal_beliefs() or []
        return FixedRun(
            rec.success, rec.steps, advisor.advice_count, advisor.benefit,
            sum(out for _, _, out in beliefs), np.array(rec.states, dtype=np.int64),
            np.array([d.p_normal for d in rec.decisions]),
            np.array([d.advise for d in rec.decisions], dtype=np.bool_),
        )  # fmt: skip

    def learning(
        self,
        goal: int,
        rng: np.random.Generator,
        *,
        advised: bool,
        params: QParams = QParams(),
        episodes: int = 5000,
        max_steps: int = 200,
        keep_history: bool = True,
        kappa: float = DEFAULT_KAPPA,
        window: int = DEFAULT_WINDOW,
        step_budget: int = 0,
        strategy: str = DEFAULT_STRATEGY,
        strategy_params: StrategyParams | None = None,
    ) -> LearningRun:
        """``episodes`` episodes of one Q-learning task (a fresh Q-table), advised by
        ``strategy`` with ``strategy_params``: compiled for the strategies whose compiled form
        runs in :func:`app.kernels.q_learning` (:attr:`Strategy.learns`). ``step_budget`` > 0
        stops after that many moves in total (Figure 7)."""
        entry, settings = self.settings(strategy, kappa, window, strategy_params)
        if episodes < 1 or max_steps < 1:
            raise ValueError("episodes and max_steps must be at least 1")
        if entry.kernel is None or not entry.learns:
            raise ValueError(
                f"Q-learning runs with a strategy whose compiled form learns "
                f"({', '.join(e.name for e in strategies.STRATEGIES.values() if e.learns)}), "
                f"not {strategy!r}"
            )
        q = np.zeros((self.domain.n_states, self.domain.n_actions))
        steps = np.zeros(episodes, dtype=np.int64)
        success = np.zeros(episodes, dtype=np.bool_)
        advice = np.zeros(episodes, dtype=np.int64)
        decisions = np.zeros(episodes, dtype=np.int64)
        p_mean = np.zeros(episodes)
        n = kernels.q_learning(
            self.next_state,
            self.domain.start,
            goal,
            episodes,
            max_steps,
            step_budget,
            (params.alpha, params.gamma, params.epsilon, params.ties == "advice"),
            advised,
            keep_history,
            settings.kappa,
            settings.window,
            resync_period(settings.window),
            self.tables.arrays,
            entry.kernel,
            self._guide(entry, settings),
            rng,
            q,
            (steps, success, advice, decisions, p_mean),
        )
        return LearningRun(steps[:n], success[:n], advice[:n], decisions[:n], p_mean[:n], q)
