"""Every experiment runs in seconds with a tiny budget, writes its files, and is reproducible."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from typer.testing import CliRunner

from app.cli import cli
from app.domain.grid import GridDomain
from app.experiments import difficulty, figure5, figure6, figure7, table1
from app.experiments.common import moving_average, prepare, rng_for, wilson
from app.experiments.output import RunDir
from app.experiments.traps import dead_end_masks, trap_goal

TINY = {"tasks": 3, "steps": 300, "episodes": 6, "episode_steps": 40, "progress": False}


def test_table1_writes_its_files_and_rows(small_maze: Path, tmp_path: Path) -> None:
    out = RunDir(tmp_path)
    result = table1.run(table1.Args(maze=small_maze, **TINY), out)  # type: ignore[arg-type]
    names = {p.name for p in tmp_path.iterdir()}
    assert {
        "table1.json",
        "table1.csv",
        "table1.md",
        "table1_tasks.csv",
        "table1_failures.png",
    } <= names
    rows = {(r["explorer"], r["advised"]): r for r in result["rows"]}
    assert len(rows) == 12
    for r in rows.values():
        assert r["reward"] == 1000.0 * r["successes"] / r["tasks"]
        assert r["reward_ci_low"] <= r["reward"] <= r["reward_ci_high"]
    assert rows["optimal", False]["successes"] == 3  # 300 steps is plenty on 11x11
    assert "paper" in (tmp_path / "table1.md").read_text()
    saved = json.loads((tmp_path / "table1.json").read_text())
    assert saved["rows"][0]["explorer"] == "random"


def test_seeded_runs_are_reproducible(small_maze: Path, tmp_path: Path) -> None:
    args = table1.Args(maze=small_maze, seed=7, **TINY)  # type: ignore[arg-type]
    first = table1.run(args, RunDir(tmp_path / "a"))
    again = table1.run(args, RunDir(tmp_path / "b"))
    other = table1.run(table1.Args(maze=small_maze, seed=8, **TINY), RunDir(tmp_path / "c"))  # type: ignore[arg-type]
    assert first["rows"] == again["rows"]
    assert first["rows"] != other["rows"]
    csv_a = (tmp_path / "a" / "table1_tasks.csv").read_text()
    assert csv_a == (tmp_path / "b" / "table1_tasks.csv").read_text()


def test_figure5_writes_curves_and_png(small_maze: Path, tmp_path: Path) -> None:
    args = figure5.Args(maze=small_maze, tasks=3, steps=200, progress=False)
    result = figure5.run(args, RunDir(tmp_path))
    assert (tmp_path / "figure5.png").stat().st_size > 10_000
    lines = (tmp_path / "figure5.csv").read_text().splitlines()
    assert len(lines) == 1 + 5 * 2 * 200
    assert set(result["summary"]) == {
        f"{n}{s}"
        for n in ("random", "random-avoid", "left", "bug", "optimal")
        for s in ("", "+advice")
    }


def test_figure6_and_table1_share_the_learning_runs(small_maze: Path, tmp_path: Path) -> None:
    fargs = figure6.Args(maze=small_maze, **{k: v for k, v in TINY.items() if k != "steps"})  # type: ignore[arg-type]
    result, learning = figure6.run(fargs, RunDir(tmp_path))
    assert (tmp_path / "figure6.png").exists()
    assert len((tmp_path / "figure6.csv").read_text().splitlines()) == 1 + 2 * 6
    targs = table1.Args(maze=small_maze, **TINY)  # type: ignore[arg-type]
    shared = table1.run(targs, RunDir(tmp_path / "t"), learning=learning)
    alone = table1.run(targs, RunDir(tmp_path / "u"))
    assert [r for r in shared["rows"] if r["explorer"] == "q-learning"] == [
        r for r in alone["rows"] if r["explorer"] == "q-learning"
    ]
    assert set(result["summary"]) == {"advised", "no_advice"}


def test_figure7_sweeps_kappa(small_maze: Path, tmp_path: Path) -> None:
    args = figure7.Args(
        maze=small_maze,
        trajectories=2,
        steps=100,
        kappa_max=1.4,
        kappa_step=0.7,
        episode_steps=30,
        progress=False,
    )
    result = figure7.run(args, RunDir(tmp_path))
    assert result["kappas"].tolist() == [0.0, 0.7, 1.4]
    for rates in result["advice_per_100_mean"].values():
        assert rates[0] == 100.0  # kappa 0: advice at every step
        assert rates[-1] == 0.0  # above log 4 nats: never
    assert (tmp_path / "figure7.png").exists()


def test_difficulty_exact_probability_matches_simulation(small_maze: Path, tmp_path: Path) -> None:
    args = difficulty.Args(maze=small_maze, tasks=2, steps=60, progress=False)
    result = difficulty.run(args, RunDir(tmp_path))
    setup = prepare(args, n_tasks=1)
    for gi, goal in enumerate(setup.domain.goals):
        exact = result["goals"][gi]["random_p_success"]
        runs = 2000
        wins = sum(
            setup.sim.fixed(
                "random", goal, rng_for(1, "mc", gi, i), advised=False, max_steps=60
            ).success
            for i in range(runs)
        )
        se = math.sqrt(max(exact * (1 - exact), 1e-4) / runs)
        assert abs(wins / runs - exact) < 5 * se


def test_hitting_probability_on_a_corridor() -> None:
    d = GridDomain.from_strings(["S.G"])
    w = difficulty.walker_weights(d, avoid_walls=True)
    # from the start the only open move is east; from the middle, east half the time
    prob, expected = difficulty.hitting(d, w, d.goals[0], 2)
    assert prob == pytest.approx(0.5)
    assert expected == pytest.approx(4.0)  # E = 1 + E_mid, E_mid = 1 + 0.5 * E  ->  E = 4


def test_trap_is_a_failure_mostly_in_another_goals_dead_end() -> None:
    d = GridDomain.from_strings(["G.#..G", "#.#.##", "#....S"])
    masks = dead_end_masks(d)
    left_goal, right_goal = d.state(0, 0), d.state(0, 5)
    assert masks[0, left_goal] and masks[0, d.state(0, 1)]
    inside = np.array([d.state(0, 1), left_goal] * 10)
    assert trap_goal(inside, False, 1, masks, last_n=20) == 0
    assert trap_goal(inside, True, 1, masks, last_n=20) == -1  # it succeeded
    elsewhere = np.array([d.start] * 20)
    assert trap_goal(elsewhere, False, 1, masks, last_n=20) == -1
    assert trap_goal(inside, False, 0, masks, last_n=20) == -1  # its own goal's corridor
    assert not masks[1, left_goal] and masks[1, right_goal]


def test_wilson_interval_known_values() -> None:
    assert wilson(0, 20) == pytest.approx((0.0, 0.1611), abs=1e-4)
    assert wilson(10, 20) == pytest.approx((0.2993, 0.7007), abs=1e-4)
    assert wilson(20, 20) == pytest.approx((0.8389, 1.0), abs=1e-4)


@given(st.integers(1, 500), st.data())
def test_wilson_interval_contains_the_rate(n: int, data: st.DataObject) -> None:
    k = data.draw(st.integers(0, n))
    lo, hi = wilson(k, n)
    assert 0.0 <= lo <= k / n <= hi <= 1.0


def test_moving_average_ignores_nan() -> None:
    x = np.array([1.0, np.nan, 3.0, 5.0])
    np.testing.assert_allclose(moving_average(x, 3), [1.0, 2.0, 4.0, 4.0])
    np.testing.assert_array_equal(moving_average(x, 1), x)


def test_cli_experiment_writes_results(small_maze: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    result = CliRunner().invoke(
        cli,
        [
            "experiment",
            "table1",
            "--maze",
            str(small_maze),
            "--tasks",
            "2",
            "--steps",
            "100",
            "--episodes",
            "3",
            "--episode-steps",
            "20",
            "--out",
            str(out),
            "--no-progress",
        ],
    )
    assert result.exit_code == 0, result.output
    assert (out / "table1.md").exists()
    assert "| random |" in result.output


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--experts", "oracle"], "'oracle' is not one of 'start', 'anywhere', 'policy'"),
        (["--alpha0", "0"], "alpha0 must be > 0"),
        (["--q-ties", "coin"], "'coin' is not one of 'advice', 'uniform'"),
        (["--q-epsilon", "2"], "epsilon"),
    ],
)
def test_cli_rejects_bad_settings(args: list[str], message: str, tmp_path: Path) -> None:
    result = CliRunner().invoke(
        cli,
        ["experiment", "table1", "--out", str(tmp_path / "x"), "--no-progress", *args],
        env={"COLUMNS": "200"},
    )
    assert result.exit_code == 2
    assert message in result.output and "Value error" not in result.output


def test_cli_rejects_a_bad_map(tmp_path: Path) -> None:
    bad = tmp_path / "bad.txt"
    bad.write_text("S..\n.#\n")
    result = CliRunner().invoke(
        cli, ["experiment", "figure5", "--maze", str(bad), "--out", str(tmp_path / "x")]
    )
    assert result.exit_code == 2
    assert "ragged row" in result.output


def test_cli_all_runs_every_experiment(small_maze: Path, tmp_path: Path) -> None:
    out = tmp_path / "all"
    result = CliRunner().invoke(
        cli,
        [
            "experiment",
            "all",
            "--maze",
            str(small_maze),
            "--tasks",
            "2",
            "--steps",
            "100",
            "--episodes",
            "3",
            "--episode-steps",
            "20",
            "--trajectories",
            "1",
            "--out",
            str(out),
            "--no-progress",
        ],
    )
    assert result.exit_code == 0, result.output
    for name in ("difficulty", "table1", "figure5", "figure6", "figure7"):
        assert (out / f"{name}.json").exists(), name
    assert {p.suffix for p in out.iterdir()} == {".json", ".csv", ".md", ".png"}


def test_ablations_vary_one_setting_at_a_time(small_maze: Path, tmp_path: Path) -> None:
    from app.experiments import ablations

    args = ablations.Args(
        maze=small_maze, tasks=1, q_tasks=1, steps=50, episodes=2, episode_steps=10, progress=False
    )
    result = ablations.run(args, RunDir(tmp_path))
    settings = {(r["setting"], str(r["value"])) for r in result["fixed"]}
    assert ("experts", "policy") in settings and ("window", "30") in settings
    assert ("no advice", "") in settings
    learning = {r["setting"] for r in result["learning"]}
    assert {"q_ties", "q_keep_history", "no advice"} <= learning
    assert (tmp_path / "ablations.md").exists()
