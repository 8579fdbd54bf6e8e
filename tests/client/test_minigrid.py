"""MiniGrid (the real package) as domains of the service: maps, compass actions, advice."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from advisor_client import AdvisorClient, AdvisorError
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
        layouts = list(env.created)  # s3, and the layouts check_env reset without a seed
        assert layouts[0] == "minigrid-fourrooms-v0-s3" and len(layouts) > 1
        env.close()
        for name in layouts:  # it made them: it deleted them
            with pytest.raises(AdvisorError) as err:
                client.domain(name)
            assert err.value.status == 404


def test_closing_deletes_the_domains_it_created_and_only_those(server: Server) -> None:
    """Layouts 5 and 6 are new: their domains go when the environment closes; layout 7's
    domain was there before it (PUT by someone else): it stays."""
    with AdvisorClient(server.url, admin_key=server.admin_key) as client:
        seven = gym.make("MiniGrid-FourRooms-v0")
        seven.reset(seed=7)
        client.put_domain("minigrid-fourrooms-v0-s7", grid_map(seven), experts={"per_goal": 5})
        env = AdvisedMiniGrid(gym.make("MiniGrid-FourRooms-v0"), client)
        for seed in (5, 6, 7, 5):
            env.reset(seed=seed)
            env.step(1)
        assert env.known == {f"minigrid-fourrooms-v0-s{s}" for s in (5, 6, 7)}
        assert env.created == ["minigrid-fourrooms-v0-s5", "minigrid-fourrooms-v0-s6"]
        client.delete_domain("minigrid-fourrooms-v0-s6")  # gone already: not an error
        env.close()
        names = {d["name"] for d in client.domains()}
        assert "minigrid-fourrooms-v0-s7" in names
        assert not names & {"minigrid-fourrooms-v0-s5", "minigrid-fourrooms-v0-s6"}
        assert env.created == [] and env.known == {"minigrid-fourrooms-v0-s7"}
        env.close()  # again: nothing more to do
        client.delete_domain("minigrid-fourrooms-v0-s7")


def test_the_minigrid_id_and_its_vector_form(server: Server) -> None:
    """``HiddenGoalAdvisor/MiniGrid-v0`` names its layouts after the MiniGrid id it wraps (not
    its own); two copies of a vector environment, their layouts' domains deleted at close."""
    env = gym.make(
        "HiddenGoalAdvisor/MiniGrid-v0", env_id="MiniGrid-MultiRoom-N4-S5-v1", url=server.url,
        admin_key=server.admin_key, kappa=0.0, follow_advice=True,
    )  # fmt: skip
    obs, info = env.reset(seed=2)
    assert env.get_wrapper_attr("domain") == "minigrid-multiroom-n4-s5-v1-s2"
    obs, _, _, _, info = env.step(0)
    assert info["followed_advice"] and info["decision"]["state"] == obs["cell"].tolist()
    env.close()
    envs = gym.make_vec(
        "HiddenGoalAdvisor/MiniGrid-v0", num_envs=2, vectorization_mode="sync",
        url=server.url, admin_key=server.admin_key,
    )  # fmt: skip
    assert isinstance(envs, gym.vector.SyncVectorEnv)
    obs, infos = envs.reset(seed=10)  # copies seeded 10 and 11
    assert envs.get_attr("domain") == ("minigrid-fourrooms-v0-s10", "minigrid-fourrooms-v0-s11")
    for _ in range(3):
        obs, _, _, _, infos = envs.step(envs.action_space.sample())
    assert obs["cell"].shape == (2, 2) and infos["decision"]["step"].tolist() == [3, 3]
    envs.close()
    with AdvisorClient(server.url) as client:
        assert not {d["name"] for d in client.domains()} & {
            "minigrid-multiroom-n4-s5-v1-s2", "minigrid-fourrooms-v0-s10",
            "minigrid-fourrooms-v0-s11",
        }  # fmt: skip
