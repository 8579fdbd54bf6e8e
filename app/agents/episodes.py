"""Reference episode loops: an explorer, the core :class:`~app.advice.advisor.Advisor`, a goal.

Plain Python, one step at a time: the obvious version the compiled kernels in
:mod:`app.kernels` are tested against, and readable documentation of the protocol.

One step (docs/METHOD.md): the advisor has decided for the explorer's state ``s``; the explorer
acts (sampling the advice, ``decision.advice``, if advised and ``advised`` is on), moves to
``s'``; reaching its goal ends the episode; otherwise the advisor appends (s, a) to its
window and decides for ``s'``. Any advisor of :mod:`app.strategies` can watch.
With ``advised=False`` the advisor still watches (its P(M1 | H) is recorded) but its advice
is not passed on.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from app.advice.advisor import Advisor, Decision
from app.agents.explorers import FixedPolicyExplorer
from app.agents.qlearning import GOAL_REWARD, QLearningExplorer
from app.domain.grid import GridDomain


@dataclass
class EpisodeRecord:
    """What happened in one episode."""

    states: list[int] = field(default_factory=list)  # the state of each decision, in order
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


def run_episode(
    domain: GridDomain,
    explorer: FixedPolicyExplorer | QLearningExplorer,
    advisor: Advisor,
    goal: int,
    rng: np.random.Generator,
    *,
    advised: bool = True,
    max_steps: int = 5000,
    new_task: bool = True,
    new_history: bool = True,
) -> EpisodeRecord:
    """One episode from the start cell; the Q-learner also learns from every move.

    ``new_task`` calls ``explorer.reset`` (a Q-learner forgets its table); ``new_history``
    starts a new advisor session (empty window, cost zero).
    """
    if new_task:
        explorer.reset(goal, rng)
    if new_history:
        advisor.reset()
    rec = EpisodeRecord()
    s = domain.start
    decision = advisor.decide(s)
    for _ in range(max_steps):
        rec.states.append(s)
        rec.decisions.append(decision)
        # the advisor's payload: theta_s for the paper's rule, theta^w_s for goal-aware advice
        advice = np.asarray(decision.advice) if advised and decision.advice is not None else None
        a = explorer.act(s, rng, advice)
        s_next = int(domain.next_state[s, a])
        rec.actions.append(a)
        if isinstance(explorer, QLearningExplorer):
            explorer.learn(s, a, s_next)
        else:
            explorer.observe(s, a, s_next)
        if s_next == goal:
            rec.success = True
            break
        decision = advisor.observe(s, a, s_next)
        s = s_next
    return rec


def run_learning(
    domain: GridDomain,
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
