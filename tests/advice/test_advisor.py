from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from app.advice.advisor import Advisor, kl_divergence
from app.advice.models import AdviceTables, BehaviourModel, uniform_model

LOG4 = math.log(4)


@st.composite
def thetas(draw: st.DrawFn, n_states: int | None = None) -> np.ndarray:
    n = n_states or draw(st.integers(1, 8))
    alpha = draw(hnp.arrays(np.float64, (n, 4), elements=st.floats(0.01, 50.0)))
    out: np.ndarray = alpha / alpha.sum(axis=1, keepdims=True)
    return out


@st.composite
def streams(draw: st.DrawFn) -> tuple[np.ndarray, list[tuple[int, int, int]], int, float]:
    theta = draw(thetas())
    n = theta.shape[0]
    length = draw(st.integers(0, 120))
    events = [
        (draw(st.integers(0, n - 1)), draw(st.integers(0, 3)), draw(st.integers(0, n - 1)))
        for _ in range(length)
    ]
    window = draw(st.integers(1, 40))
    kappa = draw(st.sampled_from([0.0, 0.05, 0.2, 0.5, 1.0, 1.5]))
    return theta, events, window, kappa


def slow_decision(theta: np.ndarray, window_pairs: list[tuple[int, int]], s: int):  # type: ignore[no-untyped-def]
    """docs/METHOD.md from scratch: sums over H, P(M1|H) = 1/(1+exp(L2-L1)), mixture, KL."""
    l1 = sum(math.log(theta[si, ai]) for si, ai in window_pairs)
    l2 = len(window_pairs) * math.log(0.25)
    p1 = 1.0 / (1.0 + math.exp(l2 - l1))
    mix = p1 * theta[s] + (1 - p1) * 0.25
    return l1, l2, p1, kl_divergence(theta[s], mix)


@given(streams())
def test_advisor_matches_from_scratch_method(
    data: tuple[np.ndarray, list[tuple[int, int, int]], int, float],
) -> None:
    theta, events, window, kappa = data
    adv = Advisor(AdviceTables.paper(theta), kappa=kappa, window=window)
    first = adv.start(0)
    assert first.p_normal == 0.5 and first.step == 0
    pairs: list[tuple[int, int]] = []
    count, benefit = int(first.advise), first.kl if first.advise else 0.0
    for s, a, s2 in events:
        d = adv.observe(s, a, s2)
        pairs.append((s, a))
        l1, l2, p1, kl = slow_decision(theta, pairs[-window:], s2)
        assert adv.log_likelihoods == pytest.approx([l1, l2], abs=1e-9)
        assert d.p_normal == pytest.approx(p1, abs=1e-9)
        assert d.kl == pytest.approx(kl, abs=1e-9)
        if abs(kl - kappa) > 1e-9:
            assert d.advise == (kl >= kappa)
        count += d.advise
        benefit += d.kl if d.advise else 0.0
        assert (d.advice is not None) == d.advise
        if d.advise:
            assert d.advice == pytest.approx(tuple(theta[s2]))
    assert adv.advice_count == count and adv.decisions == len(events) + 1
    assert adv.total_cost == pytest.approx(kappa * count)
    assert adv.benefit == pytest.approx(benefit)
    assert adv.advice_per_100 == pytest.approx(100 * count / (len(events) + 1))


@given(
    st.integers(2, 8).flatmap(
        lambda n: hnp.arrays(np.float64, (3, n), elements=st.floats(0.01, 50.0))
    ),
    st.lists(st.tuples(st.integers(0, 2), st.integers(0, 7), st.integers(0, 2)), max_size=60),
    st.integers(1, 20),
    st.sampled_from([0.0, 0.2, 0.5, 1.0]),
)
def test_advisor_matches_from_scratch_method_over_any_number_of_actions(
    alpha: np.ndarray, events: list[tuple[int, int, int]], window: int, kappa: float
) -> None:
    """Six actions in a building of several floors (N E S W U D), or any other number A: the
    uniform model is 1/A, and the KL compared with kappa is KL x log 4 / log A (so the most a
    certain theta can be worth against the uniform model is log 4 whatever A)."""
    theta = alpha / alpha.sum(axis=1, keepdims=True)
    n_actions = theta.shape[1]
    adv = Advisor(AdviceTables.paper(theta), kappa=kappa, window=window)
    adv.start(0)
    pairs: list[tuple[int, int]] = []
    for s, a, s2 in events:
        a %= n_actions
        d = adv.observe(s, a, s2)
        pairs.append((s, a))
        h = pairs[-window:]
        l1 = sum(math.log(theta[si, ai]) for si, ai in h)
        l2 = len(h) * math.log(1 / n_actions)
        p1 = 1.0 / (1.0 + math.exp(l2 - l1))
        kl = kl_divergence(theta[s2], p1 * theta[s2] + (1 - p1) / n_actions)
        assert d.p_normal == pytest.approx(p1, abs=1e-9)
        assert d.kl == pytest.approx(kl * LOG4 / math.log(n_actions), abs=1e-9)
        assert d.advise == (d.kl >= kappa)
        assert d.advice == (tuple(theta[s2]) if d.advise else None)
    certain = np.full((1, n_actions), 1e-12)
    certain[0, 0] = 1.0
    lost = Advisor(AdviceTables.paper(certain / certain.sum()), kappa=0.0, window=50)
    lost.start(0)
    for _ in range(50):  # every move the uncertain one: the uniform model certain
        d = lost.observe(0, n_actions - 1, 0)
    assert d.kl == pytest.approx(LOG4, rel=1e-6)


@given(thetas(), st.integers(1, 30), st.integers(0, 2_000), st.integers(0, 2**32 - 1))
def test_window_sums_stay_exact_over_long_streams(
    theta: np.ndarray, window: int, length: int, seed: int
) -> None:
    rng = np.random.default_rng(seed)
    n = theta.shape[0]
    adv = Advisor(AdviceTables.paper(theta), window=window)
    s = rng.integers(0, n, length)
    a = rng.integers(0, 4, length)
    for i in range(length):
        adv.append(int(s[i]), int(a[i]))
    lo = max(0, length - window)
    scratch = math.fsum(np.log(theta[s[lo:], a[lo:]]))
    assert adv.log_likelihoods[0] == pytest.approx(scratch, abs=1e-9)
    assert adv.log_likelihoods[1] == pytest.approx((length - lo) * math.log(0.25), abs=1e-9)
    assert adv.history_length == length - lo


@given(
    hnp.arrays(np.float64, 4, elements=st.floats(1e-3, 1.0)),
    hnp.arrays(np.float64, 4, elements=st.floats(1e-3, 1.0)),
)
def test_kl_is_non_negative_and_zero_only_for_equal(p: np.ndarray, q: np.ndarray) -> None:
    p, q = p / p.sum(), q / q.sum()
    assert kl_divergence(p, q) >= 0
    assert kl_divergence(p, p) == pytest.approx(0, abs=1e-12)
    if not np.allclose(p, q, atol=1e-6):
        assert kl_divergence(p, q) > 0


@given(thetas(), st.integers(0, 60), st.integers(0, 2**32 - 1))
def test_kappa_zero_always_advises_and_above_log4_never(
    theta: np.ndarray, length: int, seed: int
) -> None:
    rng = np.random.default_rng(seed)
    tables = AdviceTables.paper(theta)
    always, never = Advisor(tables, kappa=0.0), Advisor(tables, kappa=LOG4 + 1e-6)
    n = theta.shape[0]
    assert always.start(0).advise and not never.start(0).advise
    for _ in range(length):
        s, a, s2 = int(rng.integers(n)), int(rng.integers(4)), int(rng.integers(n))
        d = always.observe(s, a, s2)
        assert d.advise and d.kl >= 0
        assert not never.observe(s, a, s2).advise


def test_lost_explorer_is_advised_and_normal_one_is_not() -> None:
    # one state where experts always go E; an explorer that keeps going W looks lost
    theta = np.array([[0.02, 0.94, 0.02, 0.02]])
    adv = Advisor(AdviceTables.paper(theta), kappa=0.5, window=20)
    for _ in range(20):
        d = adv.observe(0, 1, 0)
    assert d.p_normal > 0.99 and not d.advise
    for _ in range(20):
        d = adv.observe(0, 3, 0)
    assert d.p_normal < 0.01 and d.advise
    assert d.kl == pytest.approx(kl_divergence(theta[0], np.full(4, 0.25)), abs=1e-6)


def test_tables_can_change_mid_session_and_window_stays_exact() -> None:
    rng = np.random.default_rng(0)
    t1 = AdviceTables.paper(np.full((3, 4), 0.25))
    th2 = rng.dirichlet(np.ones(4), size=3)
    t2 = AdviceTables.paper(th2)
    adv = Advisor(t1, window=4)
    added = []
    for i in range(10):
        if i == 3:
            adv.tables = t2
        s, a = i % 3, (i * 7) % 4
        adv.append(s, a)
        added.append(math.log(0.25) if i < 3 else math.log(th2[s, a]))
    assert adv.log_likelihoods[0] == pytest.approx(sum(added[-4:]), abs=1e-12)


def test_more_than_two_models_posterior_sums_to_one() -> None:
    theta = np.array([[0.7, 0.1, 0.1, 0.1], [0.1, 0.1, 0.1, 0.7]])
    westward = BehaviourModel("west", np.array([[0.1, 0.1, 0.1, 0.7]] * 2), weight=1.0)
    tables = AdviceTables.with_models(theta, [westward])
    adv = Advisor(tables, window=10)
    assert adv.posterior() == pytest.approx([0.25, 0.25, 0.5])
    for _ in range(10):
        adv.observe(0, 3, 1)
    post = adv.posterior()
    assert sum(post) == pytest.approx(1.0) and post[2] > 0.9


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"kappa": -0.1}, "kappa must be a finite number >= 0"),
        ({"kappa": float("nan")}, "kappa must be a finite number >= 0"),
        ({"kappa": float("inf")}, "kappa must be a finite number >= 0"),
        ({"window": 0}, "window must be a whole number >= 1"),
        ({"window": 2.5}, "window must be a whole number >= 1"),
    ],
)
def test_advisor_rejects_bad_parameters(kwargs: dict[str, float], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        Advisor(AdviceTables.paper(np.full((2, 4), 0.25)), **kwargs)  # type: ignore[arg-type]


def test_advisor_rejects_out_of_range_events() -> None:
    adv = Advisor(AdviceTables.paper(np.full((2, 4), 0.25)))
    with pytest.raises(ValueError, match="state 2 out of range"):
        adv.observe(2, 0, 0)
    with pytest.raises(ValueError, match="action 4 out of range"):
        adv.observe(0, 4, 0)
    with pytest.raises(ValueError, match="state -1 out of range"):
        adv.decide(-1)
    assert adv.steps == 0  # nothing half-applied


@pytest.mark.parametrize(
    ("theta", "models", "message"),
    [
        (np.full((2, 1), 1.0), None, "shape"),
        (np.full(4, 0.25), None, "shape"),
        (np.array([[1.0, 0, 0, 0]]), None, "strictly positive"),
        (np.full((1, 4), 0.3), None, "sum to 1"),
        (
            np.full((1, 4), 0.25),
            [uniform_model(1, weight=0.0)],
            "weights P\\(M\\) must be positive",
        ),
    ],
)
def test_tables_reject_bad_theta_and_models(theta, models, message: str) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(ValueError, match=message):
        if models is None:
            AdviceTables.paper(theta)
        else:
            AdviceTables.with_models(theta, models)
