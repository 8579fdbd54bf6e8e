"""Reference episode loops: an explorer, the core :class:`~app.advice.advisor.Advisor`, a goal.

Plain Python, one step at a time: the obvious version the compiled kernels in
:mod:`app.kernels` are tested against, and readable documentation of the protocol.

One step (docs/METHOD.md): the advisor has decided for the explorer's state ``s``; the explorer
acts (sampling the advice, ``decision.advice``, if advised and ``advised`` is on), moves to
``s'``; reaching its goal ends the episode; otherwise the advisor appends (s, a) to its
window and decides for ``s'``. Any advisor of :mod:`app.strategies` can watch.
With ``advised=False`` the advisor still watches (its P(M1 | H) is recorded) but its advice
is not passed on. A visitor's compliance, position noise and sight (``compliance``, ``noise``,
``sight``) change the loop as :mod:`app.agents.explorers` describes, step by step; their
defaults are the paper's protocol.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from app.advice.advisor import Advisor, Decision
from app.agents.explorers import FixedPolicyExplorer, in_sight, read_position
from app.agents.qlearning import GOAL_REWARD, QLearningExplorer
from app.domain.building import Domain
from app.domain.paths import walked_cells


@dataclass
class EpisodeRecord:
    """What happened in one episode."""

    states: list[int] = field(default_factory=list)  # the explorer's cell at each decision
    actions: list[int] = field(default_factory=list)
    decisions: list[Decision] = field(default_factory=list)
    success: bool = False

    @property
    def steps(self) -> int:
        return len(self.actions)

    @property
    def reward(self) -> float:
        return GOAL_REWARD if self.success else 0.0

    @property
    def advice_count(self) -> int:
        return sum(d.advise for d in self.decisions)


def visitor_act(
    domain: Domain,
    explorer: FixedPolicyExplorer | QLearningExplorer,
    x: int,
    goal: int,
    decision: Decision,
    rng: np.random.Generator,
    advised: bool,
    compliance: float,
    sight: int,
) -> int:
    """The explorer's move from ``x`` after ``decision``: to its goal when in sight (whatever
    the advice), else its own, sampling the advice (if advised) unless one draw says it
    keeps to its own way this time (only when ``compliance`` < 1)."""
    # the advisor's payload: theta_s for the paper's rule, theta^w_s for goal-aware advice
    advice = np.asarray(decision.advice) if advised and decision.advice is not None else None
    seen = in_sight(domain, x, goal, sight) if sight > 0 else None
    if seen is not None:  # its goal in sight: it walks there, whatever the advice
        return seen
    if advice is not None and compliance < 1.0 and rng.random() >= compliance:
        advice = None  # it keeps to its own way this time
    return explorer.act(x, rng, advice)


def run_episode(
    domain: Domain,
    explorer: FixedPolicyExplorer | QLearningExplorer,
    advisor: Advisor,
    goal: int,
    rng: np.random.Generator,
    *,
    advised: bool = True,
    max_steps: int = 5000,
    new_task: bool = True,
    new_history: bool = True,
    compliance: float = 1.0,
    noise: float = 0.0,
    sight: int = 0,
    seen_rng: np.random.Generator | None = None,
    positions: bool = False,
    jump: int = 1,
    max_walk: int = 8,
) -> EpisodeRecord:
    """One episode from the start cell; the Q-learner also learns from every move.

    ``new_task`` calls ``explorer.reset`` (a Q-learner forgets its table); ``new_history``
    starts a new advisor session (empty window, cost zero). ``seen_rng`` draws the readings
    of the explorer's cell (needed when ``noise`` > 0).

    With ``positions`` the advisor is fed as the service's ``/positions`` endpoint feeds it:
    after each move the cell is read (up to ``jump`` moves off with probability ``noise``)
    and walked from the last reading (:func:`app.domain.paths.walked_cells`), one decision
    per cell walked and none for a reading in the same cell; the explorer acts on the last
    decision. A reading more than ``max_walk`` moves from the last (the service's
    ``max_jump``) is dropped, as a refused batch is. ``rec.decisions`` holds the decision
    each move was acted on; no decision is made after the last move.
    """
    if noise > 0.0 and seen_rng is None:
        raise ValueError("position noise needs seen_rng, the readings' generator")
    readings = seen_rng if seen_rng is not None else rng  # not drawn from at noise 0
    if new_task:
        explorer.reset(goal, rng)
    if new_history:
        advisor.reset()
    rec = EpisodeRecord()
    x = domain.start  # where the explorer is
    s = read_position(domain, x, noise, readings, jump)  # where the advisor sees it
    decision = advisor.decide(s)
    for t in range(max_steps):
        rec.states.append(x)
        rec.decisions.append(decision)
        a = visitor_act(domain, explorer, x, goal, decision, rng, advised, compliance, sight)
        x_next = int(domain.next_state[x, a])
        rec.actions.append(a)
        if isinstance(explorer, QLearningExplorer):
            explorer.learn(x, a, x_next)
        else:
            explorer.observe(x, a, x_next)
        if x_next == goal:
            rec.success = True
            break
        if not positions:
            s_next = read_position(domain, x_next, noise, readings)
            decision = advisor.observe(s, a, s_next)
            s, x = s_next, x_next
            continue
        if t + 1 == max_steps:
            break  # no decision after the last move (as the compiled episodes)
        s_next = read_position(domain, x_next, noise, readings, jump)
        for cell in walked_cells(domain, s, s_next, max_walk) or ():
            move = int(np.argmax(domain.next_state[s] == cell))
            decision = advisor.observe(s, move, cell)
            s = cell
        x = x_next
    return rec


def run_learning(
    domain: Domain,
    learner: QLearningExplorer,
    advisor: Advisor,
    goal: int,
    rng: np.random.Generator,
    *,
    episodes: int,
    advised: bool = True,
    max_steps: int = 200,
    keep_history: bool = True,
) -> list[EpisodeRecord]:
    """``episodes`` episodes of one learning task; the learner keeps its Q-table throughout.

    ``keep_history``: the advisor's window carries over from one episode to the next (it
    watches the same explorer); otherwise each episode is a new advisor session.
    """
    out = []
    for e in range(episodes):
        out.append(
            run_episode(
                domain,
                learner,
                advisor,
                goal,
                rng,
                advised=advised,
                max_steps=max_steps,
                new_task=e == 0,
                new_history=e == 0 or not keep_history,
            )
        )
    return out
