"""Random advice tables for the equality tests: any theta, two or three behaviour models with
arbitrary prior weights P(M), so that no fast path is checked only on the paper's 0.5 / 0.5."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import strategies as st

from app.advice.models import AdviceTables, BehaviourModel, normal_model, uniform_model


def random_theta(rng: np.random.Generator, n_states: int, n_actions: int = 4) -> np.ndarray:
    """Rows from flat to peaked: Dirichlet-mean-like counts over a random alpha0."""
    alpha = rng.choice([0.05, 0.5, 1.0, 5.0]) + rng.integers(0, 20, (n_states, n_actions))
    out: np.ndarray = alpha / alpha.sum(axis=1, keepdims=True)
    return out


def random_tables(
    rng: np.random.Generator,
    n_states: int,
    n_models: int = 2,
    theta: np.ndarray | None = None,
    n_actions: int = 4,
) -> AdviceTables:
    """theta (given or random) over ``n_actions`` actions, the normal and uniform models and,
    for three models or more, random others; every weight drawn from 0.05 to 20 (they are
    normalised across models)."""
    th = random_theta(rng, n_states, n_actions) if theta is None else np.asarray(theta)
    n_actions = th.shape[1]
    weights = rng.uniform(0.05, 20.0, n_models).tolist()
    models = [normal_model(th, weights[0]), uniform_model(n_states, weights[1], n_actions)]
    for k in range(2, n_models):
        other = rng.dirichlet(np.full(n_actions, 0.7), size=n_states)
        other = np.maximum(other, 1e-9)
        name = "other" if k == 2 else f"other{k}"
        models.append(BehaviourModel(name, other / other.sum(axis=1, keepdims=True), weights[k]))
    return AdviceTables(th, tuple(models))


def _split_weights() -> tuple[float, float, float]:
    """P(M) weights for which numpy's log and libm's differ in the last bit (of the second,
    once normalised), where this CPU's numpy has such values (its log is vectorised on some
    CPUs only): every form of the advisor must read AdviceTables' one value, whichever it is.
    Searched, not fixed, since which values split depends on the CPU."""
    rng = np.random.default_rng(20)
    for candidate in [(7.1935, 19.4471, 2.689), *rng.uniform(0.5, 30.0, (20_000, 3)).tolist()]:
        w = np.array(candidate) / sum(candidate)
        if np.log(w)[1] != math.log(w[1]):
            return (float(candidate[0]), float(candidate[1]), float(candidate[2]))
    return (7.1935, 19.4471, 2.689)


SPLIT_WEIGHTS = _split_weights()
#: whether numpy and libm disagree on SPLIT_WEIGHTS here (else the tests still check that
#: every form reads the same value, with nothing to tell the two logs apart)
WEIGHTS_SPLIT = bool(
    np.log(np.array(SPLIT_WEIGHTS) / sum(SPLIT_WEIGHTS))[1]
    != math.log(SPLIT_WEIGHTS[1] / sum(SPLIT_WEIGHTS))
)


def split_weight_tables(
    rng: np.random.Generator, n_states: int, theta: np.ndarray | None = None
) -> AdviceTables:
    """Three models with :data:`SPLIT_WEIGHTS`."""
    th = random_theta(rng, n_states) if theta is None else np.asarray(theta)
    other = BehaviourModel("other", rng.dirichlet(np.ones(4), size=n_states), SPLIT_WEIGHTS[2])
    models = (normal_model(th, SPLIT_WEIGHTS[0]), uniform_model(n_states, SPLIT_WEIGHTS[1]))
    return AdviceTables(th, (*models, other))


@st.composite
def advice_tables(draw: st.DrawFn, n_states: int) -> AdviceTables:
    """Hypothesis: random tables for ``n_states`` states with 2 or 3 models."""
    seed = draw(st.integers(0, 2**32 - 1))
    return random_tables(np.random.default_rng(seed), n_states, draw(st.sampled_from([2, 3])))
