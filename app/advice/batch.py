"""Many explorers sharing one prior, advanced with one numpy call per step.

Same arithmetic, in the same order, as :class:`app.advice.advisor.Advisor` (incremental
window sums, exact re-sum with ``math.fsum`` when a window wraps, sequential sums over models
and actions), so the decisions are those of the single form; ``tests/advice`` checks that on
random event streams. Explorers may advance in any subset (``idx``, indices without repeats)
and be reset one by one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from app.advice.advisor import DEFAULT_KAPPA, DEFAULT_WINDOW, check_kappa_window, resync_period
from app.advice.models import AdviceTables
from app.arrays import BoolArray, FloatArray, IntArray
from app.domain.grid import N_ACTIONS


@dataclass(frozen=True)
class BatchDecision:
    """Decisions for the explorers ``idx`` now at ``states``; advice is ``theta[states]``."""

    idx: IntArray
    states: IntArray
    advise: BoolArray
    kl: FloatArray
    p_normal: FloatArray
    advice_count: IntArray
    total_cost: FloatArray
    benefit: FloatArray


class BatchAdvisor:
    """``n_explorers`` advisors in arrays: window ring (E, M, W), sums (E, M), cost (E,)."""

    def __init__(
        self,
        tables: AdviceTables,
        n_explorers: int,
        kappa: float | npt.ArrayLike = DEFAULT_KAPPA,
        window: int = DEFAULT_WINDOW,
    ):
        kap = np.broadcast_to(np.asarray(kappa, dtype=np.float64), (n_explorers,)).copy()
        for k in np.unique(kap):
            check_kappa_window(float(k), window)
        if n_explorers < 1:
            raise ValueError(f"n_explorers must be at least 1, got {n_explorers}")
        self.tables = tables
        self.n_explorers = int(n_explorers)
        self.window = int(window)
        self.kappa = kap
        m = tables.n_models
        # one flat ring per model: explorer e's window is ring[m, e*W:(e+1)*W]
        self._ring = np.zeros((m, n_explorers * window))
        self._loglik = np.zeros((m, n_explorers))
        self._pos = np.zeros(n_explorers, dtype=np.int64)
        self.steps = np.zeros(n_explorers, dtype=np.int64)
        self.decisions = np.zeros(n_explorers, dtype=np.int64)
        self.advice_count = np.zeros(n_explorers, dtype=np.int64)
        self.benefit = np.zeros(n_explorers)
        self._all = np.arange(n_explorers, dtype=np.int64)
        self._base = self._all * window
        # scratch space, so a step allocates (almost) nothing: large temporaries per step cost
        # more in page faults than in arithmetic (measured: see docs/PERFORMANCE.md)
        self._mats = np.empty((2, N_ACTIONS * n_explorers))
        self._vecs = np.empty((4, n_explorers))
        self._post = np.empty(m * n_explorers)

    def _mat(self, j: int, k: int) -> FloatArray:
        out: FloatArray = self._mats[j, : N_ACTIONS * k].reshape(N_ACTIONS, k)
        return out

    def _vec(self, j: int, k: int) -> FloatArray:
        out: FloatArray = self._vecs[j, :k]
        return out

    def _sel(self, idx: npt.ArrayLike | None) -> tuple[IntArray, slice | IntArray]:
        """(explicit indices, the cheapest selector for them: a slice when all explorers)."""
        i = self._index(idx)
        return i, (slice(None) if idx is None else i)

    def _index(self, idx: npt.ArrayLike | None) -> IntArray:
        if idx is None:
            return self._all
        out = np.asarray(idx, dtype=np.int64)
        if out.size and (out.min() < 0 or out.max() >= self.n_explorers):
            raise ValueError(f"explorer index out of range 0..{self.n_explorers - 1}")
        return out

    def _check(self, states: IntArray, actions: IntArray | None = None) -> None:
        n = self.tables.n_states
        if states.size and (states.min() < 0 or states.max() >= n):
            raise ValueError(f"state out of range 0..{n - 1}")
        if actions is not None and actions.size and (actions.min() < 0 or actions.max() > 3):
            raise ValueError("action out of range 0..3")

    def reset(self, idx: npt.ArrayLike | None = None) -> None:
        i = self._index(idx)
        ring = self._ring.reshape(self._ring.shape[0], self.n_explorers, self.window)
        ring[:, i] = 0.0
        self._loglik[:, i] = 0.0
        self._pos[i] = 0
        for arr in (self.steps, self.decisions, self.advice_count):
            arr[i] = 0
        self.benefit[i] = 0.0

    def append(
        self, states: npt.ArrayLike, actions: npt.ArrayLike, idx: npt.ArrayLike | None = None
    ) -> None:
        """Add one (s, a) to each window in ``idx`` (all explorers by default)."""
        i, sel = self._sel(idx)
        s = np.asarray(states, dtype=np.int64)
        a = np.asarray(actions, dtype=np.int64)
        self._check(s, a)
        k = s.size
        pos = self._pos[sel]
        slot = self._base[sel] + pos
        key = s * N_ACTIONS + a
        lp, delta = self._vec(0, k), self._vec(1, k)
        log_probs = self.tables.log_probs.reshape(self._ring.shape[0], -1)  # (M, S*4) view
        for m in range(self._ring.shape[0]):
            ring = self._ring[m]
            np.take(log_probs[m], key, out=lp, mode="clip")  # indices checked above
            np.take(ring, slot, out=delta, mode="clip")
            np.subtract(lp, delta, out=delta)
            self._loglik[m, sel] += delta  # same order as the single form: L + (lp - old)
            ring.put(slot, lp)
        pos += 1
        self.steps[sel] += 1
        wrapped = pos == self.window
        if wrapped.any():
            pos[wrapped] = 0
            w = self.window
            due = wrapped & (self.steps[sel] % resync_period(w) == 0)
            for e in i[due].tolist():
                for m in range(self._ring.shape[0]):
                    self._loglik[m, e] = math.fsum(self._ring[m, e * w : (e + 1) * w].tolist())
        self._pos[sel] = pos

    def posterior(self, idx: npt.ArrayLike | None = None) -> FloatArray:
        """P(M | H), shape (n, M)."""
        i, sel = self._sel(idx)
        return self._posterior(sel, i.size).T.copy()

    def _posterior(self, sel: slice | IntArray, k: int) -> FloatArray:
        """P(M | H) for the selected explorers as an (M, k) view of scratch space (eq. 5)."""
        lw = self.tables.log_weights
        post: FloatArray = self._post[: len(lw) * k].reshape(len(lw), k)
        for m in range(len(lw)):
            np.add(self._loglik[m, sel], lw[m], out=post[m])
        mx = self._vec(2, k)
        np.max(post, axis=0, out=mx)
        np.subtract(post, mx, out=post)
        np.exp(post, out=post)
        tot = self._vec(3, k)
        tot[:] = post[0]
        for m in range(1, len(lw)):
            tot += post[m]
        np.divide(post, tot, out=post)
        return post

    def decide(self, states: npt.ArrayLike, idx: npt.ArrayLike | None = None) -> BatchDecision:
        i, sel = self._sel(idx)
        s = np.asarray(states, dtype=np.int64)
        self._check(s)
        k = s.size
        t = self.tables
        post = self._posterior(sel, k)
        probs = t.probs_t  # (M, 4, S): rows per action, so every array below is (4, k)
        mix, tmp = self._mat(0, k), self._mat(1, k)
        np.take(probs[0], s, axis=1, out=mix, mode="clip")  # eq. (4)
        mix *= post[0]
        for m in range(1, len(post)):
            np.take(probs[m], s, axis=1, out=tmp, mode="clip")
            tmp *= post[m]
            mix += tmp
        np.log(mix, out=mix)
        np.take(t.theta_t, s, axis=1, out=tmp, mode="clip")
        tmp *= mix  # theta_s(a) log P(a | s, H)
        cross = self._vec(0, k)
        np.add(tmp[0], tmp[1], out=cross)
        for a in range(2, N_ACTIONS):
            cross += tmp[a]
        kl = t.neg_entropy.take(s) - cross  # eq. (6): KL[theta_s || P(A | s, H)]
        np.maximum(kl, 0.0, out=kl)
        kappa = self.kappa[sel]
        advise = kl >= kappa
        self.decisions[sel] += 1
        self.advice_count[sel] += advise
        self.benefit[sel] += np.where(advise, kl, 0.0)
        count = self.advice_count[sel].copy()  # copies: views would alias live counters/scratch
        return BatchDecision(
            i, s, advise, kl, post[0].copy(), count, kappa * count, self.benefit[sel].copy()
        )

    def start(self, states: npt.ArrayLike, idx: npt.ArrayLike | None = None) -> BatchDecision:
        """Reset explorers ``idx`` and decide for their start states (empty H)."""
        self.reset(idx)
        return self.decide(states, idx)

    def observe(
        self,
        states: npt.ArrayLike,
        actions: npt.ArrayLike,
        next_states: npt.ArrayLike,
        idx: npt.ArrayLike | None = None,
    ) -> BatchDecision:
        self.append(states, actions, idx)
        return self.decide(next_states, idx)

    def advice(self, states: npt.ArrayLike) -> FloatArray:
        """theta_s for each state: the advice given where ``advise`` is true."""
        out: FloatArray = self.tables.theta[np.asarray(states, dtype=np.int64)]
        return out

    @property
    def total_cost(self) -> FloatArray:
        out: FloatArray = self.kappa * self.advice_count
        return out

    @property
    def advice_per_100(self) -> FloatArray:
        return np.where(
            self.decisions > 0, 100.0 * self.advice_count / np.maximum(self.decisions, 1), 0.0
        )
