"""``maze import`` of an IMDF archive without ``--level``: the whole building as a map of
several floors (every level a floor, the lifts, stairs and escalators its connections, the
named destinations its goals), and a venue made in code turned into one."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from app.cli import cli
from app.domain.building import Building
from app.domain.grid import Frame, GridDomain
from app.mapio import MapImportError
from app.mapio import building as building_module
from app.mapio.budget import MemoryBudget
from app.mapio.building import venue_building
from app.mapio.venue import Connection, Destination, Level, LocalProjection, Stop, Venue
from tests.mapio.imdf_helpers import docs, features, write

runner = CliRunner()

DESTINATIONS = {
    "Information", "Radiology", "Emergency", "Pharmacy", "Registration",  # ground floor
    "Cardiology", "Room 1.02", "Dermatology", "Waiting area", "Laboratory", "Restrooms",
    "Maternity", "Dialysis", "Cafeteria", "Chapel", "Oncology", "Neurology",
}  # fmt: skip


def test_cli_import_imdf_writes_the_whole_building(tmp_path: Path) -> None:
    out = tmp_path / "hospital.txt"
    result = runner.invoke(cli, ["maze", "import", str(write(tmp_path)), "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "IMDF venue 'Example Hospital': 3 floors (0 'Ground floor', 1 'First floor', " \
        "2 'Second floor')" in result.output  # fmt: skip
    assert "1 destination(s) outside the kept region, left out: 'Store'" in result.output
    checked = runner.invoke(cli, ["maze", "check", str(out)])
    assert checked.exit_code == 0, checked.output
    b = Building.from_file(out)
    assert [(f.ordinal, f.name, f.elevation) for f in b.floors] == [
        (0, "Ground floor", 0.0), (1, "First floor", 4.0), (2, "Second floor", 8.0),
    ]  # fmt: skip
    assert b.frame is not None and b.frame.resolution == 0.5
    assert b.goal_names is not None and set(b.goal_names) == DESTINATIONS
    assert len(b.goals) == len(DESTINATIONS)
    kinds = {c.name: (c.kind, c.cost, c.floors) for c in b.connections}
    assert kinds == {  # the default costs at 0.5 m a cell
        "Lift 1": ("lift", 24, (0, 1, 2)),
        "Stairs A": ("stairs", 36, (0, 1, 2)),
        "Escalator": ("escalator", 38, (0, 1)),
    }
    lift = next(c for c in b.connections if c.kind == "lift")
    assert len({(r, c) for _, r, c in lift.stops}) == 1  # one cell of the shaft on every floor
    for conn in b.connections:  # each stop a free cell of its floor, none a destination
        for f, r, c in conn.stops:
            assert b.floors[f].rows[r][c] == "."
    assert b.cell(b.start)[0] == 0  # on the ground floor
    # every destination is reached from the start, through the connections
    assert (b.times_to(b.start)[list(b.goals)] > 0).all()
    # the goals are listed with their cells [floor, row, col]
    for i, g in enumerate(b.goals):
        assert f"G{i} {list(b.cell(g))}: {b.goal_label(i)}" in result.output


def test_cli_import_imdf_building_costs_follow_the_resolution_and_level_keeps_one_floor(
    tmp_path: Path,
) -> None:
    path = write(tmp_path)
    coarse = runner.invoke(cli, ["maze", "import", str(path), "--resolution", "1"])
    assert coarse.exit_code == 0, coarse.output
    text = coarse.stdout  # the map on stdout, the notes on stderr
    assert text.startswith("resolution: 1.0\n")
    b = Building.from_text(text)
    assert {(c.kind, c.cost) for c in b.connections} == {
        ("lift", 12), ("stairs", 18), ("escalator", 19),
    }  # fmt: skip
    one = runner.invoke(cli, ["maze", "import", str(path), "--level", "1"])
    assert one.exit_code == 0 and "floor:" not in one.stdout
    assert isinstance(GridDomain.from_text(one.stdout), GridDomain)
    refused = runner.invoke(cli, ["maze", "import", str(path), "--start", "3,3"])
    assert refused.exit_code == 2
    assert "--start and --goal-cells place one level's start and goals: give --level" in (
        " ".join(refused.output.split())
    )


def test_cli_import_imdf_building_leaves_out_levels_nothing_joins(tmp_path: Path) -> None:
    d = docs()
    ground = features(d, "level")[0]
    for o in range(3, 10):  # empty levels above: nothing joins them
        props = ground["properties"] | {"ordinal": o, "name": {"en": f"Level {o}"}}
        features(d, "level").append({**ground, "id": f"level-{o}", "properties": props})
    out = tmp_path / "tall.txt"
    result = runner.invoke(cli, ["maze", "import", str(write(tmp_path, d)), "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "7 level(s) not joined to the kept region, left out: '3 Level 3', '4 Level 4'" in (
        result.output
    )
    assert "and 2 more" in result.output
    assert Building.from_file(out).n_floors == 3


# ---- a venue made in code -------------------------------------------------------------------
FRAME = Frame(1.0, (0.0, 0.0, 0.0))


def level(ordinal: int, rows: list[str], name: str = "") -> Level:
    free = np.array([[ch == "." for ch in row] for row in rows])
    return Level(ordinal, name or f"Level {ordinal}", str(ordinal), ordinal * 4.0, free)


def stop(ordinal: int, *cells: tuple[int, int]) -> Stop:
    return Stop(ordinal, np.array(cells, dtype=np.int32))


def venue(levels: list[Level], connections: list[Connection], dests: list[Destination]) -> Venue:
    shape = levels[0].free.shape
    return Venue("Annex", LocalProjection(0.0, 50.0), FRAME, (shape[0], shape[1]),
                 tuple(levels), tuple(connections), tuple(dests))  # fmt: skip


def dest(name: str, ordinal: int, cell: tuple[int, int]) -> Destination:
    return Destination(name, "room", ordinal, cell, "unit", "f")


def test_venue_building_joins_levels_by_their_connections_and_makes_names_plain() -> None:
    levels = [
        level(-1, ["#####", "#...#", "#####"], "Car park <P1>"),
        level(0, ["#####", "#...#", "#####"]),
        level(1, ["#####", "#.#.#", "#####"]),  # its east cell is joined to nothing
    ]
    lift = Connection("elevator", "", (stop(-1, (1, 1), (1, 2)), stop(0, (1, 1), (1, 2)),
                                       stop(1, (1, 1))))  # fmt: skip
    walk = Connection("movingwalkway", "Walkway", (stop(-1, (1, 3)), stop(0, (1, 3))))
    nowhere = Connection("stairs", "Back stairs", (stop(0, (0, 0)), stop(1, (0, 0))))  # walls
    dests = [dest("Café", 0, (1, 3)), dest("Café", 1, (1, 1)), dest("Shop", 1, (1, 3)),
             dest("Pay & display", -1, (1, 2)), dest("Kiosk", -1, (1, 2))]  # fmt: skip
    made = venue_building(venue(levels, [lift, walk, nowhere], dests), np.random.default_rng(0))
    b = made.building
    assert b is not None and made.ordinal is None
    assert [f.name for f in b.floors] == ["Car park P1", "Level 0", "Level 1"]
    # the elevator is a lift, named by its kind; the moving walkway a ramp (96 s at 1 m: 48)
    assert [(c.kind, c.name, c.cost) for c in b.connections] == [
        ("lift", "Lift 1", 12), ("ramp", "Walkway", 48),
    ]  # fmt: skip
    # the lift stops on the cell every level has, avoiding the car park's destination
    assert b.connections[0].stops == ((0, 1, 1), (1, 1, 1), (2, 1, 1))
    assert b.goal_names == ("Pay & display / Kiosk", "Café", "Café 2")
    assert "1 connection(s) with fewer than two stops on free cells, left out: 'Back stairs'" in (
        made.notes
    )
    assert "1 destination(s) outside the kept region, left out: 'Shop'" in made.notes
    assert "destination [2, 1, 1] 'Café' written as 'Café 2'" in made.notes
    assert b.floors[2].rows[1] == "#G###"  # the unjoined cell walled up
    assert b.cell(b.start)[0] == 1  # the floor of ordinal 0


def test_venue_building_of_one_joined_level_is_that_level_and_cells_are_bounded(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    levels = [level(0, ["#####", "#...#", "#####"]), level(1, ["#####", "#..##", "#####"])]
    made = venue_building(venue(levels, [], []), np.random.default_rng(0))
    assert made.building is None and made.ordinal == 0
    assert "lies on level 0 alone: a one-floor map of it" in made.notes[-1]
    monkeypatch.setattr(building_module, "MAX_CELLS", 29)
    with pytest.raises(
        MapImportError,
        match=re.escape(
            "2 level(s) of 3 x 5 cells at 1 m a cell: a map of several floors holds at most 29 "
            "cells: give a coarser --resolution"
        ),
    ):
        venue_building(venue(levels, [], []), np.random.default_rng(0))


def test_venue_building_without_destinations_picks_goals_on_each_floor() -> None:
    rows = ["#######", "#.....#", "#.....#", "#######"]
    levels = [level(0, rows), level(1, rows)]
    lift = Connection("elevator", "Lift", (stop(0, (1, 1)), stop(1, (1, 1))))
    made = venue_building(venue(levels, [lift], []), np.random.default_rng(0), n_goals=2)
    b = made.building
    assert b is not None and b.goal_names is None
    assert np.bincount(b.cells[list(b.goals), 0]).tolist() == [2, 2]
    assert "no named destination in the kept region: 2 goal(s) picked a floor" in made.notes


def test_a_whole_building_budgets_every_level_placed_as_a_map() -> None:
    one, three = MemoryBudget(), MemoryBudget(placed=3)
    cells = 100 * 200
    extra = three.venue_estimate(100, 200, 3) - one.venue_estimate(100, 200, 3)
    assert extra == 2 * cells * one.cell_bytes
