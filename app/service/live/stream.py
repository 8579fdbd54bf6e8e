"""The paper's advisor for a live session: the core :class:`Advisor`, with batches compiled.

A websocket message may carry hundreds of one explorer's moves. :meth:`StreamAdvisor.observe_batch`
runs them in one call of :func:`app.kernels.observe_stream`: the core's window update and
decision (eqs. 4-6, :func:`app.kernels.decide`), in the core's order, with libm's exp and log as
:mod:`math` uses, and the core's exact re-sums where it makes them. The advisor is left in
exactly the state the sequential calls leave it in (ring, sums, position, counters), so single
events (the core's own :meth:`observe`) and batches mix freely, and every decision equals the
core's bit for bit (``tests/service/live/test_stream.py``).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from app import kernels
from app.advice.advisor import Advisor, DecisionBatch, resync_period
from app.advice.guide import GuideAdvisor, GuideParams, kernel_params
from app.domain.grid import N_ACTIONS

IntArray = npt.NDArray[np.int64]
FloatArray = npt.NDArray[np.float64]

_NO_RING = np.zeros((0, 0))  # no value kept: the window's values are those of the tables
_NO_ADVICE = np.zeros((0, N_ACTIONS))


class StreamAdvisor(Advisor):
    """An :class:`Advisor` whose window holds pair keys, with compiled batches.

    The core's window keeps, per model, the log-probability each pair added (lists of Python
    floats, about 32 bytes an entry and model). This one keeps each pair's key ``s * 4 + a``
    (int32, 4 bytes a pair whatever the number of models): the value the core stored is
    ``tables.log_probs[m][key]``. Only when the tables change (a prior update) are the values
    of the pairs then in the window kept as numbers (``_old``, models x W float64, until the
    last of those pairs has left), since the new tables would give other values. So removing
    a pair and the exact re-sums use exactly the core's numbers, and a session costs about
    1.5 kB of window instead of 4.8 (W = 300, two models): 100,000 sessions hold one each
    (docs/PERFORMANCE.md, memory). :meth:`append` is the core's, step for step.
    """

    __slots__ = ("_kept", "_keys", "_keys_tables", "_n_kept", "_old")

    def reset(self) -> None:
        super().reset()
        self._ring = []  # the core's lists are not used: the window lives in ``_keys``
        self._keys = np.full(self.window, -1, dtype=np.int32)  # -1: empty (the core's 0.0)
        self._kept = np.zeros(self.window, dtype=np.uint8)  # 1: value in _old
        self._old: FloatArray | None = None
        self._n_kept = 0
        self._keys_tables = self.tables  # the tables giving the values of the other pairs

    def _sync_tables(self) -> None:
        """After a change of tables, keep the values of the pairs added with the old ones.

        This runs at the first event after each prior update, so with one trajectory per
        ingest request nearly every event of every session pays it: one compiled call."""
        if self._keys_tables is self.tables:
            return
        if self.steps:  # the window holds pairs
            before = self._keys_tables.arrays[0]
            if self._old is None:  # then no value is kept yet: every pair moves
                self._old = np.zeros((before.shape[0], self.window))
            self._n_kept += kernels.keep_values(self._keys, self._kept, self._old, before)
        self._keys_tables = self.tables

    def _left(self, gone: int) -> None:
        self._n_kept -= gone
        if self._n_kept == 0:
            self._old = None  # every pair of the old tables has left the window

    @property
    def _window(self) -> FloatArray:
        """The window as the core holds it: (models, W) log-probabilities, 0.0 where empty."""
        self._sync_tables()
        log_probs = self.tables.arrays[0]
        filled = self._keys >= 0
        values = np.zeros((log_probs.shape[0], self.window))
        values[:, filled] = log_probs[:, self._keys[filled]]
        if self._old is not None:
            kept = self._kept == 1
            values[:, kept] = self._old[:, kept]
        return values

    def append(self, state: int, action: int) -> None:
        """Add (s, a) to H exactly as :meth:`Advisor.append` does."""
        t = self.tables
        if not (0 <= state < t.n_states and 0 <= action < N_ACTIONS):
            self._check(state, action)
        if self._keys_tables is not t:
            self._sync_tables()
        k = state * N_ACTIONS + action
        pos, loglik = self._pos, self._loglik
        leaving = int(self._keys[pos])
        tables = t.log_probs_flat
        if leaving < 0:
            for m, table in enumerate(tables):
                loglik[m] += table[k] - 0.0
        elif self._kept[pos] and self._old is not None:
            old = self._old[:, pos].tolist()
            for m, table in enumerate(tables):
                loglik[m] += table[k] - old[m]
            self._kept[pos] = 0
            self._left(1)
        else:
            for m, table in enumerate(tables):
                loglik[m] += table[k] - table[leaving]
        self._keys[pos] = k
        pos += 1
        self.steps += 1
        if pos == self.window:
            pos = 0
            if self.steps % resync_period(self.window) == 0:
                ring = self._window
                for m in range(len(loglik)):
                    loglik[m] = math.fsum(ring[m].tolist())
        self._pos = pos

    def observe_batch(
        self, states: IntArray, actions: IntArray, next_states: IntArray
    ) -> DecisionBatch:
        """``[self.observe(s, a, s2) for ...]`` as columns, in one compiled call. Inputs must
        be valid (states in range, actions 0..3): the caller checks them first."""
        n = len(states)
        count_before, benefit_before = self.advice_count, self.benefit
        self._sync_tables()
        tables = self.tables
        loglik = np.array(self._loglik, dtype=np.float64)
        kl, p_normal, benefit = np.empty(n), np.empty(n), np.empty(n)
        advise, count = np.empty(n, dtype=np.bool_), np.empty(n, dtype=np.int64)
        old = self._old if self._old is not None else _NO_RING
        pos, self.advice_count, self.benefit, gone = kernels.observe_stream(
            (self._keys, self._kept, old), loglik, self._pos, self.steps,
            resync_period(self.window), tables.arrays, self.kappa, count_before,
            benefit_before, (states, actions, next_states), (kl, p_normal, advise, count, benefit),
        )  # fmt: skip
        self._loglik, self._pos = loglik.tolist(), pos
        if gone:
            self._left(gone)
        self.steps += n
        self.decisions += n
        advice = tables.theta[next_states[advise]] if n else _NO_ADVICE
        return DecisionBatch(
            self.steps - n + 1, next_states, advise, kl, p_normal, count, benefit, advice,
            self.kappa, count_before, benefit_before, tables,
        )  # fmt: skip


class StreamGuide(GuideAdvisor):
    """A :class:`GuideAdvisor` whose batches run in one call of
    :func:`app.kernels.guide_stream`: the core's arithmetic in the core's order, leaving the
    advisor in the state the sequential calls leave it in, so single events (the core's own
    :meth:`observe`) and batches mix freely (``tests/service/live/test_stream.py``)."""

    __slots__ = ()

    def observe_batch(
        self, states: IntArray, actions: IntArray, next_states: IntArray
    ) -> DecisionBatch:
        n = len(states)
        count_before, benefit_before = self.advice_count, self.benefit
        g = self.guide
        ll = np.array(self._loglik, dtype=np.float64)
        alive = np.array(self.alive, dtype=np.bool_)
        last_advice = np.array(self._last_advice, dtype=np.float64)
        kl, p_normal, benefit = np.empty(n), np.empty(n), np.empty(n)
        advise, count = np.empty(n, dtype=np.bool_), np.empty(n, dtype=np.int64)
        rows = np.empty((n, N_ACTIONS))
        params = kernel_params(self.window, GuideParams(self.p_lost, self.slack, self.spread))
        got = kernels.guide_stream(
            g.arrays, params, g.goal_states, ll, alive, self._target, self._last, self._heading,
            last_advice, self.kappa, count_before, benefit_before,
            (states, actions, next_states), (kl, p_normal, advise, count, benefit, rows),
        )  # fmt: skip
        self._target, self._last, self._heading, self.advice_count, self.benefit = got
        self._loglik = ll.tolist()
        self.alive = alive.tolist()
        a = last_advice.tolist()
        self._last_advice = (a[0], a[1], a[2], a[3])
        self.steps += n
        self.decisions += n
        return DecisionBatch(
            self.steps - n + 1, next_states, advise, kl, p_normal, count, benefit, rows[advise],
            self.kappa, count_before, benefit_before, None,
        )  # fmt: skip
