"""The advisor's decision rule compiled with numba, for simulations of millions of steps.

The same arithmetic in the same order as :class:`app.advice.advisor.Advisor`, so it makes
the same decisions (``tests/agents/test_fast_advisor.py`` checks that on random maps and
event streams):

* window H as one ring per model holding the log-probabilities it added; ``loglik[m] +=
  lp - ring[m, pos]``; when the ring wraps after a multiple of ``resync_period(W)`` pairs
  the sums are recomputed exactly with :func:`fsum`, a port of CPython's ``math.fsum``
  (Shewchuk's algorithm, correctly rounded);
* P(M | H) by a max-shifted softmax of ``loglik + log P(M)`` (eq. 5);
* P(A | s, H) = sum_M P(M | H) P(A | s, M) (eq. 4);
* KL[theta_s || P(A | s, H)] = sum_a theta log theta - sum_a theta log P(a | s, H) (eq. 6).

The state of one advisor is ``ring`` (M, W), ``loglik`` (M,), the ring position and the
number of pairs appended so far; the
tables are those of :class:`~app.advice.models.AdviceTables` (flattened: index s * 4 + a).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from numba import njit

from app.advice.advisor import RESYNC_PAIRS
from app.advice.models import AdviceTables

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


@njit(cache=True)
def resync_period(window: int) -> int:  # pragma: no cover - compiled
    """app.advice.advisor.resync_period: pairs between exact re-sums of the window."""
    return window * -(-RESYNC_PAIRS // window)


@njit(cache=True)
def fsum(values: FloatArray) -> float:  # pragma: no cover - compiled
    """Correctly rounded sum of finite floats: CPython 3.11 ``math.fsum`` step for step."""
    partials = np.empty(values.shape[0] + 1)
    n = 0
    for k in range(values.shape[0]):
        x = values[k]
        i = 0
        for j in range(n):
            y = partials[j]
            if abs(x) < abs(y):
                x, y = y, x
            hi = x + y
            lo = y - (hi - x)
            if lo != 0.0:
                partials[i] = lo
                i += 1
            x = hi
        n = i
        if x != 0.0:
            partials[n] = x
            n += 1
    hi = 0.0
    lo = 0.0
    if n > 0:
        n -= 1
        hi = partials[n]
        while n > 0:
            x = hi
            n -= 1
            y = partials[n]
            hi = x + y
            lo = y - (hi - x)
            if lo != 0.0:
                break
        # half-even rounding across several partials (as CPython does)
        if n > 0 and ((lo < 0.0 and partials[n - 1] < 0.0) or (lo > 0.0 and partials[n - 1] > 0.0)):
            y = lo * 2.0
            x = hi + y
            if y == x - hi:
                hi = x
    return float(hi)


@njit(cache=True)
def advisor_push(
    ring: FloatArray,
    loglik: FloatArray,
    pos: int,
    steps: int,
    period: int,
    log_probs: FloatArray,
    s: int,
    a: int,
) -> int:  # pragma: no cover - compiled
    """Add (s, a) to the window; returns the new ring position. ``steps`` counts the pairs
    appended including this one; ``period`` is ``resync_period(W)``; ``log_probs`` (M, S*4)."""
    k = s * 4 + a
    for m in range(ring.shape[0]):
        lp = log_probs[m, k]
        loglik[m] += lp - ring[m, pos]
        ring[m, pos] = lp
    pos += 1
    if pos == ring.shape[1]:
        pos = 0
        if steps % period == 0:
            for m in range(ring.shape[0]):
                loglik[m] = fsum(ring[m])
    return pos


@njit(cache=True)
def advisor_decide(
    loglik: FloatArray,
    log_weights: FloatArray,
    probs: FloatArray,
    theta: FloatArray,
    neg_entropy: FloatArray,
    s: int,
) -> tuple[float, float]:  # pragma: no cover - compiled
    """(KL[theta_s || P(A | s, H)], P(M1 | H)) for the explorer now at ``s``.

    ``probs`` is (M, S*4), ``theta`` is (S*4,): the flat tables of AdviceTables.
    """
    n_models = loglik.shape[0]
    z = np.empty(n_models)
    mx = loglik[0] + log_weights[0]
    for m in range(n_models):
        z[m] = loglik[m] + log_weights[m]
        if z[m] > mx:
            mx = z[m]
    tot = 0.0
    for m in range(n_models):
        z[m] = math.exp(z[m] - mx)
        tot += z[m]
    b = s * 4
    p0 = z[0] / tot
    m0 = p0 * probs[0, b]
    m1 = p0 * probs[0, b + 1]
    m2 = p0 * probs[0, b + 2]
    m3 = p0 * probs[0, b + 3]
    for m in range(1, n_models):
        pm = z[m] / tot
        m0 += pm * probs[m, b]
        m1 += pm * probs[m, b + 1]
        m2 += pm * probs[m, b + 2]
        m3 += pm * probs[m, b + 3]
    cross = theta[b] * math.log(m0) + theta[b + 1] * math.log(m1)
    cross += theta[b + 2] * math.log(m2)
    cross += theta[b + 3] * math.log(m3)
    kl = neg_entropy[s] - cross
    if kl < 0.0:
        kl = 0.0
    return kl, p0


@njit(cache=True)
def advisor_stream(
    log_probs: FloatArray,
    log_weights: FloatArray,
    probs: FloatArray,
    theta: FloatArray,
    neg_entropy: FloatArray,
    window: int,
    start: int,
    states: IntArray,
    actions: IntArray,
    next_states: IntArray,
) -> tuple[FloatArray, FloatArray]:  # pragma: no cover - compiled
    """Decisions for a start state and then each observed (s, a, s'): (kl, p_normal) arrays."""
    n = states.shape[0]
    ring = np.zeros((log_probs.shape[0], window))
    loglik = np.zeros(log_probs.shape[0])
    kl = np.empty(n + 1)
    p_normal = np.empty(n + 1)
    kl[0], p_normal[0] = advisor_decide(loglik, log_weights, probs, theta, neg_entropy, start)
    pos = 0
    period = resync_period(window)
    for t in range(n):
        pos = advisor_push(ring, loglik, pos, t + 1, period, log_probs, states[t], actions[t])
        kl[t + 1], p_normal[t + 1] = advisor_decide(
            loglik, log_weights, probs, theta, neg_entropy, next_states[t]
        )
    return kl, p_normal


class FlatTables:
    """The arrays the compiled advisor reads, taken from :class:`AdviceTables`."""

    def __init__(self, tables: AdviceTables):
        m = tables.n_models
        self.tables = tables
        self.theta2d = np.ascontiguousarray(tables.theta)
        self.theta = np.ascontiguousarray(tables.theta.reshape(-1))
        self.probs = np.ascontiguousarray(tables.probs.reshape(m, -1))
        self.log_probs = np.ascontiguousarray(tables.log_probs.reshape(m, -1))
        # math.log, as the single-explorer Advisor uses (np.log may differ in the last bit)
        self.log_weights = np.array(tables.log_weight_list, dtype=np.float64)
        self.neg_entropy = np.ascontiguousarray(tables.neg_entropy)

    def stream(
        self,
        window: int,
        start: int,
        states: npt.ArrayLike,
        actions: npt.ArrayLike,
        next_states: npt.ArrayLike,
    ) -> tuple[FloatArray, FloatArray]:
        """(kl, p_normal) of the start decision and of each observed move."""
        return advisor_stream(
            self.log_probs,
            self.log_weights,
            self.probs,
            self.theta,
            self.neg_entropy,
            int(window),
            int(start),
            np.asarray(states, dtype=np.int64),
            np.asarray(actions, dtype=np.int64),
            np.asarray(next_states, dtype=np.int64),
        )
