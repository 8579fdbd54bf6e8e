"""``python -m app serve`` and ``python -m app simulate`` as a user runs them."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from advisor_client import AdvisorClient

from tests.client.conftest import REPO, Server, start_server, stop_server

TINY = ["#######", "#G..#G#", "#.#.#.#", "#...#.#", "###...#", "#S....#", "#######"]


def simulate(*args: str) -> subprocess.CompletedProcess[str]:
    cmd = [sys.executable, "-m", "app", "simulate", *args]
    return subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=120)


def test_simulate_drives_explorers_and_prints_outcomes(server: Server) -> None:
    with AdvisorClient(server.url) as client:
        before = client.overview()["total_sessions"]
    options = ["--explorer", "random-avoid", "--advice", "--episodes", "3"]
    run = simulate("--server", server.url, *options, "--explorers", "2", "--steps", "60")
    assert run.returncode == 0, run.stderr
    lines = run.stdout.strip().splitlines()
    episodes = [line for line in lines if line.startswith("episode ")]
    assert [line.split()[1] for line in episodes] == ["0", "1", "2"]  # in order
    assert all(", P(M1|H) 0." in line or ", P(M1|H) 1.000" in line for line in episodes)
    assert lines[-1].startswith("random-avoid, advice on (paper), kappa 0.5: ")
    assert "reached their goal" in lines[-1] and "advice per 100 decisions" in lines[-1]
    with AdvisorClient(server.url) as client:  # each episode's session was ended
        assert client.overview()["total_sessions"] == before


def test_simulate_optimal_explorers_reach_their_goals(server: Server) -> None:
    run = simulate("--server", server.url, "--explorer", "optimal", "--no-advice",
                   "--episodes", "2", "--steps", "500")  # fmt: skip
    assert run.returncode == 0, run.stderr
    assert "2/2 reached their goal (mean reward 1000)" in run.stdout


def test_simulate_walks_a_building_of_floors(server: Server, tmp_path: Path) -> None:
    """Optimal explorers on a building of two floors: every goal reached, those upstairs by
    the stairs or a lift (cells [floor, row, col], U and D sent to the service)."""
    from tests.service.test_strategies import TOWER

    path = tmp_path / "tower.txt"
    path.write_text(TOWER.to_text())
    with AdvisorClient(server.url, admin_key=server.admin_key) as client:
        client.put_domain_file("tower-sim", path, experts={"per_goal": 1})
    run = simulate("--server", server.url, "--domain", "tower-sim", "--explorer", "optimal",
                   "--strategy", "guide", "--episodes", "6", "--steps", "400")  # fmt: skip
    assert run.returncode == 0, run.stderr
    assert "6/6 reached their goal (mean reward 1000)" in run.stdout
    upstairs = [line for line in run.stdout.splitlines() if ": goal [1, " in line]
    assert upstairs, run.stdout  # a goal on the first floor was among them
    with AdvisorClient(server.url, admin_key=server.admin_key) as client:
        client.delete_domain("tower-sim")


def test_simulate_takes_an_advising_strategy(server: Server) -> None:
    run = simulate("--server", server.url, "--strategy", "goal_aware", "--episodes", "1",
                   "--steps", "40")  # fmt: skip
    assert run.returncode == 0, run.stderr
    assert "random, advice on (goal_aware), kappa 0.5: " in run.stdout


def test_simulate_explains_bad_options_and_unreachable_servers() -> None:
    run = simulate("--explorer", "teleporter")
    assert run.returncode == 2 and "'teleporter' is not one of 'random'" in run.stderr
    run = simulate("--strategy", "oracle")
    assert run.returncode == 2 and "'oracle' is not one of 'paper'" in run.stderr
    run = simulate("--server", "http://127.0.0.1:9", "--episodes", "1")
    assert run.returncode == 2 and "cannot reach the advisor at http://127.0.0.1:9" in run.stderr


def test_serve_says_where_a_generated_key_is_kept_and_never_logs_it(tmp_path: Path) -> None:
    first = start_server(tmp_path / "data")
    _, err = stop_server(first)
    operator_key = (tmp_path / "data" / "operator_key").read_text().strip()
    assert first.admin_key not in err and operator_key not in err
    for name in ("admin_key", "operator_key"):
        path = tmp_path / "data" / name
        assert f"kept in {path} (mode 0600" in err and f"cat {path}" in err
        assert path.stat().st_mode & 0o777 == 0o600
    assert "Created domain 'default'" in err
    second = start_server(tmp_path / "data")
    _, err = stop_server(second)
    assert second.admin_key == first.admin_key
    assert first.admin_key not in err and "Created domain" not in err


def advisor(*args: str, **env: str) -> subprocess.CompletedProcess[str]:
    cmd = [sys.executable, "-m", "app", *args]
    environ = {k: v for k, v in os.environ.items() if not k.startswith("ADVISOR_")} | env
    return subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=120, env=environ)


def test_domain_put_sends_a_map_file_to_the_service_serve_settings_name(
    server: Server, tmp_path: Path
) -> None:
    """`domain put NAME FILE` finds the service and its admin key as serve's settings say
    (ADVISOR_PORT, ADVISOR_DATA_DIR's admin_key), sends the file as it is, and says what the
    service made; a bad map is refused in maze check's words."""
    port = server.url.rsplit(":", 1)[1]
    env = {"ADVISOR_PORT": port, "ADVISOR_DATA_DIR": str(server.data_dir)}
    imported = tmp_path / "office.txt"  # as `maze import office.yaml` writes a ROS map
    imported.write_text("resolution: 0.25\norigin: 1.0 2.0 0.0\n" + "\n".join(TINY) + "\n")
    run = advisor("domain", "put", "office", str(imported), "--experts", "start", **env)
    assert run.returncode == 0, run.stderr
    assert run.stdout.startswith(f"created domain 'office' at {server.url}: 7x7, ")
    assert "cells of 0.25 m; prior from 20 expert trajectories" in run.stdout
    again = advisor("domain", "put", "office", str(imported), **env)
    assert again.returncode == 0 and again.stdout.startswith("replaced domain 'office'")
    bad = tmp_path / "bad.txt"
    bad.write_text(imported.read_text().replace("#S....#", "#S..x.#"))
    check = advisor("maze", "check", str(bad))
    refused = advisor("domain", "put", "office", str(bad), **env)
    assert refused.returncode == 2 == check.returncode
    assert refused.stderr == check.stderr  # error: PATH: line 8, column 5: unknown character ...
    assert "line 8, column 5" in refused.stderr
    # without a key: what to set
    nokey = advisor("domain", "put", "office", str(imported), "--url", server.url,
                    ADVISOR_DATA_DIR=str(tmp_path / "nowhere"))  # fmt: skip
    assert nokey.returncode == 2 and "no admin key: set ADVISOR_ADMIN_KEY" in nokey.stderr
    with AdvisorClient(server.url, admin_key=server.admin_key) as client:
        client.delete_domain("office")
