"""Typed wrappers around the compiled kernels: one call runs one task of one explorer.

>>> sim = Simulator(domain, AdviceTables.paper(prior.theta()))
>>> run = sim.fixed("random", goal, np.random.default_rng(0), advised=True, kappa=0.5)
>>> run.success, run.steps, run.advice_count
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from app.advice.advisor import DEFAULT_KAPPA, DEFAULT_WINDOW, check_kappa_window
from app.advice.models import AdviceTables
from app.agents.experts import optimal_actions
from app.agents.explorers import FIXED_EXPLORERS
from app.agents.fast import fixed_episode, q_learning
from app.agents.fast_advisor import FlatTables
from app.agents.qlearning import TIE_RULES
from app.domain.grid import GridDomain

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class FixedRun:
    """One task of a fixed-policy explorer; per-step arrays have one entry per move."""

    success: bool
    steps: int
    advice_count: int
    benefit: float
    states: IntArray  # state before each move
    p_normal: FloatArray  # P(M1 | H) at each decision the explorer acted on
    advise: BoolArray  # the advisor's decision there (given to the explorer only if advised)


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


class Simulator:
    """A domain and the advisor's tables, prepared once for many compiled runs."""

    def __init__(self, domain: GridDomain, tables: AdviceTables):
        if tables.n_states != domain.n_states:
            raise ValueError(f"tables have {tables.n_states} states, the maze {domain.n_states}")
        self.domain = domain
        self.flat = FlatTables(tables)
        self.next_state = np.ascontiguousarray(domain.next_state)
        self.open_moves = np.ascontiguousarray(domain.open_moves)
        self.cells = np.ascontiguousarray(domain.cells)
        self._optimal: dict[int, BoolArray] = {}

    def optimal(self, goal: int) -> BoolArray:
        if goal not in self._optimal:
            self._optimal[goal] = np.ascontiguousarray(optimal_actions(self.domain, goal))
        return self._optimal[goal]

    def fixed(
        self,
        explorer: str,
        goal: int,
        rng: np.random.Generator,
        *,
        advised: bool,
        kappa: float = DEFAULT_KAPPA,
        window: int = DEFAULT_WINDOW,
        max_steps: int = 5000,
    ) -> FixedRun:
        """One task of ``explorer`` (a name in FIXED_EXPLORERS) from the start cell."""
        if explorer not in FIXED_EXPLORERS:
            raise ValueError(f"unknown explorer {explorer!r}: use {', '.join(FIXED_EXPLORERS)}")
        check_kappa_window(kappa, window)
        if max_steps < 1:
            raise ValueError(f"max_steps must be at least 1, got {max_steps}")
        states = np.empty(max_steps, dtype=np.int64)
        p_out = np.empty(max_steps)
        advise = np.empty(max_steps, dtype=np.bool_)
        f = self.flat
        steps, success, count, benefit = fixed_episode(
            FIXED_EXPLORERS.index(explorer),
            self.next_state,
            self.open_moves,
            self.cells,
            self.optimal(goal),
            self.domain.start,
            goal,
            max_steps,
            advised,
            float(kappa),
            int(window),
            f.theta,
            f.probs,
            f.log_probs,
            f.log_weights,
            f.neg_entropy,
            rng,
            states,
            p_out,
            advise,
        )
        return FixedRun(
            bool(success),
            int(steps),
            int(count),
            float(benefit),
            states[:steps],
            p_out[:steps],
            advise[:steps],
        )

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
    ) -> LearningRun:
        """``episodes`` episodes of one Q-learning task (a fresh Q-table).

        ``step_budget`` > 0 stops after that many moves in total (Figure 7).
        """
        check_kappa_window(kappa, window)
        if episodes < 1 or max_steps < 1:
            raise ValueError("episodes and max_steps must be at least 1")
        q = np.zeros((self.domain.n_states, 4))
        steps = np.zeros(episodes, dtype=np.int64)
        success = np.zeros(episodes, dtype=np.bool_)
        advice = np.zeros(episodes, dtype=np.int64)
        decisions = np.zeros(episodes, dtype=np.int64)
        p_mean = np.zeros(episodes)
        f = self.flat
        n = q_learning(
            self.next_state,
            self.domain.start,
            goal,
            episodes,
            max_steps,
            step_budget,
            params.alpha,
            params.gamma,
            params.epsilon,
            params.ties == "advice",
            advised,
            keep_history,
            float(kappa),
            int(window),
            f.theta,
            f.probs,
            f.log_probs,
            f.log_weights,
            f.neg_entropy,
            rng,
            q,
            steps,
            success,
            advice,
            decisions,
            p_mean,
        )
        return LearningRun(steps[:n], success[:n], advice[:n], decisions[:n], p_mean[:n], q)
