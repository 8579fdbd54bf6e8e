"""Goal-aware advice: a posterior over the experts' goals narrows the advice (docs/ARCHITECTURE.md).

The store knows where each expert trajectory ended. Counts are kept per goal, ``c^g``, plus
``c^?`` for trajectories of unknown goal. For a goal posterior ``w`` over the G goals::

    alpha^w_s = alpha0 + c^?_s + G * sum_g w_g c^g_s        theta^w_s = alpha^w_s / |alpha^w_s|

A uniform ``w`` gives exactly the pooled prior (and so the paper's rule). The posterior rules a
goal out once the explorer leaves its cell (it stood there and its task did not end), and may
weight the rest by how well each goal's own prior explains the recent actions (``beta``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from app.advice.advisor import DEFAULT_KAPPA, DEFAULT_WINDOW, Advisor, Decision, resync_period
from app.advice.models import AdviceTables
from app.advice.priors import TrajectoryLike, trajectory_counts
from app.domain.grid import N_ACTIONS

FloatArray = npt.NDArray[np.float64]


class GoalPriors:
    """Per-goal Dirichlet counts for the goal states ``goals`` of one domain."""

    def __init__(self, n_states: int, goals: Sequence[int], alpha0: float = 1.0):
        if alpha0 <= 0 or not math.isfinite(alpha0):
            raise ValueError("alpha0 must be finite and > 0")
        if not goals:
            raise ValueError("goal-aware advice needs at least one goal")
        self.n_states = int(n_states)
        self.goals = tuple(int(g) for g in goals)
        self.alpha0 = float(alpha0)
        self.goal_counts = np.zeros((len(self.goals), n_states, N_ACTIONS))
        self.unknown_counts = np.zeros((n_states, N_ACTIONS))

    @property
    def n_goals(self) -> int:
        return len(self.goals)

    def add(
        self, trajectories: Sequence[TrajectoryLike], goal_index: Sequence[int | None]
    ) -> GoalPriors:
        """Add trajectories with the index (into ``goals``) of the goal each reached, or None."""
        if len(trajectories) != len(goal_index):
            raise ValueError("one goal index (or None) per trajectory is needed")
        by_goal: dict[int | None, list[TrajectoryLike]] = {}
        for t, g in zip(trajectories, goal_index, strict=True):
            if g is not None and not 0 <= g < self.n_goals:
                raise ValueError(f"goal index {g} out of range 0..{self.n_goals - 1}")
            by_goal.setdefault(g, []).append(t)
        for g, group in by_goal.items():
            counts = trajectory_counts(group, self.n_states)
            if g is None:
                self.unknown_counts += counts
            else:
                self.goal_counts[g] += counts
        return self

    def copy(self, alpha0: float | None = None) -> GoalPriors:
        """The same counts (optionally under another ``alpha0``), in arrays of its own."""
        out = GoalPriors(self.n_states, self.goals, self.alpha0 if alpha0 is None else alpha0)
        out.goal_counts = self.goal_counts.copy()
        out.unknown_counts = self.unknown_counts.copy()
        return out

    def pooled_theta(self) -> FloatArray:
        """The paper's theta: alpha0 + all counts, normalised."""
        return self.theta(np.full(self.n_goals, 1.0 / self.n_goals))

    def theta(self, w: npt.ArrayLike) -> FloatArray:
        """theta^w for every state, shape (S, 4)."""
        wv = np.asarray(w, dtype=np.float64)
        alpha = (
            self.alpha0
            + self.unknown_counts
            + self.n_goals * np.tensordot(wv, self.goal_counts, axes=1)
        )
        out: FloatArray = alpha / alpha.sum(axis=1, keepdims=True)
        return out

    def theta_row(self, state: int, w: npt.ArrayLike) -> FloatArray:
        """theta^w_s for one state (what a single decision needs)."""
        alpha = (
            self.alpha0
            + self.unknown_counts[state]
            + self.n_goals * (np.asarray(w, dtype=np.float64) @ self.goal_counts[:, state])
        )
        out: FloatArray = alpha / alpha.sum()
        return out

    def goal_log_theta(self) -> FloatArray:
        """log theta^g: each goal's own prior (alpha0 + G c^g), shape (G, S, 4)."""
        alpha = self.alpha0 + self.n_goals * self.goal_counts
        out: FloatArray = np.log(alpha / alpha.sum(axis=2, keepdims=True))
        return out


class GoalAwareAdvisor(Advisor):
    """The paper's advisor with advice narrowed by a posterior over the experts' goals.

    ``beta`` in [0, 1] scales the per-goal likelihood of the window (0: only ruling out).
    P(M1 | H) uses the pooled theta of ``tables``; the advice and the KL target use theta^w.
    """

    __slots__ = ("_goal_ll", "_goal_pos", "_goal_ring", "_log_theta_g", "alive", "beta", "priors")

    def __init__(
        self,
        tables: AdviceTables,
        priors: GoalPriors,
        kappa: float = DEFAULT_KAPPA,
        window: int = DEFAULT_WINDOW,
        beta: float = 0.0,
    ):
        if not (math.isfinite(beta) and 0.0 <= beta <= 1.0):
            raise ValueError(f"beta must be in [0, 1], got {beta!r}")
        if priors.n_states != tables.n_states:
            raise ValueError("goal priors and tables describe different domains")
        self.priors = priors
        self.beta = float(beta)
        self._log_theta_g = priors.goal_log_theta().reshape(priors.n_goals, -1).T.tolist()
        super().__init__(tables, kappa, window)

    def use_priors(self, priors: GoalPriors) -> None:
        """Advise from new per-goal counts (more expert trajectories) from the next step on.

        The window keeps the log-probabilities it added, so removing them stays exact."""
        if priors.goals != self.priors.goals or priors.n_states != self.priors.n_states:
            raise ValueError("the new goal priors describe another domain")
        self.priors = priors
        self._log_theta_g = priors.goal_log_theta().reshape(priors.n_goals, -1).T.tolist()

    def reset(self) -> None:
        super().reset()
        g = self.priors.n_goals
        self.alive = [True] * g
        self._goal_ring = [[0.0] * g for _ in range(self.window)]
        self._goal_ll = [0.0] * g
        self._goal_pos = 0

    def append(self, state: int, action: int) -> None:
        super().append(state, action)
        if state in self.priors.goals:  # it stood on this goal and went on: not its goal
            self.alive[self.priors.goals.index(state)] = False
        row = self._log_theta_g[state * N_ACTIONS + action]
        old = self._goal_ring[self._goal_pos]
        self._goal_ll = [ll + (v - o) for ll, v, o in zip(self._goal_ll, row, old, strict=True)]
        self._goal_ring[self._goal_pos] = row
        self._goal_pos += 1
        if self._goal_pos == self.window:
            self._goal_pos = 0
            if self.steps % resync_period(self.window) == 0:
                self._goal_ll = [math.fsum(col) for col in zip(*self._goal_ring, strict=True)]

    def goal_posterior(self) -> list[float]:
        """w_g: P(goal g | H); uniform over all goals if every goal has been ruled out."""
        alive = self.alive if any(self.alive) else [True] * len(self.alive)
        z = [self.beta * ll if a else -math.inf for ll, a in zip(self._goal_ll, alive, strict=True)]
        mx = max(z)
        e = [math.exp(v - mx) if v > -math.inf else 0.0 for v in z]
        tot = sum(e)
        return [v / tot for v in e]

    def decide(self, state: int) -> Decision:
        self._check(state)
        theta_w = self.priors.theta_row(state, self.goal_posterior())
        post = self.posterior()
        mix = post[0] * theta_w  # M1 now speaks for theta^w; the other models as before
        base = state * N_ACTIONS
        for m in range(1, len(post)):
            mix = mix + post[m] * np.asarray(self.tables.probs_flat[m][base : base + N_ACTIONS])
        kl = max(0.0, float(np.sum(theta_w * (np.log(theta_w) - np.log(mix)))))
        advice = (float(theta_w[0]), float(theta_w[1]), float(theta_w[2]), float(theta_w[3]))
        return self.record(state, kl >= self.kappa, advice, kl, post[0])
