"""The Gymnasium wrapper reports every step and hands back the decision (real server)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from advisor_client import AdvisorClient
from advisor_client.gym import AdvisedEnv, MazeEnv

from tests.client.conftest import Server


def test_maze_env_follows_the_map() -> None:
    env = MazeEnv(["#####", "#S.G#", "#####"], max_steps=3)
    obs, info = env.reset(seed=0)
    assert obs.tolist() == [1, 1] and info["goal"] == (1, 3)
    obs, reward, terminated, truncated, _ = env.step(0)  # N: a wall, stays
    assert obs.tolist() == [1, 1] and (reward, terminated, truncated) == (0.0, False, False)
    env.step(1)
    obs, reward, terminated, truncated, _ = env.step(1)
    assert obs.tolist() == [1, 3] and reward == 1000.0 and terminated and not truncated


def test_advised_env_reports_steps_and_puts_decisions_in_info(server: Server) -> None:
    with AdvisorClient(server.url) as client:
        env = AdvisedEnv(MazeEnv(client.domain("default")["map"]), client, "default", window=30)
        obs, info = env.reset(seed=1)
        assert info["decision"]["step"] == 0 and info["decision"]["state"] == obs.tolist()
        session = env.session
        rng = np.random.default_rng(1)
        for t in range(1, 41):
            obs, _, _, _, info = env.step(int(rng.integers(4)))
            assert info["decision"]["step"] == t and info["decision"]["state"] == obs.tolist()
            assert info["followed_advice"] is False
        assert session is not None and client.session(session)["steps"] == 40
        env.close()
        assert env.session is None


def test_advised_env_can_follow_the_advice(server: Server) -> None:
    with AdvisorClient(server.url) as client:
        env = AdvisedEnv(
            MazeEnv(client.domain("default")["map"]), client, kappa=0.0, follow_advice=True
        )
        env.reset(seed=2)
        for _ in range(30):
            _, _, _, _, info = env.step(0)  # the agent says N; kappa 0 advises every step
            assert info["followed_advice"] is True and info["decision"]["advise"] is True
        env.close()


def test_advised_env_wraps_a_stock_gymnasium_environment(server: Server) -> None:
    """FrozenLake (slippery): observation s = row * 4 + col, actions 0 W, 1 S, 2 E, 3 N. The
    service learns from the action taken and decides for the cell actually reached."""
    lake = ["SFFF", "FFFF", "FFFF", "FFFG"]
    with AdvisorClient(server.url, admin_key=server.admin_key) as client:
        client.put_domain("lake", [row.replace("F", ".") for row in lake])
        base = gym.make("FrozenLake-v1", desc=lake, is_slippery=True)
        env = AdvisedEnv(
            base, client, "lake", cell_of=lambda s: divmod(int(s), 4), action_names="WSEN"
        )
        obs, info = env.reset(seed=3)
        rng = np.random.default_rng(3)
        steps = 0
        for _ in range(25):
            obs, _, terminated, truncated, info = env.step(int(rng.integers(4)))
            steps += 1
            assert info["decision"]["state"] == list(divmod(int(obs), 4))
            if terminated or truncated:
                break
        assert env.session is not None and client.session(env.session)["steps"] == steps
        env.close()
        client.delete_domain("lake")
