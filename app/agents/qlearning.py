"""The learning explorer: epsilon-greedy tabular Q-learning (Sutton & Barto), advised.

Reward 1000 on reaching its goal (the episode ends), 0 otherwise; Q starts at 0. Per step,
with ``u1 = rng.random()``:

* ``u1 < epsilon`` (explore): sample the advice theta_s if the advisor advised at this state,
  else a uniform action of the domain's (one more draw: four, or six in a building of
  several floors, whose ``U`` and ``D`` it learns as any move).
* otherwise (exploit): the action with the largest Q(s, .). When several actions tie (always
  the case before the first reward reaches s), one more draw breaks the tie: with
  ``ties="advice"`` by sampling the advice restricted to the tied actions when advice was
  given, uniformly otherwise; with ``ties="uniform"`` always uniformly.

The tie rule is a choice the paper leaves open. With Q = 0 everywhere until a goal is found,
a learner whose ties ignore the advice acts uniformly at random 90% of the time however
much it is advised; ``"advice"`` lets the advice shape the choices it has no preference
about. Both are measured (docs/RESULTS.md).

Update (off-policy, whatever chose the action)::

    Q(s, a) += alpha * (r + gamma * max_a' Q(s', a') - Q(s, a))      (no bootstrap at the goal)
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from app.agents.explorers import sample_action, uniform_choice
from app.arrays import FloatArray
from app.domain.building import Domain

TieRule = Literal["advice", "uniform"]
TIE_RULES: tuple[str, ...] = ("advice", "uniform")
GOAL_REWARD = 1000.0


class QLearningExplorer:
    """Epsilon-greedy tabular Q-learning whose exploration follows the advice when given."""

    name = "q-learning"

    def __init__(
        self,
        domain: Domain,
        alpha: float = 0.1,
        gamma: float = 0.95,
        epsilon: float = 0.1,
        ties: TieRule = "advice",
    ):
        if not (0 < alpha <= 1 and 0 <= gamma <= 1 and 0 <= epsilon <= 1):
            raise ValueError(
                f"need 0 < alpha <= 1, 0 <= gamma <= 1, 0 <= epsilon <= 1; "
                f"got alpha={alpha}, gamma={gamma}, epsilon={epsilon}"
            )
        if ties not in TIE_RULES:
            raise ValueError(f"ties must be one of {', '.join(TIE_RULES)}, got {ties!r}")
        self.domain = domain
        self.alpha = alpha
        self.gamma = gamma
        self.epsilon = epsilon
        self.ties = ties
        self.goal = domain.goals[0]
        self.q = np.zeros((domain.n_states, domain.n_actions))

    def reset(self, goal: int, rng: np.random.Generator) -> None:
        """A new task: forget what was learned."""
        self.goal = goal
        self.q = np.zeros((self.domain.n_states, self.domain.n_actions))

    def act(self, state: int, rng: np.random.Generator, advice: FloatArray | None = None) -> int:
        if rng.random() < self.epsilon:
            if advice is not None:
                return sample_action(advice, rng.random())
            return int(rng.random() * self.domain.n_actions)
        q = self.q[state]
        best = q == q.max()
        if best.sum() == 1:
            return int(np.argmax(best))
        if advice is not None and self.ties == "advice":
            return sample_action(advice, rng.random(), mask=best)
        return uniform_choice(best, rng.random())

    def learn(self, state: int, action: int, next_state: int) -> float:
        """One Q-learning update; returns the reward of the move."""
        done = next_state == self.goal
        reward = GOAL_REWARD if done else 0.0
        target = reward if done else reward + self.gamma * self.q[next_state].max()
        self.q[state, action] += self.alpha * (target - self.q[state, action])
        return reward

    def greedy_action(self, state: int, rng: np.random.Generator) -> int:
        """The learned policy without exploration (uniform among ties)."""
        q = self.q[state]
        return uniform_choice(q == q.max(), rng.random())
