from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from app.advice.priors import ActionPrior, NotFittedError, policy_counts, trajectory_counts


def slow_trajectory_counts(trajs: list[np.ndarray], n_states: int, delta: float) -> np.ndarray:
    """The counts of eq. (1) applied trajectory by trajectory, with dicts: obviously right, slow."""
    out = np.zeros((n_states, 4))
    for t in trajs:
        visits: dict[int, int] = {}
        taken: dict[tuple[int, int], int] = {}
        for s, a in t.tolist():
            visits[s] = visits.get(s, 0) + 1
            taken[(s, a)] = taken.get((s, a), 0) + 1
        for (s, a), k in taken.items():
            if k / visits[s] > delta:
                out[s, a] += 1
    return out


@st.composite
def trajectory_sets(draw: st.DrawFn) -> tuple[list[np.ndarray], int]:
    n_states = draw(st.integers(1, 12))
    k = draw(st.integers(0, 6))
    trajs = []
    for _ in range(k):
        length = draw(st.integers(0, 40))
        s = draw(hnp.arrays(np.int64, length, elements=st.integers(0, n_states - 1)))
        a = draw(hnp.arrays(np.int64, length, elements=st.integers(0, 3)))
        trajs.append(np.column_stack([s, a]).reshape(-1, 2))
    return trajs, n_states


@given(trajectory_sets(), st.sampled_from([0.0, 0.2, 0.5, 0.99]))
def test_trajectory_counts_match_eq1_slow_version(
    data: tuple[list[np.ndarray], int], delta: float
) -> None:
    trajs, n = data
    np.testing.assert_array_equal(
        trajectory_counts(trajs, n, delta), slow_trajectory_counts(trajs, n, delta)
    )


def test_trajectory_counts_each_trajectory_counts_once_per_pair() -> None:
    # one trajectory going E three times in state 0 adds 1, not 3 (eq. (2) counts policies)
    t = np.array([[0, 1], [0, 1], [0, 1], [1, 2]])
    counts = trajectory_counts([t, t], n_states=2)
    assert counts[0].tolist() == [0, 2, 0, 0]
    assert counts[1].tolist() == [0, 0, 2, 0]


def test_policy_counts_match_eq2_on_hand_made_policies() -> None:
    # two policies over 3 states; ties in a policy count every tied action
    pi1 = np.array([[0.5, 0.5, 0, 0], [0, 0, 1, 0], [0.25, 0.25, 0.25, 0.25]])
    pi2 = np.array([[1.0, 0, 0, 0], [0, 0.1, 0.9, 0], [0, 0, 0, 0]])
    assert policy_counts(np.stack([pi1, pi2])).tolist() == [
        [2, 1, 0, 0],
        [0, 1, 2, 0],
        [1, 1, 1, 1],
    ]
    # delta = 0.2 drops the 0.1 entry (eq. (1) threshold)
    assert policy_counts(np.stack([pi1, pi2]), delta=0.2)[1].tolist() == [0, 0, 2, 0]
    prior = ActionPrior(alpha0=0.5).fit_policies(np.stack([pi1, pi2]))
    np.testing.assert_allclose(prior.counts()[0], [2.5, 1.5, 0.5, 0.5])


@given(trajectory_sets(), st.floats(0.01, 5.0))
def test_theta_rows_are_positive_and_sum_to_one(
    data: tuple[list[np.ndarray], int], alpha0: float
) -> None:
    trajs, n = data
    prior = ActionPrior(alpha0=alpha0).fit(trajs, n)
    for theta in (prior.theta(), prior.theta(sample=True, rng=np.random.default_rng(0))):
        assert theta.shape == (n, 4)
        assert np.all(theta > 0)
        np.testing.assert_allclose(theta.sum(axis=1), 1.0, atol=1e-12)
    alpha = prior.counts()
    np.testing.assert_allclose(prior.theta(), alpha / alpha.sum(axis=1, keepdims=True))


def test_theta_is_uniform_where_no_expert_went() -> None:
    prior = ActionPrior(alpha0=1.0).fit([np.array([[0, 1]])], n_states=3)
    np.testing.assert_allclose(prior.theta()[2], 0.25)
    assert prior.theta()[0].argmax() == 1


def test_theta_sample_is_reproducible_and_centred_on_mean() -> None:
    prior = ActionPrior(alpha0=1.0).fit([np.array([[0, 1]] * 1)] * 20, n_states=1)
    a = prior.theta(sample=True, rng=np.random.default_rng(1))
    b = prior.theta(sample=True, rng=np.random.default_rng(1))
    np.testing.assert_array_equal(a, b)
    draws = np.stack([prior.theta(sample=True, rng=np.random.default_rng(i)) for i in range(400)])
    np.testing.assert_allclose(draws.mean(axis=0), prior.theta(), atol=0.03)
    with pytest.raises(ValueError, match="explicit rng"):
        prior.theta(sample=True)


@given(trajectory_sets(), trajectory_sets())
def test_partial_fit_equals_fit_on_all_data(
    first: tuple[list[np.ndarray], int], second: tuple[list[np.ndarray], int]
) -> None:
    n = max(first[1], second[1])
    a = [t % [n, 4] for t in first[0]]
    b = [t % [n, 4] for t in second[0]]
    inc = ActionPrior().partial_fit(a, n_states=n).partial_fit(b)
    full = ActionPrior().fit(a + b, n_states=n)
    np.testing.assert_array_equal(inc.counts(), full.counts())
    assert inc.n_trajectories_["*"] == len(a) + len(b)


def test_agent_types_keep_own_counts_pool_all_and_fall_back() -> None:
    staff = [np.array([[0, 1], [1, 1]])]
    visitor = [np.array([[0, 2]])]
    prior = ActionPrior(alpha0=1.0)
    prior.partial_fit(staff, n_states=3, agent_type="staff")
    prior.partial_fit(visitor, agent_type="visitor")
    assert prior.agent_types == ["staff", "visitor"]
    assert prior.counts("staff")[0].tolist() == [1, 2, 1, 1]
    assert prior.counts("visitor")[0].tolist() == [1, 1, 2, 1]
    assert prior.counts()[0].tolist() == [1, 2, 2, 1]  # pooled
    assert prior.resolve_type("robot") == "*"
    np.testing.assert_array_equal(prior.theta("robot"), prior.theta())
    with pytest.raises(ValueError, match="reserved"):
        prior.partial_fit(staff, agent_type="*")


def test_save_load_round_trip(tmp_path: Path) -> None:
    prior = ActionPrior(alpha0=0.3, delta=0.1)
    prior.partial_fit([np.array([[0, 1], [2, 3]])], n_states=4, agent_type="staff")
    prior.partial_fit([np.array([[1, 0]])])
    path = tmp_path / "prior.npz"
    prior.save(path)
    back = ActionPrior.load(path)
    assert back.delta == pytest.approx(0.1)
    assert back.n_trajectories_ == prior.n_trajectories_
    for t in (None, "staff"):
        np.testing.assert_array_equal(back.counts(t), prior.counts(t))


def test_from_counts_restores_what_stored_counts_gives() -> None:
    prior = ActionPrior(alpha0=0.7)
    prior.partial_fit([np.array([[0, 1], [2, 3]])] * 2, n_states=5, agent_type="staff")
    prior.partial_fit([np.array([[4, 0]])], agent_type="visitor")
    prior.partial_fit([np.array([[1, 2]])])
    back = ActionPrior.from_counts(0.7, prior.stored_counts())
    assert back.n_trajectories_ == prior.n_trajectories_ == {"*": 4, "staff": 2, "visitor": 1}
    for t in (None, "staff", "visitor"):
        np.testing.assert_array_equal(back.theta(t), prior.theta(t))
    # without the pooled table it is the sum of the typed ones
    typed = {k: v for k, v in prior.stored_counts().items() if k != "*"}
    pooled = ActionPrior.from_counts(0.7, typed)
    assert pooled.n_trajectories_["*"] == 3
    np.testing.assert_array_equal(
        pooled.counts(), 0.7 + prior.increments_["staff"] + prior.increments_["visitor"]
    )


@pytest.mark.parametrize(
    ("tables", "n_states", "message"),
    [
        ({"*": (1, np.zeros((3, 4)))}, 4, "table '*': counts of shape (3, 4), expected (4, 4)"),
        ({"staff": (1, -np.ones((2, 4)))}, None, "table 'staff': counts and trajectories must"),
        ({"*": (-1, np.zeros((2, 4)))}, None, "counts and trajectories must be >= 0"),
        ({"*": (1, np.zeros((2, 4))), "a": (1, np.zeros((3, 4)))}, None, "n_states is needed"),
        ({}, None, "n_states is needed"),
    ],
)
def test_from_counts_says_what_does_not_fit(
    tables: dict[str, tuple[int, np.ndarray]], n_states: int | None, message: str
) -> None:
    with pytest.raises(ValueError, match=re.escape(message)):
        ActionPrior.from_counts(1.0, tables, n_states)


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda: ActionPrior(alpha0=0).fit([], 3), "alpha0 must be finite and > 0"),
        (lambda: ActionPrior(alpha0=[1, 2]).fit([], 3), "alpha0 must be a number or broadcast"),
        (lambda: ActionPrior(delta=1.0).fit([], 3), "delta must be in"),
        (lambda: ActionPrior().fit([np.array([[3, 0]])], 3), "state out of range"),
        (lambda: ActionPrior().fit([np.array([[0, 4]])], 3), "action out of range"),
        (lambda: ActionPrior().fit([np.array([0, 1, 2])], 3), "(T, 2) array"),
        (lambda: ActionPrior().fit([np.array([[0.5, 1]])], 3), "must be integers"),
        (lambda: ActionPrior().partial_fit([np.array([[0, 1]])]), "n_states is needed"),
        (lambda: ActionPrior().fit([], 3).partial_fit([], n_states=4), "prior has 3 states"),
        (lambda: ActionPrior().fit_policies(np.ones((2, 3))), "shape"),
        (lambda: ActionPrior().fit_policies(-np.ones((3, 4))), "non-negative"),
        (lambda: ActionPrior().fit([], 3).partial_fit_policies(np.ones((1, 1, 3, 4))), "shape"),
    ],
)
def test_prior_rejects_bad_input_with_message(make, message: str) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        make()


def test_prior_refuses_use_before_fit() -> None:
    with pytest.raises(NotFittedError, match="call fit or partial_fit"):
        ActionPrior().theta()
