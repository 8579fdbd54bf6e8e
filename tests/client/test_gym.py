"""The Gymnasium wrapper reports every step and hands back the decision (real server); the
registered ids, alone and in their vector form."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from advisor_client import AdvisorClient, AdvisorError
from advisor_client.gym import MAZE_ID, MAZE_STEPS, AdvisedEnv, MazeEnv, register_envs

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


def test_the_maze_id_is_registered_with_a_step_limit() -> None:
    spec = gym.spec(MAZE_ID)
    assert spec.max_episode_steps == MAZE_STEPS == 5000
    assert spec.entry_point == "advisor_client.gym:make_maze"
    register_envs()  # again: nothing changes, nothing is overridden
    assert gym.spec(MAZE_ID) is spec
    assert gym.spec("HiddenGoalAdvisor/MiniGrid-v0").max_episode_steps is None  # MiniGrid's


def test_gym_make_gives_an_advised_maze_that_truncates_and_closes_its_client(
    server: Server,
) -> None:
    env = gym.make(MAZE_ID, url=server.url, max_episode_steps=7, window=20)
    assert env.spec is not None and env.spec.max_episode_steps == 7
    obs, info = env.reset(seed=0)
    session = env.get_wrapper_attr("session")
    client = env.get_wrapper_attr("client")
    with AdvisorClient(server.url) as reader:
        assert info["decision"]["state"] == obs.tolist() == reader.domain("default")["start"]
        truncated = False
        for t in range(1, 8):
            obs, _, terminated, truncated, info = env.step(1)
            assert info["decision"]["step"] == t and not terminated
            assert "advice" not in info["decision"] or info["decision"]["advise"]
        assert truncated  # the registration's TimeLimit, not MazeEnv's own limit
        assert reader.session(session)["steps"] == 7
        env.close()
        with pytest.raises(AdvisorError) as err:
            reader.session(session)
        assert err.value.status == 404  # the session ended with the environment
    assert client.http.is_closed  # its own client, closed with it


def test_the_vector_form_gives_each_copy_a_session_and_resets_them_itself(
    server: Server,
) -> None:
    """``gym.make_vec`` (sync): each copy its own session and client; infos stacked; a copy
    truncated is reset at the next step (its session ended, a new one at step 0); closing
    ends every session."""
    with AdvisorClient(server.url) as reader:
        envs = gym.make_vec(
            MAZE_ID, num_envs=3, vectorization_mode="sync", url=server.url,
            max_episode_steps=5, kappa=0.0,
        )  # fmt: skip
        assert isinstance(envs, gym.vector.SyncVectorEnv)
        obs, infos = envs.reset(seed=1)
        first = envs.get_attr("session")
        assert obs.shape == (3, 2) and len({s.session_id for s in first}) == 3
        assert list(infos["session_id"]) == [s.session_id for s in first]
        rng = np.random.default_rng(1)
        for t in range(1, 6):
            obs, _, terminated, truncated, infos = envs.step(rng.integers(4, size=3))
            decision = infos["decision"]
            assert decision["step"].tolist() == [t] * 3
            assert [list(s) for s in decision["state"]] == obs.tolist()
            assert decision["advise"].all() and decision["_advice"].all()  # kappa 0
            assert decision["advice"]["N"].shape == (3,)
        assert truncated.all() and not terminated.any()
        assert [reader.session(s)["steps"] for s in first] == [5, 5, 5]
        obs, _, _, _, infos = envs.step(np.zeros(3, dtype=np.int64))  # the reset step
        assert infos["decision"]["step"].tolist() == [0] * 3
        second = envs.get_attr("session")
        for old in first:  # ended by the reset
            with pytest.raises(AdvisorError, match="404"):
                reader.session(old)
        assert [reader.session(s)["steps"] for s in second] == [0, 0, 0]
        envs.close()
        for new in second:
            with pytest.raises(AdvisorError, match="404"):
                reader.session(new)


def test_advice_is_left_out_of_info_where_the_service_gave_none(server: Server) -> None:
    with AdvisorClient(server.url) as client:
        env = AdvisedEnv(MazeEnv(client.domain("default")["map"]), client, kappa=1e6)
        _, info = env.reset(seed=0)
        _, _, _, _, info = env.step(1)
        assert info["decision"]["advise"] is False and "advice" not in info["decision"]
        assert env.decision is not None and env.decision["advice"] is None  # all of it here
        env.close()
