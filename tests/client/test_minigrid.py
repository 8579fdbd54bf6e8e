"""MiniGrid (the real package) as domains of the service: maps, compass actions, advice."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from advisor_client import AdvisorClient
from advisor_client.minigrid import (
    AdvisedMiniGrid,
    CompassActions,
    agent_cell,
    grid_map,
    layout_name,
)
from gymnasium.utils.env_checker import check_env

from app.domain.grid import GridDomain
from tests.client.conftest import Server

pytestmark = pytest.mark.filterwarnings("ignore:.*is different from the unwrapped")

ENVS = ["MiniGrid-FourRooms-v0", "MiniGrid-MultiRoom-N4-S5-v1", "MiniGrid-LavaGapS6-v0"]


@pytest.mark.parametrize("env_id", ENVS)
@pytest.mark.parametrize("seed", [0, 7])
def test_grid_map_is_a_valid_domain_of_the_layout(env_id: str, seed: int) -> None:
    env = gym.make(env_id)
    env.reset(seed=seed)
    rows = grid_map(env)
    domain = GridDomain.from_strings(rows)  # every free cell reachable from S, or it refuses
    inner = env.unwrapped
    assert domain.shape == (inner.height, inner.width)  # type: ignore[attr-defined]
    assert domain.cell(domain.start) == agent_cell(env)
    for r, row in enumerate(rows):
        for c, ch in enumerate(row):
            obj = inner.grid.get(c, r)  # type: ignore[attr-defined]
            kind = obj.type if obj is not None else None
            if kind in ("wall", "lava"):
                assert ch == "#", (r, c, kind)
            elif kind == "goal":
                assert ch == "G"
            elif kind == "door":
                assert ch == ".", "unlocked doors open: they are passable"
    assert len(domain.goals) == 1


def test_compass_actions_move_the_agent_and_open_doors() -> None:
    env = CompassActions(gym.make("MiniGrid-MultiRoom-N4-S5-v1"))
    obs, _ = env.reset(seed=1)
    rows = grid_map(env)
    grid = GridDomain.from_strings(rows)
    rng = np.random.default_rng(0)
    cell = tuple(obs["cell"].tolist())
    doors = 0
    for _ in range(300):
        a = int(rng.integers(4))
        inner = env.unwrapped
        x, y = cell[1], cell[0]
        dx, dy = ((0, -1), (1, 0), (0, 1), (-1, 0))[a]
        ahead = inner.grid.get(x + dx, y + dy)  # type: ignore[attr-defined]
        closed = ahead is not None and ahead.type == "door" and not ahead.is_open
        obs, _, terminated, truncated, _ = env.step(a)
        doors += closed
        want = grid.cell(grid.step(grid.state(*cell), a))  # the map's transitions
        assert tuple(obs["cell"].tolist()) == want == agent_cell(env)
        cell = want
        if terminated or truncated:
            obs, _ = env.reset(seed=1)
            cell = tuple(obs["cell"].tolist())
    assert doors > 0  # walked through a closed door at least once


@pytest.mark.parametrize("env_id", ENVS)
def test_compass_actions_pass_gymnasiums_env_checker(env_id: str) -> None:
    check_env(CompassActions(gym.make(env_id)), skip_render_check=True)


def test_layouts_are_named_by_seed_or_by_their_map() -> None:
    env = gym.make("MiniGrid-FourRooms-v0")
    env.reset(seed=4)
    rows = grid_map(env)
    assert layout_name(env, 4, rows) == "minigrid-fourrooms-v0-s4"
    assert layout_name(env, None, rows) == layout_name(env, None, list(rows))
    assert layout_name(env, None, rows) != layout_name(env, None, rows[::-1])


def test_advised_minigrid_makes_a_domain_per_layout_and_advises(server: Server) -> None:
    with AdvisorClient(server.url, admin_key=server.admin_key) as client:
        env = AdvisedMiniGrid(
            gym.make("MiniGrid-FourRooms-v0"), client, kappa=0.0, follow_advice=True
        )
        obs, info = env.reset(seed=3)
        made = client.domain("minigrid-fourrooms-v0-s3")
        assert made["trajectories"] > 0 and made["map"] == grid_map(env)
        assert info["decision"]["state"] == obs["cell"].tolist()
        for _ in range(5):
            obs, _, terminated, truncated, info = env.step(0)
            assert info["followed_advice"] and info["decision"]["state"] == obs["cell"].tolist()
            if terminated or truncated:
                break
        env.reset(seed=3)  # the same layout: the same domain, not put again
        assert env.domain == "minigrid-fourrooms-v0-s3" and env.known == {env.domain}
        check_env(env, skip_render_check=True)  # through the service, sessions and all
        env.close()
        client.delete_domain("minigrid-fourrooms-v0-s3")
