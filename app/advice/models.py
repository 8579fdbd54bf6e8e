"""Behaviour models M: an action distribution P(a | s, M) per state plus a prior weight P(M).

The paper uses two (Section IV-B): M1 normalcy, P(a | s, M1) = theta_s(a), and M2 uniformity,
P(a | s, M2) = 1/|A|, with P(M1) = P(M2) = 1/2. More can be added: anything that gives a
strictly positive (states x actions) table. :class:`AdviceTables` precomputes everything the advisor
needs for a fixed theta and model set, once: numpy arrays (the batch form, and flat views for the
compiled kernels of :mod:`app.kernels`) and flat Python lists (the single form, where list
indexing is several times faster than numpy scalar access). Every form holds the same numbers
(the sequences are the arrays' numbers in ``array.array``: ``grid.packed``), so every form of
the advisor reads the same bits.
"""

from __future__ import annotations

import math
from array import array
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from app.arrays import FloatArray
from app.domain.grid import N_ACTIONS, packed


@dataclass(frozen=True)
class BehaviourModel:
    """P(a | s, M) as a (states, actions) table, and the prior P(M) (normalised across
    models)."""

    name: str
    probabilities: FloatArray
    weight: float = 0.5


def normal_model(theta: npt.ArrayLike, weight: float = 0.5) -> BehaviourModel:
    """M1, normalcy: the action prior itself."""
    return BehaviourModel("normal", np.asarray(theta, dtype=np.float64), weight)


def uniform_model(n_states: int, weight: float = 0.5, n_actions: int = N_ACTIONS) -> BehaviourModel:
    """M2, uniformity: a lost explorer picks any of the domain's actions (the four moves; in
    a building of several floors, up and down too)."""
    return BehaviourModel("uniform", np.full((n_states, n_actions), 1.0 / n_actions), weight)


def _as_theta(theta: npt.ArrayLike) -> FloatArray:
    th = np.asarray(theta, dtype=np.float64)
    if th.ndim != 2 or th.shape[1] < 2:
        raise ValueError(f"theta must have shape (states, actions >= 2), got {th.shape}")
    return th


def kl_scale(n_actions: int) -> float:
    """log 4 / log A: a KL over A actions in the units of four (1.0 for four). The uniform
    model's KL from a certain theta is log A, so without it six actions would make every
    piece of advice worth log 6 / log 4 = 1.29 times more against the same kappa."""
    return 1.0 if n_actions == N_ACTIONS else math.log(4.0) / math.log(float(n_actions))


@dataclass(frozen=True, eq=False)
class AdviceTables:
    """Everything the decision rule reads, precomputed for one theta and one model set.

    ``models[0]`` is the normal model; ``p_normal`` is its posterior. An advisor may be handed
    new tables at any time (the prior was updated): its window keeps the log-probabilities it
    added, so the O(1) update stays exact.
    """

    theta: FloatArray
    models: tuple[BehaviourModel, ...]
    probs: FloatArray = field(init=False, repr=False)  # (M, S, A)
    log_probs: FloatArray = field(init=False, repr=False)  # (M, S, A)
    log_weights: FloatArray = field(init=False, repr=False)  # (M,)
    neg_entropy: FloatArray = field(init=False, repr=False)  # (S,) sum_a theta log theta
    # action-major copies for the batch form: gathers give (A, n) rows with long inner loops
    probs_t: FloatArray = field(init=False, repr=False)  # (M, A, S)
    theta_t: FloatArray = field(init=False, repr=False)  # (A, S)
    # what the compiled kernels read (app/kernels.py), views of the arrays above:
    # (log_probs (M, S*A), log_weights (M,), probs (M, S*A), theta (S*A,), neg_entropy (S,))
    arrays: tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray] = field(
        init=False, repr=False
    )
    # flat Python sequences (``array.array`` of doubles, ``grid.packed``) for the
    # single-explorer form: index s * A + a
    probs_flat: tuple[array[float], ...] = field(init=False, repr=False)
    log_probs_flat: tuple[array[float], ...] = field(init=False, repr=False)
    theta_flat: array[float] = field(init=False, repr=False)
    neg_entropy_list: array[float] = field(init=False, repr=False)
    log_weight_list: list[float] = field(init=False, repr=False)
    n_states: int = field(init=False, repr=False)  # a plain attribute: read on every decision
    #: A, the domain's number of actions (4: N E S W; 6 with U D in a building of floors)
    n_actions: int = field(init=False, repr=False)
    #: what the decision multiplies a KL by before comparing it with kappa: log 4 / log A (1.0
    #: for four actions, where nothing is multiplied), so that the most a KL from the uniform
    #: model can be is log 4 whatever the number of actions (docs/ARCHITECTURE.md)
    kl_scale: float = field(init=False, repr=False)

    def __post_init__(self) -> None:
        theta = np.ascontiguousarray(self.theta, dtype=np.float64)
        if theta.ndim != 2 or theta.shape[1] < 2:
            raise ValueError(f"theta must have shape (states, actions >= 2), got {theta.shape}")
        if not np.all(theta > 0) or not np.allclose(theta.sum(axis=1), 1.0, atol=1e-9):
            raise ValueError("theta rows must be strictly positive and sum to 1")
        if not self.models:
            raise ValueError("at least one behaviour model is needed")
        probs = np.stack([np.asarray(m.probabilities, dtype=np.float64) for m in self.models])
        if probs.shape[1:] != theta.shape:
            raise ValueError(f"model tables must have shape {theta.shape}, got {probs.shape[1:]}")
        if not np.all(probs > 0):
            raise ValueError("behaviour models must give every action a positive probability")
        weights = np.array([m.weight for m in self.models], dtype=np.float64)
        if not np.all(np.isfinite(weights)) or weights.min() <= 0:
            raise ValueError("model weights P(M) must be positive")
        weights = weights / weights.sum()
        # log P(M) with libm's log, once: every form of the advisor reads these same numbers
        log_weights = np.array([math.log(w) for w in weights.tolist()])
        log_probs = np.log(probs)
        neg_entropy = (theta * np.log(theta)).sum(axis=1)
        m = len(self.models)
        setters = {
            "theta": theta,
            "probs": probs,
            "log_probs": log_probs,
            "log_weights": log_weights,
            "neg_entropy": neg_entropy,
            "probs_t": np.ascontiguousarray(probs.transpose(0, 2, 1)),
            "theta_t": np.ascontiguousarray(theta.T),
            "probs_flat": tuple(packed(p, "d") for p in probs),
            "log_probs_flat": tuple(packed(lp, "d") for lp in log_probs),
            "theta_flat": packed(theta, "d"),
            "neg_entropy_list": packed(neg_entropy, "d"),
            "log_weight_list": log_weights.tolist(),
            "n_states": int(theta.shape[0]),
            "n_actions": int(theta.shape[1]),
            "kl_scale": kl_scale(int(theta.shape[1])),
        }
        for name, value in setters.items():
            if isinstance(value, np.ndarray):
                value.setflags(write=False)
            object.__setattr__(self, name, value)
        flat = (log_probs.reshape(m, -1), log_weights, probs.reshape(m, -1), theta.reshape(-1))
        object.__setattr__(self, "arrays", (*flat, neg_entropy))

    @classmethod
    def paper(cls, theta: npt.ArrayLike) -> AdviceTables:
        """The paper's two models, normal and uniform, equally likely a priori."""
        th = _as_theta(theta)
        return cls(th, (normal_model(th), uniform_model(th.shape[0], n_actions=th.shape[1])))

    @classmethod
    def with_models(cls, theta: npt.ArrayLike, extra: Sequence[BehaviourModel]) -> AdviceTables:
        th = _as_theta(theta)
        uniform = uniform_model(th.shape[0], n_actions=th.shape[1])
        return cls(th, (normal_model(th), uniform, *extra))

    @property
    def n_models(self) -> int:
        return len(self.models)
