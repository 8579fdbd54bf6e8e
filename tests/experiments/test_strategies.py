"""The strategies comparison runs in seconds with a tiny budget, writes its files and is
reproducible (whatever the number of worker processes)."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from app.cli import cli
from app.experiments import strategies, strategy_suite
from app.experiments.curves import paired
from app.experiments.output import RunDir

TINY = {"tasks": 2, "maps": 2, "map_size": 9, "steps": 120, "workers": 1, "progress": False}


@pytest.fixture(scope="module")
def tiny_run(small_maze: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:  # type: ignore[type-arg]
    out = tmp_path_factory.mktemp("strategies")
    args = strategy_suite.Args(maze=small_maze, **TINY)  # type: ignore[arg-type]
    return out, strategies.run(args, RunDir(out))


def test_strategies_writes_every_file(tiny_run: tuple[Path, dict]) -> None:  # type: ignore[type-arg]
    out, result = tiny_run
    names = {p.name for p in out.iterdir()}
    assert names == {
        "strategies.json",
        "strategies.csv",
        "strategies_maps.csv",
        "strategies_tasks.csv",
        "strategies_versus.csv",
        "strategies.md",
        "strategies_suite.png",
        "strategies_file.png",
    }
    saved = json.loads((out / "strategies.json").read_text())
    assert [m["kind"] for m in saved["maps"]] == ["file", "perfect", "braided"]
    text = (out / "strategies.md").read_text()
    assert "Who advice helps" in text and "Target 1" in text and "Target 2" in text
    assert "against every other default" in text
    assert {v["other"] for v in result["versus"]} >= {"none", "paper@0.5", "always"}
    n_configs = len(result["configs"])
    tasks = (out / "strategies_tasks.csv").read_text().splitlines()
    assert len(tasks) == 1 + 5 * n_configs * 3 * 2  # explorers x configs x maps x tasks


def test_strategies_rows_are_consistent(tiny_run: tuple[Path, dict]) -> None:  # type: ignore[type-arg]
    _, result = tiny_run
    rows = [r for r in result["rows"] if r["scope"] == "suite"]
    assert {r["curve"] for r in rows} >= {"none", "paper", "goal_aware", "early", "always"}
    for r in rows:
        assert r["tasks"] == 3 * 2
        assert r["success_ci_low"] <= r["success"] <= r["success_ci_high"]
        assert -1.0 <= r["change_vs_none_ci_low"] <= r["change_vs_none_ci_high"] <= 1.0
        if r["curve"] == "none":
            assert r["advice_per_100_steps"] == 0.0 and r["change_vs_none"] == 0.0
        if r["curve"] == "always":
            assert r["advice_per_100_steps"] == 100.0
    optimal = {r["key"]: r for r in rows if r["explorer"] == "optimal"}
    assert optimal["none"]["success"] == 1.0  # 120 steps is plenty on 9x9 and 11x11
    defaults = {r["curve"] for r in rows if r["default"]}
    assert defaults >= {"paper", "goal_aware", "early", "importance", "mistake", "random"}
    assert isinstance(result["targets"]["first_met"], bool)


def test_strategies_seeded_runs_are_reproducible(small_maze: Path, tmp_path: Path) -> None:
    args = strategy_suite.Args(maze=small_maze, **{**TINY, "maps": 1})  # type: ignore[arg-type]
    args.goal_aware_levels, args.paper_levels, args.variants = (0.5,), (0.5,), ()
    first = strategy_suite.run_all(args)
    again = strategy_suite.run_all(replace(args, workers=2))  # worker processes give the same
    other = strategy_suite.run_all(replace(args, seed=1))
    for explorer, by_key in first.data.items():
        for key, measures in by_key.items():
            for name, values in measures.items():
                np.testing.assert_array_equal(values, again.data[explorer][key][name])
    assert any(
        not np.array_equal(m["steps"], other.data[e][k]["steps"])
        for e, by_key in first.data.items()
        for k, m in by_key.items()
    )


def test_strategies_configs_include_every_default_level() -> None:
    args = strategy_suite.Args(
        kappa=0.6, paper_levels=(0.25,), goal_aware_levels=(0.0,),
        variants=("goal_aware beta=0", "goal_aware beta=0.5"),
    )  # fmt: skip
    keys = [c.key for c in strategy_suite.configs(args)]
    assert keys[0] == "none" and "paper@0.6" in keys and "goal_aware@0.6" in keys
    assert "goal_aware beta=0.5@0.6" in keys and "goal_aware beta=0@0.6" not in keys
    defaults = [c.key for c in strategy_suite.configs(args) if c.default]
    assert defaults == [
        "none",
        "paper@0.6",
        "goal_aware@0.6",
        "early@20",
        "importance@0.5",
        "mistake@0.5",
        "random@0.1",
        "always",
    ]


def test_paired_difference_interval() -> None:
    a = np.array([1, 1, 0, 1, 0, 1, 1, 1], dtype=float)
    b = np.array([0, 1, 0, 0, 0, 1, 0, 1], dtype=float)
    mean, lo, hi = paired(a, b)
    d = a - b
    half = 1.959963984540054 * d.std(ddof=1) / math.sqrt(d.size)
    assert mean == pytest.approx(0.375)
    assert (lo, hi) == pytest.approx((0.375 - half, 0.375 + half))
    assert paired(np.ones(4), np.zeros(4)) == (1.0, 1.0, 1.0)


def test_cli_strategies_runs_and_rejects_policy_experts(small_maze: Path, tmp_path: Path) -> None:
    base = ["experiment", "strategies", "--maze", str(small_maze), "--no-progress"]
    small = ["--tasks", "1", "--maps", "0", "--steps", "40", "--workers", "1"]
    result = CliRunner().invoke(cli, [*base, *small, "--out", str(tmp_path / "a")])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "a" / "strategies.md").exists()
    assert "Who advice helps" in result.output
    bad = CliRunner().invoke(cli, [*base, *small, "--experts", "policy", "--out", str(tmp_path)])
    assert bad.exit_code == 2
    assert "expert trajectories" in bad.output
