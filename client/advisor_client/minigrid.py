"""MiniGrid (Farama's gridworlds) advised by the service: ``pip install './client[minigrid]'``.

* :func:`grid_map`: the layout of a reset MiniGrid environment as an ASCII map, cell ``[row,
  col]`` = MiniGrid's ``(x, y) = (col, row)``: walls, lava, locked doors and objects that block
  are ``#``; floor and doors that open are ``.``; goals ``G``; the agent ``S``; cells the agent
  cannot reach are walled off.
* :class:`CompassActions`: MiniGrid acts by turning and moving forward; this wrapper acts by
  compass, ``Discrete(4)`` = N, E, S, W (the service's actions): the agent faces that way and
  moves one cell (opening a closed door in its way first, which costs MiniGrid a step too).
  Its observations are MiniGrid's plus ``"cell"``, the agent's ``[row, col]``
  (:func:`agent_cell`), which is what :class:`~advisor_client.gym.AdvisedEnv` reads.
* :class:`AdvisedMiniGrid`: :class:`~advisor_client.gym.AdvisedEnv` over
  :class:`CompassActions`, with one domain per layout: at each ``reset(seed=s)`` the layout's
  domain (``<env id>-s<s>``; without a seed, named by the map's hash) is PUT once, with
  simulated experts (the PUT's ``experts``) walking shortest paths to its goals, so advice
  works at once. PUT needs the admin key. Closing it deletes the domains its PUTs created
  (not those that were there before).
* :func:`make_minigrid`: the entry point of ``HiddenGoalAdvisor/MiniGrid-v0``
  (``gym.make("HiddenGoalAdvisor/MiniGrid-v0", env_id="MiniGrid-FourRooms-v0", url=...,
  admin_key=...)``, and ``gym.make_vec`` for several at once).

>>> env = AdvisedMiniGrid(gym.make("MiniGrid-FourRooms-v0"), client, follow_advice=True)
>>> obs, info = env.reset(seed=1)
>>> obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
"""

from __future__ import annotations

import hashlib
import re
from collections import deque
from collections.abc import Mapping
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from minigrid.core.actions import Actions
from minigrid.core.world_object import Door, Goal, Lava

from advisor_client.api import AdvisorError
from advisor_client.client import DEFAULT_URL, AdvisorClient
from advisor_client.gym import AdvisedEnv

COMPASS = ("N", "E", "S", "W")
#: MiniGrid's ``agent_dir`` for each compass action: 0 faces +x (east), 1 +y (south), ...
FACING = (3, 0, 1, 2)
MOVES = ((-1, 0), (0, 1), (1, 0), (0, -1))
#: simulated experts of a new layout's domain (the PUT's ``experts``)
EXPERTS: Mapping[str, Any] = {"source": "anywhere", "per_goal": 100, "seed": 0}


def _minigrid(env: gym.Env[Any, Any]) -> Any:
    inner = env.unwrapped
    if not hasattr(inner, "grid") or not hasattr(inner, "agent_pos"):
        raise TypeError(f"{inner!r} is not a MiniGrid environment (it has no grid, agent_pos)")
    return inner


def agent_cell(env: gym.Env[Any, Any]) -> tuple[int, int]:
    """The agent's ``(row, col)``: MiniGrid's ``(x, y)`` is ``(col, row)``."""
    x, y = _minigrid(env).agent_pos
    return int(y), int(x)


def grid_map(env: gym.Env[Any, Any]) -> list[str]:
    """The current layout as an ASCII map (call after ``reset``)."""
    inner = _minigrid(env)
    rows, cols = inner.height, inner.width
    cells = [["#"] * cols for _ in range(rows)]
    for y in range(rows):
        for x in range(cols):
            obj = inner.grid.get(x, y)
            if obj is None or (isinstance(obj, Door) and not obj.is_locked):
                cells[y][x] = "."
            elif isinstance(obj, Goal):
                cells[y][x] = "G"
            elif obj.can_overlap() and not isinstance(obj, Lava):
                cells[y][x] = "."
    start = agent_cell(env)
    reach = {start}
    todo = deque([start])
    while todo:  # walled off: what the agent cannot reach
        r, c = todo.popleft()
        for dr, dc in MOVES:
            nxt = (r + dr, c + dc)
            inside = 0 <= nxt[0] < rows and 0 <= nxt[1] < cols
            if inside and cells[nxt[0]][nxt[1]] != "#" and nxt not in reach:
                reach.add(nxt)
                todo.append(nxt)
    for r in range(rows):
        for c in range(cols):
            if (r, c) not in reach:
                cells[r][c] = "#"
    cells[start[0]][start[1]] = "S"
    return ["".join(row) for row in cells]


class CompassActions(
    gym.Wrapper[dict[str, Any], int, dict[str, Any], int], gym.utils.RecordConstructorArgs
):
    """MiniGrid acting by compass: ``Discrete(4)``, 0 N, 1 E, 2 S, 3 W; observations are
    MiniGrid's with ``"cell"``, the agent's ``[row, col]``. Reward, termination and truncation
    are MiniGrid's (a door opened on the way adds its step)."""

    def __init__(self, env: gym.Env[Any, Any]):
        gym.utils.RecordConstructorArgs.__init__(self)
        gym.Wrapper.__init__(self, env)
        inner = _minigrid(env)
        base = env.observation_space
        assert isinstance(base, spaces.Dict), "MiniGrid observations are dicts"
        cell = spaces.MultiDiscrete([inner.height, inner.width])
        self.observation_space = spaces.Dict({**base.spaces, "cell": cell})
        self.action_space: spaces.Space[int] = spaces.Discrete(4)  # type: ignore[assignment]

    def _with_cell(self, obs: dict[str, Any]) -> dict[str, Any]:
        return {**obs, "cell": np.array(agent_cell(self.env), dtype=np.int64)}

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, Any], dict[str, Any]]:
        obs, info = self.env.reset(seed=seed, options=options)
        return self._with_cell(obs), info

    def step(self, action: int) -> tuple[dict[str, Any], SupportsFloat, bool, bool, dict[str, Any]]:
        inner = _minigrid(self.env)
        inner.agent_dir = FACING[int(action)]
        ahead = inner.grid.get(*inner.front_pos)
        reward = 0.0
        if isinstance(ahead, Door) and not ahead.is_open:
            obs, r, terminated, truncated, info = self.env.step(Actions.toggle)
            reward += float(r)
            if terminated or truncated:
                return self._with_cell(obs), reward, terminated, truncated, info
        obs, r, terminated, truncated, info = self.env.step(Actions.forward)
        return self._with_cell(obs), reward + float(r), terminated, truncated, info


def env_name(env: gym.Env[Any, Any]) -> str:
    """The id ``env`` was made with (``gym.make``), else its class's name."""
    return env.spec.id if env.spec is not None else type(_minigrid(env)).__name__


def layout_name(
    env: gym.Env[Any, Any], seed: int | None, rows: list[str], env_id: str | None = None
) -> str:
    """A domain name for this layout: ``<env id>-s<seed>`` (lower case), else the map's hash.
    ``env_id``: the environment's id if not :func:`env_name`'s."""
    spec = env_id or env_name(env)
    base = re.sub(r"[^a-z0-9_.-]+", "-", spec.lower()).strip("-")[:40]
    if seed is not None:
        return f"{base}-s{seed}"
    digest = hashlib.sha1("\n".join(rows).encode()).hexdigest()
    return f"{base}-{digest[:12]}"


class AdvisedMiniGrid(AdvisedEnv):
    """A MiniGrid environment reporting to the service, one domain per layout.

    ``env``: a MiniGrid environment (``gym.make("MiniGrid-FourRooms-v0")``), wrapped here in
    :class:`CompassActions`; ``experts``: the simulated experts of each new layout's domain
    (:data:`EXPERTS`); the other options are :class:`~advisor_client.gym.AdvisedEnv`'s
    (``follow_advice=True``: an advised step takes an action sampled from the advice).

    ``created``: the domains its PUTs created (201), which :meth:`close` deletes; a layout's
    domain that was there already (another environment's, or one kept from before) is left.
    Environments that share layouts (copies of a vector environment) should close together,
    as a vector environment's do: a deleted domain ends the sessions of the others.
    """

    def __init__(
        self,
        env: gym.Env[Any, Any],
        client: AdvisorClient,
        *,
        experts: Mapping[str, Any] = EXPERTS,
        **options: Any,
    ):
        gym.utils.RecordConstructorArgs.__init__(
            self, _disable_deepcopy=True, client=client, experts=experts, **options
        )
        self.env_id = env_name(env)  # now: gym.make of a registered id sets it anew
        compass = env if isinstance(env, CompassActions) else CompassActions(env)
        super().__init__(compass, client, "", action_names=COMPASS, **options)
        self.experts = dict(experts)
        self.known: set[str] = set()
        self.created: list[str] = []

    def domain_for(self, obs: Any, info: dict[str, Any], seed: int | None) -> str:
        rows = grid_map(self.env)
        name = layout_name(self.env, seed, rows, self.env_id)
        if name not in self.known:
            _, created = self.client.put_domain_created(name, rows, experts=self.experts)
            self.known.add(name)
            if created:
                self.created.append(name)
        return name

    def close(self) -> None:
        """End the session, delete the domains this environment created, close."""
        try:
            self._end_session()
            while self.created:
                name = self.created.pop()
                self.known.discard(name)
                try:
                    self.client.delete_domain(name)
                except AdvisorError as exc:
                    if exc.status != 404:  # deleted already: nothing to do
                        raise
        finally:
            super().close()


def make_minigrid(
    env_id: str = "MiniGrid-FourRooms-v0",
    client: AdvisorClient | None = None,
    *,
    url: str = DEFAULT_URL,
    admin_key: str | None = None,
    env_kwargs: Mapping[str, Any] | None = None,
    **options: Any,
) -> AdvisedMiniGrid:
    """The entry point of ``HiddenGoalAdvisor/MiniGrid-v0``: ``gym.make(env_id,
    **env_kwargs)`` in an :class:`AdvisedMiniGrid` (``options``: its keywords), through
    ``client`` or a client of its own for ``url`` with ``admin_key`` (needed: it PUTs the
    layouts' domains; closed with the environment)."""
    owned = client is None
    client = client or AdvisorClient(url, admin_key=admin_key)
    env = gym.make(env_id, **dict(env_kwargs or {}))
    return AdvisedMiniGrid(env, client, close_client=owned, **options)
