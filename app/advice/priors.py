"""Action priors: Dirichlet counts over actions per state, learned from experts (Section III).

``alpha_s(a) = alpha0(a) + |{pi : pi(s, a) > delta}|`` (eq. (2)). A trajectory is treated as one
sampled policy: ``pi_hat(s, a)`` is the fraction of its visits to ``s`` in which it took ``a``, so
with ``delta = 0`` each *distinct* (s, a) in a trajectory adds 1, however often it recurs.
A full policy (shape states x actions) counts every state where ``pi(s, a) > delta``.

Counts are kept per agent type ("staff", "visitor", ...) and pooled over all data; asking for a
type that has no data falls back to the pooled prior. Fitting is vectorised over all
transitions of all trajectories at once (one sort, one bincount).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from app.arrays import FloatArray, IntArray
from app.domain.grid import N_ACTIONS

TrajectoryLike = npt.ArrayLike  # (T, 2) int pairs (state, action)


class NotFittedError(RuntimeError):
    """An :class:`ActionPrior` was used before any data was given to it."""


def as_pairs(trajectory: TrajectoryLike, n_states: int, n_actions: int = N_ACTIONS) -> IntArray:
    """A trajectory as an int64 array of shape (T, 2), checked against the domain's size and
    its number of actions."""
    arr = np.asarray(trajectory)
    if arr.size == 0:
        return np.zeros((0, 2), dtype=np.int64)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(
            f"a trajectory is a (T, 2) array of (state, action), got shape {arr.shape}"
        )
    if not np.issubdtype(arr.dtype, np.integer):
        raise ValueError(f"trajectory entries must be integers, got dtype {arr.dtype}")
    pairs = arr.astype(np.int64, copy=False)
    s, a = pairs[:, 0], pairs[:, 1]
    if s.min() < 0 or s.max() >= n_states:
        raise ValueError(f"trajectory state out of range: states are 0..{n_states - 1}")
    if a.min() < 0 or a.max() >= n_actions:
        raise ValueError(f"trajectory action out of range: actions are 0..{n_actions - 1}")
    return pairs


def trajectory_counts(
    trajectories: Sequence[TrajectoryLike],
    n_states: int,
    delta: float = 0.0,
    n_actions: int = N_ACTIONS,
) -> FloatArray:
    """The counts of eq. (1) summed over ``trajectories``: how many of them took ``a`` in
    ``s`` with ``pi_hat(s, a) > delta``. Shape (n_states, n_actions)."""
    pairs = [as_pairs(t, n_states, n_actions) for t in trajectories]
    lengths = np.fromiter((len(p) for p in pairs), dtype=np.int64, count=len(pairs))
    if lengths.sum() == 0:
        return np.zeros((n_states, n_actions))
    flat = np.concatenate(pairs)
    tid = np.repeat(np.arange(len(pairs), dtype=np.int64), lengths)
    n_sa = n_states * n_actions
    sa = flat[:, 0] * n_actions + flat[:, 1]
    keys, visits_sa = np.unique(tid * n_sa + sa, return_counts=True)
    sa_of_key = keys % n_sa
    if delta > 0:
        # pi_hat(s, a) = visits(traj, s, a) / visits(traj, s)
        ts_keys, visits_s = np.unique(tid * n_states + flat[:, 0], return_counts=True)
        ts_of_key = (keys // n_sa) * n_states + sa_of_key // n_actions
        frac = visits_sa / visits_s[np.searchsorted(ts_keys, ts_of_key)]
        sa_of_key = sa_of_key[frac > delta]
    return np.bincount(sa_of_key, minlength=n_sa).reshape(n_states, n_actions).astype(np.float64)


def policy_counts(
    policies: npt.ArrayLike, delta: float = 0.0, n_actions: int = N_ACTIONS
) -> FloatArray:
    """The counts of eq. (2) for full policies, shape (k, n_states, n_actions) or
    (n_states, n_actions)."""
    pi = np.asarray(policies, dtype=np.float64)
    if pi.ndim == 2:
        pi = pi[None]
    if pi.ndim != 3 or pi.shape[2] != n_actions:
        raise ValueError(
            f"policies must have shape (k, states, {n_actions}), got {np.shape(policies)}"
        )
    if not np.all(np.isfinite(pi)) or pi.min() < 0:
        raise ValueError("policy probabilities must be finite and non-negative")
    out: FloatArray = (pi > delta).sum(axis=0).astype(np.float64)
    return out


class ActionPrior:
    """Dirichlet action priors theta_s(A) for every state of one domain.

    Parameters
    ----------
    alpha0 : float or array broadcastable to (n_states, n_actions)
        The hyperprior alpha0(a) > 0 (keeps every probability positive, so logs are finite).
    delta : float in [0, 1)
        A policy counts for (s, a) when ``pi(s, a) > delta`` (eq. (1)).
    n_actions : int
        The domain's number of actions (``domain.n_actions``: 4 on one floor, ``N E S W``; 6
        in a building of several floors, ``U D`` as well).

    Learned attributes (after ``fit``/``partial_fit``): ``n_states_``, ``increments_`` (per
    agent type), ``pooled_increments_``, ``n_trajectories_`` (per type, and ``"*"`` pooled).
    """

    POOLED = "*"

    def __init__(
        self, alpha0: float | npt.ArrayLike = 1.0, delta: float = 0.0, n_actions: int = N_ACTIONS
    ):
        self.alpha0 = alpha0
        self.delta = delta
        self.n_actions = n_actions

    # ---- fitting ------------------------------------------------------------------------
    def _check_params(self, n_states: int) -> FloatArray:
        if not (isinstance(self.n_actions, int) and self.n_actions >= 2):
            raise ValueError(f"n_actions must be an int >= 2, got {self.n_actions!r}")
        a0 = np.asarray(self.alpha0, dtype=np.float64)
        try:
            a0 = np.broadcast_to(a0, (n_states, self.n_actions))
        except ValueError:
            raise ValueError(
                f"alpha0 must be a number or broadcast to (states, {self.n_actions}), got shape "
                f"{a0.shape}"
            ) from None
        if not np.all(np.isfinite(a0)) or a0.min() <= 0:
            raise ValueError("alpha0 must be finite and > 0 (it keeps every theta positive)")
        if not (0.0 <= float(self.delta) < 1.0):
            raise ValueError(f"delta must be in [0, 1), got {self.delta}")
        return a0

    def _reset(self, n_states: int) -> None:
        if n_states < 1:
            raise ValueError(f"n_states must be at least 1, got {n_states}")
        self.alpha0_ = self._check_params(n_states)
        self.n_states_ = int(n_states)
        self.increments_: dict[str, FloatArray] = {}
        self.pooled_increments_ = np.zeros((n_states, self.n_actions))
        self.n_trajectories_: dict[str, int] = {self.POOLED: 0}
        self._theta_cache: dict[str, FloatArray] = {}

    def _ensure(self, n_states: int | None) -> int:
        if hasattr(self, "n_states_"):
            if n_states is not None and n_states != self.n_states_:
                raise ValueError(f"prior has {self.n_states_} states, data has {n_states}")
            return self.n_states_
        if n_states is None:
            raise ValueError("n_states is needed for the first fit")
        self._reset(n_states)
        return n_states

    def _add(self, inc: FloatArray, n_items: int, agent_type: str | None) -> None:
        self.pooled_increments_ += inc
        self.n_trajectories_[self.POOLED] += n_items
        if agent_type is not None:
            if agent_type == self.POOLED:
                raise ValueError(f"agent type {self.POOLED!r} is reserved for the pooled prior")
            if agent_type not in self.increments_:
                self.increments_[agent_type] = np.zeros_like(inc)
                self.n_trajectories_[agent_type] = 0
            self.increments_[agent_type] += inc
            self.n_trajectories_[agent_type] += n_items
        self._theta_cache.clear()

    def fit(
        self, trajectories: Sequence[TrajectoryLike], n_states: int, agent_type: str | None = None
    ) -> ActionPrior:
        """Forget all data, then learn from ``trajectories``."""
        self._reset(n_states)
        return self.partial_fit(trajectories, agent_type=agent_type)

    def partial_fit(
        self,
        trajectories: Sequence[TrajectoryLike],
        n_states: int | None = None,
        agent_type: str | None = None,
    ) -> ActionPrior:
        """Add trajectories (each a (T, 2) array of (state, action)) to the counts."""
        n = self._ensure(n_states)
        trajectories = list(trajectories)
        self._add(
            trajectory_counts(trajectories, n, float(self.delta), self.n_actions),
            len(trajectories),
            agent_type,
        )
        return self

    def fit_policies(self, policies: npt.ArrayLike, agent_type: str | None = None) -> ActionPrior:
        """Forget all data, then learn from full policies of shape (k, states, n_actions)."""
        pi = np.asarray(policies)
        self._reset(int(pi.shape[-2]))
        return self.partial_fit_policies(pi, agent_type=agent_type)

    def partial_fit_policies(
        self, policies: npt.ArrayLike, agent_type: str | None = None
    ) -> ActionPrior:
        pi = np.asarray(policies, dtype=np.float64)
        if pi.ndim not in (2, 3):
            raise ValueError(
                f"policies must have shape (k, states, {self.n_actions}), got {pi.shape}"
            )
        k = 1 if pi.ndim == 2 else int(pi.shape[0])
        self._ensure(int(pi.shape[-2]))
        self._add(policy_counts(pi, float(self.delta), self.n_actions), k, agent_type)
        return self

    # ---- reading ------------------------------------------------------------------------
    def _check_fitted(self) -> None:
        if not hasattr(self, "n_states_"):
            raise NotFittedError("this ActionPrior has no data yet: call fit or partial_fit")

    @property
    def agent_types(self) -> list[str]:
        self._check_fitted()
        return sorted(self.increments_)

    def resolve_type(self, agent_type: str | None) -> str:
        """The table that serves ``agent_type``: its own if it has data, else the pooled one."""
        self._check_fitted()
        if agent_type is not None and self.n_trajectories_.get(agent_type, 0) > 0:
            return agent_type
        return self.POOLED

    def counts(self, agent_type: str | None = None) -> FloatArray:
        """alpha_s(a) (eq. (2)) for ``agent_type`` (pooled if None or without data)."""
        key = self.resolve_type(agent_type)
        inc = self.pooled_increments_ if key == self.POOLED else self.increments_[key]
        out: FloatArray = self.alpha0_ + inc
        return out

    def theta(
        self,
        agent_type: str | None = None,
        *,
        sample: bool = False,
        rng: np.random.Generator | None = None,
    ) -> FloatArray:
        """theta_s(A): the Dirichlet mean alpha_s / sum(alpha_s), or with ``sample=True`` one
        draw theta_s ~ Dir(alpha_s) per state. Shape (n_states, n_actions); rows sum to 1."""
        if sample:
            if rng is None:
                raise ValueError("sample=True needs an explicit rng (np.random.Generator)")
            g = rng.standard_gamma(self.counts(agent_type))
            g = np.maximum(g, np.finfo(np.float64).tiny)  # a tiny alpha can draw an exact 0
            return g / g.sum(axis=1, keepdims=True)  # type: ignore[no-any-return]
        key = self.resolve_type(agent_type)
        if key not in self._theta_cache:
            alpha = self.counts(key)
            th = alpha / alpha.sum(axis=1, keepdims=True)
            th.setflags(write=False)
            self._theta_cache[key] = th
        return self._theta_cache[key]

    def summary(self, agent_type: str | None = None) -> dict[str, Any]:
        key = self.resolve_type(agent_type)
        inc = self.pooled_increments_ if key == self.POOLED else self.increments_[key]
        th = self.theta(key)
        entropy = -(th * np.log(th)).sum(axis=1)
        return {
            "table": key,
            "states": self.n_states_,
            "trajectories": self.n_trajectories_.get(key, 0),
            "states_with_data": int((inc.sum(axis=1) > 0).sum()),
            "mean_entropy_nats": float(entropy.mean()),
            "mean_max_theta": float(th.max(axis=1).mean()),
        }

    # ---- persistence --------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        self._check_fitted()
        types = sorted(self.increments_)
        np.savez_compressed(
            Path(path),
            alpha0=self.alpha0_,
            delta=np.float64(self.delta),
            pooled=self.pooled_increments_,
            types=np.array(types, dtype=str),
            typed=np.stack([self.increments_[t] for t in types])
            if types
            else np.zeros((0, self.n_states_, self.n_actions)),
            n_traj_types=np.array([self.n_trajectories_[t] for t in types], dtype=np.int64),
            n_traj_pooled=np.int64(self.n_trajectories_[self.POOLED]),
        )

    @classmethod
    def load(cls, path: str | Path) -> ActionPrior:
        """A prior written by :meth:`save`."""
        with np.load(Path(path), allow_pickle=False) as z:
            tables = {cls.POOLED: (int(z["n_traj_pooled"]), z["pooled"])}
            for t, inc, n in zip(z["types"].tolist(), z["typed"], z["n_traj_types"], strict=True):
                tables[str(t)] = (int(n), inc)
            return cls.from_counts(z["alpha0"], tables, delta=float(z["delta"]))

    @classmethod
    def from_counts(
        cls,
        alpha0: float | npt.ArrayLike,
        tables: Mapping[str, tuple[int, npt.ArrayLike]],
        n_states: int | None = None,
        delta: float = 0.0,
        n_actions: int | None = None,
    ) -> ActionPrior:
        """A prior holding stored counts: ``tables`` maps the pooled key ``"*"`` and each agent
        type to (trajectories, increments of shape (n_states, n_actions)); a missing pooled
        table is the sum of the others. ``n_states`` and ``n_actions`` default to the tables'
        (or alpha0's) shape, ``n_actions`` to 4 when neither gives it. ValueError says what
        does not fit."""
        shapes = {np.shape(inc) for _, inc in tables.values()}
        given = {shape for shape in shapes if len(shape) == 2}
        given |= {np.shape(alpha0)} if np.ndim(alpha0) == 2 else set()
        if n_states is None:
            sizes = {shape[0] for shape in given}
            if len(sizes) != 1:
                raise ValueError("n_states is needed (no table or alpha0 gives it, or they differ)")
            n_states = sizes.pop()
        if n_actions is None:
            widths = {shape[1] for shape in given}
            n_actions = widths.pop() if len(widths) == 1 else N_ACTIONS
        prior = cls(alpha0=alpha0, delta=delta, n_actions=n_actions)
        prior._reset(n_states)
        for key, (n, inc) in tables.items():
            counts = np.asarray(inc, dtype=np.float64)
            if counts.shape != (n_states, n_actions):
                raise ValueError(
                    f"table {key!r}: counts of shape {counts.shape}, expected ({n_states}, "
                    f"{n_actions})"
                )
            if not np.all(np.isfinite(counts)) or counts.min(initial=0.0) < 0 or n < 0:
                raise ValueError(f"table {key!r}: counts and trajectories must be >= 0")
            if key == cls.POOLED:
                prior.pooled_increments_ = counts.copy()
            else:
                prior.increments_[key] = counts.copy()
            prior.n_trajectories_[key] = int(n)
        if cls.POOLED not in tables:
            for key, inc in prior.increments_.items():
                prior.pooled_increments_ += inc
                prior.n_trajectories_[cls.POOLED] += prior.n_trajectories_[key]
        return prior

    def stored_counts(self) -> dict[str, tuple[int, FloatArray]]:
        """(trajectories, increments) per table, pooled ``"*"`` included: what
        :meth:`from_counts` takes back."""
        self._check_fitted()
        out = {self.POOLED: (self.n_trajectories_[self.POOLED], self.pooled_increments_)}
        out |= {t: (self.n_trajectories_[t], inc) for t, inc in self.increments_.items()}
        return out


def iter_pairs(states: Iterable[int], actions: Iterable[int]) -> IntArray:
    """Zip parallel state and action sequences into a (T, 2) trajectory array."""
    return np.column_stack([np.fromiter(states, np.int64), np.fromiter(actions, np.int64)])


class GoalPriors:
    """Per-goal Dirichlet counts for the goal states ``goals`` of one domain (goal-aware
    advice, :mod:`app.advice.goals`).

    Counts are kept per goal, ``c^g``, plus ``c^?`` for trajectories of unknown goal. For a goal
    posterior ``w`` over the G goals::

        alpha^w_s = alpha0 + c^?_s + G * sum_g w_g c^g_s      theta^w_s = alpha^w_s / |alpha^w_s|

    so a uniform ``w`` gives exactly the pooled prior (and the paper's rule). Counts change only
    through :meth:`add`; readers share the flat lists of :meth:`rows`, made once per change.
    """

    def __init__(
        self, n_states: int, goals: Sequence[int], alpha0: float = 1.0, n_actions: int = N_ACTIONS
    ):
        if not (math.isfinite(alpha0) and alpha0 > 0):
            raise ValueError("alpha0 must be finite and > 0")
        if not goals:
            raise ValueError("goal-aware advice needs at least one goal")
        self.n_states = int(n_states)
        self.goals = tuple(int(g) for g in goals)
        self.goal_index = {g: i for i, g in enumerate(self.goals)}
        self.alpha0 = float(alpha0)
        self.n_actions = int(n_actions)
        self.goal_counts = np.zeros((len(self.goals), n_states, self.n_actions))
        self.unknown_counts = np.zeros((n_states, self.n_actions))
        self._rows: GoalRows | None = None
        self._arrays: GoalArrays | None = None

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
            counts = trajectory_counts(group, self.n_states, n_actions=self.n_actions)
            if g is None:
                self.unknown_counts += counts
            else:
                self.goal_counts[g] += counts
        self._rows = None
        self._arrays = None
        return self

    def copy(self, alpha0: float | None = None) -> GoalPriors:
        """The same counts (optionally under another ``alpha0``), in arrays of its own."""
        alpha = self.alpha0 if alpha0 is None else alpha0
        out = GoalPriors(self.n_states, self.goals, alpha, self.n_actions)
        out.goal_counts = self.goal_counts.copy()
        out.unknown_counts = self.unknown_counts.copy()
        return out

    def pooled_theta(self) -> FloatArray:
        """The paper's theta: alpha0 + all counts, normalised."""
        return self.theta(np.full(self.n_goals, 1.0 / self.n_goals))

    def theta(self, w: npt.ArrayLike) -> FloatArray:
        """theta^w for every state, shape (S, A)."""
        wv = np.asarray(w, dtype=np.float64)
        alpha = (
            self.alpha0
            + self.unknown_counts
            + self.n_goals * np.tensordot(wv, self.goal_counts, axes=1)
        )
        out: FloatArray = alpha / alpha.sum(axis=1, keepdims=True)
        return out

    def theta_row(self, state: int, w: Sequence[float]) -> tuple[float, ...]:
        """theta^w_s for one state, summed in order (app/kernels.py:goal_decide does the same
        operations on the same numbers, so the same bits)."""
        rows = self.rows()
        n_actions = self.n_actions
        b, g = state * n_actions, self.n_goals
        alpha = []
        for a in range(n_actions):
            dot = 0.0
            for wg, cg in zip(w, rows.counts[b + a], strict=True):
                dot += wg * cg
            alpha.append(self.alpha0 + rows.unknown[b + a] + g * dot)
        total = alpha[0]
        for a in range(1, n_actions):
            total += alpha[a]
        return tuple(x / total for x in alpha)

    def goal_log_theta(self) -> FloatArray:
        """log theta^g: each goal's own prior (alpha0 + G c^g), shape (G, S, A)."""
        alpha = self.alpha0 + self.n_goals * self.goal_counts
        out: FloatArray = np.log(alpha / alpha.sum(axis=2, keepdims=True))
        return out

    def rows(self) -> GoalRows:
        """The counts and each goal's log theta as flat lists (index s * A + a), made once per
        change of the counts and shared by every advisor that reads them."""
        if self._rows is None:
            g = self.n_goals
            self._rows = GoalRows(
                self.goal_counts.reshape(g, -1).T.tolist(),
                self.unknown_counts.reshape(-1).tolist(),
                self.goal_log_theta().reshape(g, -1).T.tolist(),
            )
        return self._rows

    def arrays(self) -> GoalArrays:
        """The counts as app/kernels.py reads them (its ``GoalTables``): (goal index of each
        state (S,), alpha0, unknown counts (S*A,), goal counts (S*A, G), each goal's log theta
        (S*A, G)). The two (S*A, G) arrays are transposed views of (G, S*4) ones, the goal
        counts a view of :attr:`goal_counts` itself: made once per change of the counts, 32
        bytes per goal, state and action beside the counts, shared by every reader."""
        if self._arrays is None:
            g, s = self.n_goals, self.n_states
            of_state = np.full(s, -1, dtype=np.int64)
            of_state[list(self.goals)] = np.arange(g)
            self._arrays = (
                of_state,
                self.alpha0,
                self.unknown_counts.reshape(-1),
                self.goal_counts.reshape(g, -1).T,
                self.goal_log_theta().reshape(g, -1).T,
            )
        return self._arrays


GoalArrays = tuple[npt.NDArray[np.int64], float, FloatArray, FloatArray, FloatArray]


@dataclass(frozen=True, slots=True)
class GoalRows:
    """:class:`GoalPriors` as lists for the single-explorer form: per (s, a), a number per goal."""

    counts: list[list[float]]  # c^g_s(a)
    unknown: list[float]  # c^?_s(a)
    log_theta: list[list[float]]  # log theta^g_s(a)
