"""Goal-aware advice: a posterior over the experts' goals narrows the advice (docs/ARCHITECTURE.md).

The per-goal counts are :class:`app.advice.priors.GoalPriors`; a posterior ``w`` over the goals
gives theta^w (a uniform ``w`` gives the pooled prior, and so the paper's rule). The posterior
rules a goal out once the explorer leaves its cell (it stood there and its task did not end), and
may weight the rest by how well each goal's own prior explains the recent actions (``beta``).
"""

from __future__ import annotations

import math

from app.advice.advisor import DEFAULT_KAPPA, DEFAULT_WINDOW, Advisor, Decision, resync_period
from app.advice.models import AdviceTables
from app.advice.priors import GoalPriors


class GoalAwareAdvisor(Advisor):
    """The paper's advisor with advice narrowed by a posterior over the experts' goals.

    ``beta`` in [0, 1] scales the per-goal likelihood of the window (0: only ruling out, and
    then no per-goal window is kept at all). P(M1 | H) uses the pooled theta of ``tables``;
    the advice and the KL target use theta^w. Plain Python in a fixed order:
    app/kernels.py:goal_posterior and goal_decide are the same arithmetic, compiled.
    """

    strategy = "goal_aware"
    own_advice = True

    __slots__ = ("_goal_ll", "_goal_pos", "_goal_ring", "alive", "beta", "priors")

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
        if (priors.n_states, priors.n_actions) != (tables.n_states, tables.n_actions):
            raise ValueError("goal priors and tables describe different domains")
        self.priors = priors
        self.beta = float(beta)
        super().__init__(tables, kappa, window)

    def params(self) -> dict[str, int | float]:
        return {"beta": self.beta}

    def use_tables(self, tables: AdviceTables, goals: GoalPriors | None = None) -> None:
        """New tables and, when given, new per-goal counts (more expert trajectories) from the
        next step on. The window keeps the log-probabilities it added, so removing them stays
        exact."""
        if goals is not None:
            if (goals.goals, goals.n_states, goals.n_actions) != (
                self.priors.goals, self.priors.n_states, self.priors.n_actions,
            ):  # fmt: skip
                raise ValueError("the new goal priors describe another domain")
            self.priors = goals
        super().use_tables(tables)

    def reset(self) -> None:
        super().reset()
        g = self.priors.n_goals
        self.alive = [True] * g
        self._reset_goal_window()
        self._goal_ll = [0.0] * g
        self._goal_pos = 0

    def _reset_goal_window(self) -> None:
        """The per-goal window, only where it is read (beta > 0): W rows of G values."""
        g = self.priors.n_goals
        self._goal_ring = [[0.0] * g for _ in range(self.window)] if self.beta > 0.0 else []

    def append(self, state: int, action: int) -> None:
        super().append(state, action)
        gi = self.priors.goal_index.get(state)
        if gi is not None:  # it stood on this goal and went on: not its goal
            self.alive[gi] = False
        if self.beta == 0.0:
            return
        row = self.priors.rows().log_theta[state * self.priors.n_actions + action]
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
        if self.beta == 0.0:  # ruling out only: exp(0) = 1 for every goal left
            e = [1.0 if a else 0.0 for a in alive]
        else:
            z = [
                self.beta * ll if a else -math.inf
                for ll, a in zip(self._goal_ll, alive, strict=True)
            ]
            mx = max(z)
            e = [math.exp(v - mx) if v > -math.inf else 0.0 for v in z]
        tot = sum(e)
        return [v / tot for v in e]

    def goal_beliefs(self) -> list[tuple[int, float, bool]]:
        w = self.goal_posterior()
        return [(g, p, not a) for g, p, a in zip(self.priors.goals, w, self.alive, strict=True)]

    def decide(self, state: int) -> Decision:
        self._check(state)
        tw = self.priors.theta_row(state, self.goal_posterior())
        post = self.posterior()
        p0 = post[0]
        probs = self.tables.probs_flat
        n_actions = self.tables.n_actions
        b = state * n_actions
        kl = 0.0
        for a in range(n_actions):
            mix = p0 * tw[a]  # M1 now speaks for theta^w; the other models as before
            for m in range(1, len(post)):
                mix += post[m] * probs[m][b + a]
            kl += tw[a] * (math.log(tw[a]) - math.log(mix))
        kl = kl * self.tables.kl_scale if kl > 0.0 else 0.0  # kl_scale: AdviceTables
        return self.record(state, kl >= self.kappa, tw, kl, p0)
