"""``guide``: advice that leads a lost explorer to a destination of the map (beyond the paper).

The paper's advisor can only repeat what experts did where they went: in a cell no expert
visited theta is uniform and no advice is possible, and its theta pools every destination, so
it can lead into another destination's dead end. A building knows more: its map and its
destinations. ``guide`` keeps a posterior over what the explorer is doing, with these models of
its next action ``a`` at ``s`` (docs/ARCHITECTURE.md has the equations beside the paper's)::

    L4      lost, any action:                1/4
    LO      lost, any open move:             lo(a | s) = (1 - b) open(s, a) / n_open(s) + b/4
    WL, WR  lost, a hand on the wall:        (1 - slack) [a = w(s, h)]' + slack lo(a | s)
    D4_g    on its way to destination g:     (1 - slack) pi_g(a | s) + slack/4
    DO_g    the same, never into a wall:     (1 - slack) pi_g(a | s) + slack lo(a | s)
    C_g     heading for g as the crow flies: (1 - slack) c_g(a | s)' + slack lo(a | s)

* ``w(s, h)``: the move of someone keeping the left (WL) or right (WR) hand on the wall,
  heading ``h`` (the last move that moved).
* ``pi_g``: uniform over the moves that shorten the BFS distance to ``g``, each weighted by
  1 + the experts' goal-``g`` count of (s, a), so that among shortest moves the experts'
  routes are preferred; at ``g`` itself, or where ``g`` cannot be reached, uniform over the
  open moves.
* ``c_g``: uniform over the open moves that shorten the straight (Manhattan) distance to
  ``g``: someone who heads for where the destination is and meets a wall; where no move does,
  uniform over the four (it says nothing).
* ``'``: where the last decision advised theta at ``s``, the rule's indicator or c_g is
  averaged with theta_s: these explorers take the advice or their own way, and undo the
  advice afterwards, so a detour must be advised step by step.

The evidence fades with time constant W, the session's window::

    L_k  <-  lam L_k + log P(a | s, k)            lam = 1 - 1/W
    P(k | H)  ~  exp(L_k) P(k)                    P(L4) = ... = P(WR) = p_lost / 4,
                                                  3 n_alive P(D4_g) = ... = 1 - p_lost

A destination is ruled out once the explorer stood on it and went on (its task would have
ended there); if every one is, all count again. The advice leads to a *target* T, the
destination not ruled out with the largest (P(g | H) + P(lost | H) / n_alive) / (d_g(s) + 1),
where P(g | H) = P(D4_g | H) + P(DO_g | H) + P(C_g | H), kept until it is ruled out or another
scores more than twice as much (no flapping between two)::

    theta_s     = (1 - spread) [P(lost | H) pi_T(s) + sum_g P(g | H) pi_g(s)] + spread/4
    P(A | s, H) = sum_k P(k | H) P(A | s, k)
    advise  iff  KL[theta_s || P(A | s, H)] >= kappa           (the paper's eq. 6 and cost)

A competent explorer is explained by some D_g, so the prediction already is the advice and
nothing is said; a lost one is explained by a lost model and is led; one that heads for its
destination into a wall is explained by C_g and is shown the way round. P(M1 | H) is
reported as 1 - P(lost | H). This is plain Python in a fixed order; app/kernels.py's
guide_decide, guide_append and guide_stream are the same arithmetic, compiled, and the tests
compare them bit for bit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from app.advice.advisor import DEFAULT_KAPPA, DEFAULT_WINDOW, Advisor, Decision
from app.advice.models import AdviceTables
from app.advice.priors import GoalPriors
from app.domain.grid import N_ACTIONS, GridDomain

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

#: probability mass the open-moves lost model gives to bumping into walls
LOST_BUMP = 0.02
#: the lost models: L4, LO, WL, WR
N_LOST = 4
#: a new target must score more than this many times the current one
SWITCH = 2.0
#: most destinations x states a guide map holds (its distances: 8 bytes each)
MAX_GUIDE_CELLS = 16_777_216


class GuideError(ValueError):
    """The domain cannot be guided (no destination, or too many destinations x states)."""


@dataclass(frozen=True, eq=False)
class GuideMap:
    """What ``guide`` reads of a domain: its moves, the BFS distance from every state to every
    destination, and the experts' per-destination counts (zeros where there are none)."""

    next_state: IntArray  # (S, 4)
    n_open: IntArray  # (S,) open moves per state
    cells: IntArray  # (S, 2) row, column
    dist: IntArray  # (G, S), -1 where unreachable
    goal_of_state: IntArray  # (S,) destination index, -1 elsewhere
    counts: FloatArray  # (G, S * 4) experts' goal counts
    goals: tuple[int, ...]

    @classmethod
    def of(cls, domain: GridDomain, goal_priors: GoalPriors | None = None) -> GuideMap:
        goals = tuple(int(g) for g in domain.goals)
        if not goals:
            raise GuideError("guide advice needs the map's destinations: this map has no goal")
        most = MAX_GUIDE_CELLS
        if len(goals) * domain.n_states > most:
            raise GuideError(
                f"guide advice holds a distance per destination and cell: {len(goals)} "
                f"destinations x {domain.n_states} cells is more than {most}"
            )
        s = domain.n_states
        of_state = np.full(s, -1, dtype=np.int64)
        of_state[list(goals)] = np.arange(len(goals))
        plain = cls(
            np.ascontiguousarray(domain.next_state, dtype=np.int64),
            np.ascontiguousarray(domain.open_moves.sum(axis=1), dtype=np.int64),
            np.ascontiguousarray(domain.cells, dtype=np.int64),
            np.ascontiguousarray(domain.goal_distances, dtype=np.int64),
            of_state,
            np.zeros((len(goals), s * N_ACTIONS)),
            goals,
        )
        return plain if goal_priors is None else plain.replace_counts(goal_priors)

    @property
    def n_states(self) -> int:
        return int(self.next_state.shape[0])

    @property
    def n_goals(self) -> int:
        return len(self.goals)

    @property
    def arrays(self) -> tuple[IntArray, IntArray, IntArray, IntArray, IntArray, FloatArray]:
        """As app/kernels.py reads it."""
        return (
            self.next_state, self.n_open, self.cells, self.dist, self.goal_of_state, self.counts,
        )  # fmt: skip

    @property
    def goal_states(self) -> IntArray:
        return np.array(self.goals, dtype=np.int64)

    def replace_counts(self, goal_priors: GoalPriors) -> GuideMap:
        """The same map with the experts' counts of ``goal_priors`` (read, not copied, when
        its goals are the map's: a prior update costs no copy per session)."""
        if goal_priors.n_states != self.n_states:
            raise ValueError("the goal priors describe another domain")
        if goal_priors.goals == self.goals:
            counts = goal_priors.goal_counts.reshape(self.n_goals, -1)
        else:
            counts = np.zeros_like(self.counts)
            for i, cell in enumerate(self.goals):
                gi = goal_priors.goal_index.get(cell)
                if gi is not None:
                    counts[i] = goal_priors.goal_counts[gi].reshape(-1)
        return GuideMap(
            self.next_state, self.n_open, self.cells, self.dist, self.goal_of_state, counts,
            self.goals,
        )  # fmt: skip

    def policy(self, g: int, s: int) -> list[float]:
        """pi_g(. | s): the shortest moves towards destination g, weighted 1 + expert count."""
        d = int(self.dist[g, s])
        if d > 0:
            w = [0.0, 0.0, 0.0, 0.0]
            tot = 0.0
            for a in range(N_ACTIONS):
                if int(self.dist[g, int(self.next_state[s, a])]) == d - 1:
                    w[a] = 1.0 + float(self.counts[g, s * N_ACTIONS + a])
                    tot += w[a]
            return [w[0] / tot, w[1] / tot, w[2] / tot, w[3] / tot]
        return self.open_policy(s)

    def compass(self, g: int, s: int) -> list[float]:
        """c_g(. | s): the open moves that shorten the straight distance to destination g."""
        gs = self.goals[g]
        dr = int(self.cells[gs, 0]) - int(self.cells[s, 0])
        dc = int(self.cells[gs, 1]) - int(self.cells[s, 1])
        ok = [dr < 0, dc > 0, dr > 0, dc < 0]  # N, E, S, W
        n = 0
        for a in range(N_ACTIONS):
            if ok[a] and int(self.next_state[s, a]) != s:
                n += 1
        if n == 0:  # no way closer: nothing said
            return [0.25, 0.25, 0.25, 0.25]
        return [
            1.0 / n if ok[a] and int(self.next_state[s, a]) != s else 0.0 for a in range(N_ACTIONS)
        ]

    def wall(self, s: int, heading: int, hand: int) -> int:
        """The move of a wall follower at ``s`` heading ``heading`` (-1: none yet, then its
        first open way, N E S W): the left hand's (``hand`` 0: left, straight, right, back) or
        the right hand's (1: right, straight, left, back); -1 where every way is shut."""
        turns = (0, 1, 2, 3) if heading < 0 else ((3, 0, 1, 2) if hand == 0 else (1, 0, 3, 2))
        h = max(heading, 0)
        for turn in turns:
            a = (h + turn) % 4
            if int(self.next_state[s, a]) != s:
                return a
        return -1

    def open_policy(self, s: int) -> list[float]:
        """Uniform over the open moves of s (over all four where none is open)."""
        n = int(self.n_open[s])
        if n == 0:
            return [0.25, 0.25, 0.25, 0.25]
        return [1.0 / n if int(self.next_state[s, a]) != s else 0.0 for a in range(N_ACTIONS)]


@dataclass(frozen=True)
class GuideParams:
    """guide's own parameters: their defaults, bounds and meaning are those of
    :class:`app.advice.strategies.StrategyParams` (``guide_params`` makes one)."""

    p_lost: float
    slack: float
    spread: float


def kernel_params(window: int, p: GuideParams) -> tuple[float, float, float, float, float]:
    """The parameters as app/kernels.py reads them: (lam, p_lost, slack, spread, bump), with
    lam = 1 - 1/W the evidence's fading."""
    return (1.0 - 1.0 / window, float(p.p_lost), float(p.slack), float(p.spread), LOST_BUMP)


class GuideAdvisor(Advisor):
    """Leads explorers that look lost to a destination of the map; see the module text."""

    own_advice = True

    __slots__ = (
        "_heading", "_lam", "_last", "_last_advice", "_target", "alive", "guide", "p_lost",
        "slack", "spread",
    )  # fmt: skip

    def __init__(
        self,
        tables: AdviceTables,
        guide: GuideMap,
        kappa: float = DEFAULT_KAPPA,
        window: int = DEFAULT_WINDOW,
        *,
        params: GuideParams,
    ):
        if guide.n_states != tables.n_states:
            raise ValueError("guide map and tables describe different domains")
        p = params
        self.guide = guide
        self.p_lost, self.slack, self.spread = float(p.p_lost), float(p.slack), float(p.spread)
        if not (0.0 < self.p_lost < 1.0 and 0.0 < self.slack <= 1.0 and 0 <= self.spread <= 1):
            raise ValueError("need 0 < p_lost < 1, 0 < slack <= 1 and 0 <= spread <= 1")
        super().__init__(tables, kappa, window)
        self._lam = kernel_params(self.window, p)[0]

    @property
    def strategy(self) -> str:
        return "guide"

    def params(self) -> dict[str, int | float]:
        return {"p_lost": self.p_lost, "slack": self.slack, "spread": self.spread}

    def use_tables(self, tables: AdviceTables, goals: GoalPriors | None = None) -> None:
        """New tables; new per-goal counts (more expert trajectories) re-weight the routes."""
        if goals is not None:
            self.guide = self.guide.replace_counts(goals)
        super().use_tables(tables)

    def reset(self) -> None:
        # the paper's window is not kept: guide's evidence is the faded sums below
        self._ring = []
        self._pos = 0
        self.steps = 0
        self.decisions = 0
        self.advice_count = 0
        self.benefit = 0.0
        self._loglik = [0.0] * (N_LOST + 3 * self.guide.n_goals)
        self.alive = [True] * self.guide.n_goals
        self._target = -1
        self._last = -1  # the state the last decision advised (-1: it did not advise)
        self._last_advice = (0.25, 0.25, 0.25, 0.25)
        self._heading = -1  # the last move that moved (-1: none yet)

    @property
    def target(self) -> int:
        """The destination (index) the advice leads to; -1 before the first decision."""
        return self._target

    def append(self, state: int, action: int) -> None:
        """Fade the evidence and add log P(a | s, k) for every model."""
        self._check(state, action)
        g = self.guide
        lam, slack = self._lam, self.slack
        ll = self._loglik
        lo = self._lost_open(state)[action]
        ll[0] = lam * ll[0] + math.log(0.25)
        ll[1] = lam * ll[1] + math.log(lo)
        advised = state == self._last
        for hand in range(2):
            ind = 1.0 if action == g.wall(state, self._heading, hand) else 0.0
            if advised:
                ind = 0.5 * (ind + self._last_advice[action])
            ll[2 + hand] = lam * ll[2 + hand] + math.log((1.0 - slack) * ind + slack * lo)
        for i in range(g.n_goals):
            pa = g.policy(i, state)[action]
            ca = g.compass(i, state)[action]
            if advised:
                ca = 0.5 * (ca + self._last_advice[action])
            k = N_LOST + 3 * i
            ll[k] = lam * ll[k] + math.log((1.0 - slack) * pa + slack / 4.0)
            ll[k + 1] = lam * ll[k + 1] + math.log((1.0 - slack) * pa + slack * lo)
            ll[k + 2] = lam * ll[k + 2] + math.log((1.0 - slack) * ca + slack * lo)
        gi = int(g.goal_of_state[state])
        if gi >= 0:  # it stood on this destination and went on: not its destination
            self.alive[gi] = False
        if int(g.next_state[state, action]) != state:
            self._heading = action
        self.steps += 1

    def _lost_open(self, s: int) -> list[float]:
        o = self.guide.open_policy(s)
        return [(1.0 - LOST_BUMP) * o[a] + LOST_BUMP / 4.0 for a in range(N_ACTIONS)]

    def _alive(self) -> list[bool]:
        return self.alive if any(self.alive) else [True] * len(self.alive)

    def model_posterior(self) -> list[float]:
        """P(k | H): L4, LO, WL, WR, then D4_g, DO_g, C_g per destination (0 for those ruled
        out)."""
        alive = self._alive()
        n_alive = sum(alive)
        lw_lost = math.log(self.p_lost / 4.0)
        lw_dir = math.log((1.0 - self.p_lost) / (3.0 * n_alive))
        ll = self._loglik
        z = [ll[k] + lw_lost for k in range(N_LOST)]
        for i, on in enumerate(alive):
            for j in range(3):
                z.append(ll[N_LOST + 3 * i + j] + lw_dir if on else -math.inf)
        mx = max(z)
        e = [0.0 if v == -math.inf else (1.0 if v == mx else math.exp(v - mx)) for v in z]
        tot = 0.0
        for v in e:
            tot += v
        return [v / tot for v in e]

    def goal_beliefs(self) -> list[tuple[int, float, bool]]:
        """(destination, P(g | H) + P(lost | H) / n_alive, ruled out) per destination."""
        post = self.model_posterior()
        alive = self._alive()
        n_alive = sum(alive)
        lost = post[0] + post[1] + post[2] + post[3]
        return [
            (cell, self._p_goal(post, i) + lost / n_alive if alive[i] else 0.0, not self.alive[i])
            for i, cell in enumerate(self.guide.goals)
        ]

    @staticmethod
    def _p_goal(post: list[float], i: int) -> float:
        k = N_LOST + 3 * i
        return post[k] + post[k + 1] + post[k + 2]

    def decide(self, state: int) -> Decision:
        self._check(state)
        g = self.guide
        post = self.model_posterior()
        alive = self._alive()
        n_alive = 0
        for on in alive:
            n_alive += 1 if on else 0
        lost = post[0] + post[1] + post[2] + post[3]
        pis = [g.policy(i, state) if alive[i] else None for i in range(g.n_goals)]
        cs = [g.compass(i, state) if alive[i] else None for i in range(g.n_goals)]
        # the target: kept unless ruled out or clearly beaten
        best, best_score = -1, -1.0
        cur = -1.0
        for i in range(g.n_goals):
            d = int(g.dist[i, state])
            if not alive[i] or d < 0:
                continue
            score = (self._p_goal(post, i) + lost / n_alive) / (d + 1.0)
            if score > best_score:
                best, best_score = i, score
            if i == self._target:
                cur = score
        if self._target < 0 or cur < 0.0 or best_score > SWITCH * cur:
            self._target = best
        pi_t = pis[self._target] if self._target >= 0 else None
        if pi_t is None:
            pi_t = g.open_policy(state)
        lo = self._lost_open(state)
        wl, wr = g.wall(state, self._heading, 0), g.wall(state, self._heading, 1)
        slack, spread = self.slack, self.spread
        theta = [0.0, 0.0, 0.0, 0.0]
        kl = 0.0
        for a in range(N_ACTIONS):
            v = lost * pi_t[a]
            m = post[0] * 0.25 + post[1] * lo[a]
            m += post[2] * ((1.0 - slack) * (1.0 if a == wl else 0.0) + slack * lo[a])
            m += post[3] * ((1.0 - slack) * (1.0 if a == wr else 0.0) + slack * lo[a])
            for i in range(g.n_goals):
                pi, c = pis[i], cs[i]
                if pi is not None and c is not None:
                    k = N_LOST + 3 * i
                    v += self._p_goal(post, i) * pi[a]
                    m += post[k] * ((1.0 - slack) * pi[a] + slack / 4.0)
                    m += post[k + 1] * ((1.0 - slack) * pi[a] + slack * lo[a])
                    m += post[k + 2] * ((1.0 - slack) * c[a] + slack * lo[a])
            th = (1.0 - spread) * v + spread / 4.0
            theta[a] = th
            if th > 0.0:
                kl += th * (math.log(th) - math.log(m))
        kl = kl if kl > 0.0 else 0.0
        row = (theta[0], theta[1], theta[2], theta[3])
        advise = kl >= self.kappa
        self._last = state if advise else -1
        if advise:
            self._last_advice = row
        return self.record(state, advise, row, kl, 1.0 - lost)
