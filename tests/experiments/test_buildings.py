"""The buildings experiment runs in seconds with a tiny budget, writes its files, takes any map
file, is reproducible whatever the number of workers, and its target checks read the rows."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

from app.cli import cli
from app.domain.generate import generate_building_domain
from app.experiments import buildings
from app.experiments.output import RunDir

TINY: dict[str, Any] = {
    "tasks": 3, "buildings": (24,), "steps": 400, "q_tasks": 2, "episodes": 3, "workers": 1,
    "progress": False, "paper_levels": (0.5,), "goal_aware_levels": (0.5,),
    "guide_levels": (0.25, 0.5),
}  # fmt: skip


@pytest.fixture(scope="module")
def floor(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("maps") / "floor.txt"
    path.write_text(generate_building_domain(20, 26, 9, n_goals=3).to_text())
    return path


@pytest.fixture(scope="module")
def tiny(floor: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    out = tmp_path_factory.mktemp("buildings")
    args = buildings.Args(mazes=(floor,), **TINY)
    return out, buildings.run(args, RunDir(out))


def test_writes_every_file_and_names_the_suite(tiny: tuple[Path, dict[str, Any]]) -> None:
    out, result = tiny
    for name in ("buildings.json", "buildings.csv", "buildings_learning.csv", "buildings.md",
                 "buildings.png"):  # fmt: skip
        assert (out / name).stat().st_size > 0, name
    assert [m["name"] for m in result["maps"]][1] == "floor"
    assert result["maps"][1]["states"] > 0 and result["maps"][0]["rows"] == 24
    keys = {c["key"] for c in result["configs"]}
    assert keys == {"none", "paper@0.5", "goal_aware@0.5", "guide@0.25", "guide@0.5"}
    # a row per map (and the suite), explorer and configuration; success is a share of tasks
    assert len(result["rows"]) == 3 * 5 * len(keys)
    for r in result["rows"]:
        assert r["tasks"] == (6 if r["map"] == "suite" else 3)
        assert r["success"] * r["tasks"] == pytest.approx(round(r["success"] * r["tasks"]))
    assert {r["curve"] for r in result["learning"]} == {"none", "paper", "guide"}
    text = (out / "buildings.md").read_text()
    assert "## Targets" in text and "Q-learning" in text
    assert json.loads((out / "buildings.json").read_text())["targets"] == result["targets"]


def test_the_unadvised_configuration_gives_no_advice(tiny: tuple[Path, dict[str, Any]]) -> None:
    _, result = tiny
    assert all(r["advice_per_100_steps"] == 0 for r in result["rows"] if r["curve"] == "none")
    assert all(r["change_vs_none"] == 0 for r in result["rows"] if r["curve"] == "none")


def test_target_checks_follow_the_rows(tiny: tuple[Path, dict[str, Any]]) -> None:
    """Each check is recomputed from the rows it names (not a stored verdict)."""
    _, result = tiny
    rows = result["rows"]
    for c in result["targets"]["checks"]:
        if "advice / 100" in c["what"]:
            explorer = c["what"].split(" >=")[0]
            need = buildings.TARGETS[explorer]
            r = buildings.find(rows, map=c["map"], explorer=explorer, key="guide@0.5")
            assert c["ok"] == (r["success"] >= need and r["advice_per_100_steps"] <= 25)
    assert result["targets"]["all_hold"] == all(c["ok"] for c in result["targets"]["checks"])


def test_curve_above_compares_where_both_reach() -> None:
    mine = np.array([[0.0, 0.2], [10.0, 0.9], [20.0, 1.0]])
    other = np.array([[0.0, 0.1], [15.0, 0.5]])
    c = buildings.curve_above(mine, other)
    assert c["shared_range"] == [0.0, 15.0] and c["above"] and c["min_margin"] > 0
    worse = buildings.curve_above(other, mine)
    assert worse["above"] is False and worse["min_margin"] < 0
    apart = buildings.curve_above(np.array([[30.0, 1.0]]), other)
    assert apart["shared_range"] is None and apart["above"] is None
    # a task's difference at the unadvised success is noise at 100 tasks, not at 10,000
    base, one_less = np.array([[0.0, 0.02], [5.0, 0.02]]), np.array([[0.0, 0.01], [5.0, 0.01]])
    noisy = buildings.curve_above(one_less, base, tasks=100)
    assert noisy["above"] and not noisy["strictly_above"]
    assert not buildings.curve_above(one_less, base, tasks=10_000)["above"]


def test_reproducible_across_worker_counts(floor: Path, tmp_path: Path) -> None:
    args = buildings.Args(mazes=(floor,), **{**TINY, "q_tasks": 0})
    one = buildings.run(args, RunDir(tmp_path / "one"))
    two = buildings.run(replace(args, workers=2), RunDir(tmp_path / "two"))
    assert one["rows"] == two["rows"] and one["learning"] == two["learning"] == []


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--buildings", "8"], "at least 16"),
        (["--mazes", "/nonexistent/map.txt"], "no map file"),
        (["--experts", "policy"], "needs expert trajectories"),
        (["--q-reach", "0.5"], "q-reach must be at least 1"),
    ],
)
def test_bad_arguments_are_refused_clearly(argv: list[str], message: str) -> None:
    result = CliRunner().invoke(cli, ["experiment", "buildings", *argv])
    assert result.exit_code != 0
    assert message in result.output
