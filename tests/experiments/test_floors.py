"""The buildings and visitors experiments on maps of several floors: generated hospitals, the
project's IMDF venue and map files of several floors give rows, the reports name each map's
floors and free cells and say how kappa's scale is kept, and bad specs are refused clearly."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

from app.cli import cli
from app.domain.building import Building
from app.domain.floorplans import generate_floors
from app.experiments import buildings, suite, visitors
from app.experiments.output import RunDir

TINY: dict[str, Any] = {
    "tasks": 3, "buildings": (0,), "hospitals": ("2x32",), "imdf": True, "steps": 300,
    "q_tasks": 2, "episodes": 2, "workers": 1, "progress": False, "paper_levels": (0.5,),
    "goal_aware_levels": (0.5,), "guide_levels": (0.5,),
}  # fmt: skip


@pytest.fixture(scope="module")
def two_floors(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("maps") / "two_floors.txt"
    b = generate_floors(32, 32, 2, np.random.default_rng(5), purpose="office", n_goals=2)
    path.write_text(b.to_text())
    return path


@pytest.fixture(scope="module")
def tiny(two_floors: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    out = tmp_path_factory.mktemp("floors")
    return out, buildings.run(buildings.Args(mazes=(two_floors,), **TINY), RunDir(out))


def test_buildings_of_several_floors_give_rows(tiny: tuple[Path, dict[str, Any]]) -> None:
    _, result = tiny
    maps = {m["name"]: m for m in result["maps"]}
    hospital = next(n for n in maps if n.startswith("hospital-2x32-s"))
    assert list(maps) == [hospital, "imdf-hospital", "two_floors"]
    assert [maps[n]["floors"] for n in maps] == [2, 3, 2]
    assert all(m["actions"] == 6 and m["states"] > 0 and m["goals"] > 0 for m in maps.values())
    assert maps[hospital]["goals"] == 2 * 8  # --hospital-goals a floor
    assert (maps[hospital]["rows"], maps[hospital]["cols"]) == (32, 32)
    for name in [*maps, "suite"]:
        mine = [r for r in result["rows"] if r["map"] == name]
        assert len(mine) == 5 * 4  # every explorer and configuration
        assert all(r["tasks"] == (9 if name == "suite" else 3) for r in mine)
    assert {r["map"] for r in result["learning"]} == {*maps, "suite"}
    assert all(m["bug_advice_floor_per_100"] >= 0 for m in maps.values())


def test_a_buildings_report_names_floors_and_kappas_scale(
    tiny: tuple[Path, dict[str, Any]],
) -> None:
    out, result = tiny
    text = (out / "buildings.md").read_text()
    assert "| map | floors | rows x cols (a floor) | free cells |" in text
    venue = next(m for m in result["maps"] if m["name"] == "imdf-hospital")
    assert f"| imdf-hospital | 3 | {venue['rows']} x {venue['cols']} | {venue['states']} |" in text
    assert "kl_scale" in text and "log 4 / log 6" in text


def test_the_imdf_venue_is_the_sample_imported_whole() -> None:
    b = suite.imdf_hospital()
    assert isinstance(b, Building) and b.n_floors == 3 and b.goal_names is not None
    assert len(b.goals) == len(b.goal_names) > 1


def test_one_floor_maps_keep_their_seeds_and_say_nothing_of_floors() -> None:
    base = buildings.Args(buildings=(64, 128), progress=False)
    more = buildings.Args(buildings=(64, 128), hospitals=("3x64",), imdf=True, progress=False)
    one, both = suite.map_suite(base), suite.map_suite(more)
    assert both[:2] == one and [s.kind for s in both] == ["building", "building", "hospital",
                                                           "venue"]  # fmt: skip
    assert both[2].name == f"hospital-3x64-s{both[2].seed}" and both[2].floors == 3
    assert buildings.floors_note([{"name": "x", "floors": 1}]) == []


def test_goal_moves_are_each_destinations_distances(two_floors: Path) -> None:
    b = suite.load_map(suite.MapSpec(0, "file", 0, -1, str(two_floors)))
    assert isinstance(b, Building)
    moves = suite.goal_moves(b)
    for i, g in enumerate(b.goals):
        np.testing.assert_array_equal(moves[i], b.distances_to(g))
    assert (suite.compass_detours(b) <= moves).all()  # a detour is a move of the way


def test_visitors_on_several_floors_give_rows(tmp_path: Path) -> None:
    args = visitors.Args(
        buildings=(0,), hospitals=("2x32",), tasks=2, steps=200, workers=1, progress=False,
        visitors=("random", "corridor p=0.5", "optimal q=0.2"),
    )  # fmt: skip
    result = visitors.run(args, RunDir(tmp_path))
    assert [m["floors"] for m in result["maps"]] == [2]
    assert len(result["rows"]) == 2 * 3 * 2  # the map and the suite, visitors, configurations
    assert "| floors |" in (tmp_path / "visitors.md").read_text()


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--hospitals", "3by64"], "bad hospital '3by64': give FLOORSxSIDE"),
        (["--hospitals", "1x64"], "2-16 floors of a side of 32-256 cells"),
        (["--hospitals", "3x16"], "2-16 floors of a side of 32-256 cells"),
        (["--hospital-goals", "0", "--hospitals", "2x32"], "hospital-goals must be 1 to 40"),
        (["--buildings", "0"], "the suite is empty"),
    ],
)
def test_bad_suite_specs_are_refused_clearly(argv: list[str], message: str) -> None:
    for name in ("buildings", "visitors"):
        result = CliRunner().invoke(cli, ["experiment", name, *argv])
        assert result.exit_code == 2, result.output
        assert message in result.output
