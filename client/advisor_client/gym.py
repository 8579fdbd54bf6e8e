"""Gymnasium: report every step of an environment to the advice service.

:class:`AdvisedEnv` wraps any environment whose observations name a grid cell. At ``reset`` it
opens a session at the start cell; at each ``step`` it sends (cell, action, next cell) over the
session's websocket and puts the service's decision in ``info["decision"]``. With
``follow_advice=True`` an advised step replaces the agent's action with one sampled from the
advice (as the paper's advised explorers do), drawn from the environment's ``np_random``.

:class:`MazeEnv` is a small grid world built from a map the service serves
(``GET /domains/{name}``), so the wrapper can be used without any server code:

>>> env = AdvisedEnv(MazeEnv(client.domain("default")["map"]), client, "default")
>>> obs, info = env.reset(seed=0)
>>> obs, reward, terminated, truncated, info = env.step(1)   # info["decision"]["advise"]

Importing this module registers Gymnasium ids (:func:`register_envs`):
``HiddenGoalAdvisor/Maze-v0`` (:func:`make_maze`: a domain's map as a :class:`MazeEnv`,
advised; 5000 steps at most, ``max_episode_steps`` to change it) and
``HiddenGoalAdvisor/MiniGrid-v0`` (:func:`advisor_client.minigrid.make_minigrid`). Their vector
form is Gymnasium's (each copy an explorer of its own, with its own session):

>>> envs = gym.make_vec("HiddenGoalAdvisor/Maze-v0", num_envs=4, vectorization_mode="sync",
...                     url="http://127.0.0.1:8000")
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
import numpy.typing as npt
from gymnasium import spaces

from advisor_client.api import AdvisorError, Session
from advisor_client.client import DEFAULT_URL, AdvisorClient, Stream
from advisor_client.types import Decision

ACTIONS = ("N", "E", "S", "W")
MOVES = ((-1, 0), (0, 1), (1, 0), (0, -1))
GOAL_REWARD = 1000.0
Obs = npt.NDArray[np.int64]
#: the ids :func:`register_envs` registers, and the steps of an episode at most
MAZE_ID = "HiddenGoalAdvisor/Maze-v0"
MINIGRID_ID = "HiddenGoalAdvisor/MiniGrid-v0"
MAZE_STEPS = 5000


class MazeEnv(gym.Env[Obs, int]):
    """An ASCII maze ('#' wall, '.' free, 'S' start, 'G' goals) with a hidden goal.

    * Observation: ``[row, col]`` of the agent (``MultiDiscrete([rows, cols])``).
    * Actions: ``Discrete(4)``: 0 N, 1 E, 2 S, 3 W. A move into a wall or off the map stays.
    * Goal: one of the map's goals, drawn at ``reset`` (or ``options={"goal": [r, c]}``);
      reaching it gives reward 1000 and ends the episode; every other step gives 0.
    * Truncation after ``max_steps`` steps (``None``: never; ``gym.make`` of
      ``HiddenGoalAdvisor/Maze-v0`` truncates with its ``max_episode_steps`` instead).
    """

    metadata = {"render_modes": ["ansi"]}  # noqa: RUF012  (Gymnasium's own convention)

    def __init__(
        self,
        rows: Sequence[str],
        max_steps: int | None = MAZE_STEPS,
        render_mode: str | None = None,
    ):
        self.rows = [r.rstrip() for r in rows]
        self.shape = (len(self.rows), len(self.rows[0]))
        self.start = next(
            (r, c) for r, row in enumerate(self.rows) for c, ch in enumerate(row) if ch == "S"
        )
        self.goals = [
            (r, c) for r, row in enumerate(self.rows) for c, ch in enumerate(row) if ch == "G"
        ]
        self.max_steps = max_steps
        self.render_mode = render_mode
        self.observation_space = spaces.MultiDiscrete(list(self.shape))
        self.action_space: spaces.Space[int] = spaces.Discrete(4)  # type: ignore[assignment]
        self.cell, self.goal, self.steps = self.start, self.goals[0], 0

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Obs, dict[str, Any]]:
        super().reset(seed=seed)
        goal = (options or {}).get("goal")
        if goal is None:
            goal = self.goals[int(self.np_random.integers(len(self.goals)))]
        self.goal, self.cell, self.steps = (int(goal[0]), int(goal[1])), self.start, 0
        return np.array(self.cell), {"goal": self.goal}

    def step(self, action: int) -> tuple[Obs, SupportsFloat, bool, bool, dict[str, Any]]:
        dr, dc = MOVES[int(action)]
        r, c = self.cell[0] + dr, self.cell[1] + dc
        if 0 <= r < self.shape[0] and 0 <= c < self.shape[1] and self.rows[r][c] != "#":
            self.cell = (r, c)
        self.steps += 1
        done = self.cell == self.goal
        return (
            np.array(self.cell), GOAL_REWARD if done else 0.0, done,
            self.max_steps is not None and self.steps >= self.max_steps and not done,
            {"goal": self.goal},
        )  # fmt: skip

    def render(self) -> str:
        grid = [list(r) for r in self.rows]
        grid[self.cell[0]][self.cell[1]] = "@"
        return "\n".join("".join(r) for r in grid)


class NoCell(TypeError):
    """An observation from which :class:`AdvisedEnv` cannot read the explorer's cell."""


def _describe(obs: Any) -> str:
    if isinstance(obs, Mapping):
        return f"a dict with keys {sorted(map(str, obs))}"
    shape = getattr(obs, "shape", None)
    if shape is not None:
        return f"an array of shape {tuple(shape)}"
    text = repr(obs)
    return f"{type(obs).__name__} {text[:60]}{'...' if len(text) > 60 else ''}"


def cell_of_observation(obs: Any) -> tuple[int, int]:
    """The default ``cell_of``: an observation's ``"cell"`` entry if it is a dict that has
    one, else its first two entries, as ``(row, col)``."""
    value = obs["cell"] if isinstance(obs, Mapping) and "cell" in obs else obs
    try:
        return int(value[0]), int(value[1])
    except (KeyError, IndexError, TypeError, ValueError):
        raise NoCell(
            f"AdvisedEnv needs the explorer's cell (row, col) from each observation, and this "
            f"observation ({_describe(obs)}) names none: pass cell_of=<a function from an "
            "observation to (row, col)>, e.g. cell_of=lambda s: divmod(int(s), 4) for a 4x4 "
            "FrozenLake; for MiniGrid, wrap the environment in "
            "advisor_client.minigrid.CompassActions, whose observations carry a 'cell'"
        ) from None


def _given(decision: Decision) -> dict[str, Any]:
    """A decision without its null entries: Gymnasium's vector environments stack each entry
    of their copies' infos into an array, which a null in one copy and a dict in another
    breaks; an entry missing is masked (``info["decision"]["_advice"]``)."""
    return {k: v for k, v in decision.items() if v is not None}


class AdvisedEnv(gym.Wrapper[Any, Any, Any, Any], gym.utils.RecordConstructorArgs):
    """Reports each step to the advice service; the decision goes in ``info["decision"]``
    (without the entries the service gives as null: ``advice`` when it does not advise, so
    that a vector environment's infos stack; :attr:`decision` has them all).

    ``cell_of`` maps an observation to ``(row, col)`` (default: :func:`cell_of_observation`,
    a dict's ``"cell"`` or the first two entries; :class:`NoCell` says what to pass otherwise);
    ``action_names`` names the wrapped environment's actions as compass moves (e.g.
    FrozenLake's ``("W", "S", "E", "N")``). ``info["followed_advice"]`` says whether the step
    took an action sampled from the advice instead of the agent's. ``close_client``: closing
    the environment closes ``client`` too (the registered ids' own clients).
    """

    def __init__(
        self,
        env: gym.Env[Any, Any],
        client: AdvisorClient,
        domain: str = "default",
        *,
        kappa: float | None = None,
        window: int | None = None,
        agent_type: str | None = None,
        follow_advice: bool = False,
        cell_of: Callable[[Any], tuple[int, int]] = cell_of_observation,
        action_names: Sequence[str] = ACTIONS,
        close_client: bool = False,
    ):
        gym.utils.RecordConstructorArgs.__init__(
            self, _disable_deepcopy=True, client=client, domain=domain, kappa=kappa,
            window=window, agent_type=agent_type, follow_advice=follow_advice, cell_of=cell_of,
            action_names=action_names, close_client=close_client,
        )  # fmt: skip
        gym.Wrapper.__init__(self, env)
        self.client = client
        self.close_client = close_client
        self.domain = domain
        self.options = {"kappa": kappa, "window": window, "agent_type": agent_type}
        self.follow_advice = follow_advice
        self.cell_of = cell_of
        self.action_names = tuple(action_names)
        self.session: Session | None = None
        self.stream: Stream | None = None
        self.decision: Decision | None = None
        self.cell = (0, 0)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(seed=seed, options=options)
        self._end_session()
        self.cell = self.cell_of(obs)
        self.domain = self.domain_for(obs, info, seed)
        self.session = self.client.create_session(self.domain, start=self.cell, **self.options)  # type: ignore[arg-type]
        self.stream = self.client.stream(self.session)
        self.decision = self.session.decision
        return obs, {
            **info,
            "decision": _given(self.decision),
            "session_id": self.session.session_id,
        }

    def domain_for(self, obs: Any, info: dict[str, Any], seed: int | None) -> str:
        """The domain of the episode that ``reset`` began (here: always the one given;
        :class:`~advisor_client.minigrid.AdvisedMiniGrid` makes one per layout)."""
        return self.domain

    def advised_action(self) -> int | None:
        """An action sampled from the current advice, if the last decision advised."""
        if self.decision is None or not self.decision["advise"] or not self.decision["advice"]:
            return None
        advice = self.decision["advice"]
        weights = np.array([advice[name] for name in self.action_names])  # type: ignore[literal-required]
        return int(self.np_random.choice(len(weights), p=weights / weights.sum()))

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        if self.stream is None:
            raise gym.error.ResetNeeded("call reset() before step()")
        advised = self.advised_action() if self.follow_advice else None
        if advised is not None:
            action = advised
        obs, reward, terminated, truncated, info = self.env.step(action)
        cell = self.cell_of(obs)
        event = {"state": self.cell, "action": self.action_names[int(action)], "next_state": cell}
        self.decision = self.stream.send(event)
        self.cell = cell
        info = {**info, "decision": _given(self.decision), "followed_advice": advised is not None}
        return obs, reward, terminated, truncated, info

    def _end_session(self) -> None:
        if self.stream is not None:
            self.stream.close()
        if self.session is not None:
            try:
                self.client.end_session(self.session)
            except AdvisorError as exc:
                if exc.status != 404:  # already ended or expired: nothing to do
                    raise
        self.session = self.stream = None

    def close(self) -> None:
        try:
            self._end_session()
        finally:
            if self.close_client:
                self.client.close()
            super().close()


def make_maze(
    domain: str = "default",
    client: AdvisorClient | None = None,
    *,
    url: str = DEFAULT_URL,
    admin_key: str | None = None,
    **options: Any,
) -> AdvisedEnv:
    """The entry point of ``HiddenGoalAdvisor/Maze-v0``: ``domain``'s map (read from the
    service) as a :class:`MazeEnv` without a step limit of its own, in an :class:`AdvisedEnv`
    (``options``: its keywords, e.g. ``kappa``, ``follow_advice``). Through ``client``, or a
    client of its own for ``url`` (closed with the environment: give ``url`` to vector forms
    whose copies run in other processes)."""
    owned = client is None
    client = client or AdvisorClient(url, admin_key=admin_key)
    try:
        rows = client.domain(domain)["map"]
    except BaseException:
        if owned:
            client.close()
        raise
    return AdvisedEnv(MazeEnv(rows, max_steps=None), client, domain, close_client=owned, **options)


def register_envs() -> None:
    """Register ``HiddenGoalAdvisor/Maze-v0`` (:func:`make_maze`, ``max_episode_steps``
    :data:`MAZE_STEPS`) and ``HiddenGoalAdvisor/MiniGrid-v0``
    (:func:`advisor_client.minigrid.make_minigrid`; MiniGrid truncates its episodes itself)
    with Gymnasium. Importing this module does it; doing it again changes nothing."""
    ids = (
        (MAZE_ID, "advisor_client.gym:make_maze", MAZE_STEPS),
        (MINIGRID_ID, "advisor_client.minigrid:make_minigrid", None),
    )
    for env_id, entry_point, steps in ids:
        if env_id not in gym.registry:
            gym.register(env_id, entry_point=entry_point, max_episode_steps=steps)


register_envs()
