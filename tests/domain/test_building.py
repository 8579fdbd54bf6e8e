"""Maps of several floors: the text read into a :class:`Building` and written back, U and D
along the connections, rides' times, and every refusal naming the floor, line and column."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.domain import building as building_module
from app.domain import floors as floors_module
from app.domain.building import ACTIONS, Building, D, U, load_map, load_map_file
from app.domain.floors import Connection, Floor, is_floors_text
from app.domain.generate import generate_building, generate_maze
from app.domain.grid import Frame, GridDomain, MapError, NamedCell
from app.domain.maps import DEFAULT_MAP

#: ordinals -1, 0, 1: the lift serves all three, the stairs the lower two
TEXT = """\
resolution: 0.5
origin: 1.0 2.0 0.0
destination: 0 1 2 Radiology
connection: lift 5 -1:1,1 0:1,1 1:1,1 Lift 1
connection: stairs 3 -1:1,4 0:1,4 Stairs A
floor: -1 Basement elevation: -4.0
######
#..#.#
#S...#
######
floor: 0 Ground floor elevation: 0.0
######
#.G..#
#....#
######
floor: 1 First floor
######
#.G..#
######
######"""


def refusal(text: str) -> MapError:
    with pytest.raises(MapError) as refused:
        Building.from_text(text)
    return refused.value


def changed(old: str, new: str) -> str:
    assert old in TEXT
    return TEXT.replace(old, new, 1)


def test_building_reads_floors_connections_and_names() -> None:
    b = Building.from_text(TEXT)
    assert b.shape == (3, 4, 6) and b.n_floors == 3
    assert [(f.ordinal, f.name, f.elevation) for f in b.floors] == [
        (-1, "Basement", -4.0), (0, "Ground floor", 0.0), (1, "First floor", None),
    ]  # fmt: skip
    assert b.actions == ACTIONS == ("N", "E", "S", "W", "U", "D") and b.n_actions == 6
    assert b.cell(b.start) == (0, 2, 1)  # floor index 0 is ordinal -1
    assert b.goal_cells == [(1, 1, 2), (2, 1, 2)]
    assert b.goal_names == ("Radiology", None) and b.goal_label(1) == "G1"
    assert b.cells.shape == (b.n_states, 3) and b.next_state.shape == (b.n_states, 6)
    assert b.frame == Frame(0.5, (1.0, 2.0, 0.0))
    lift, stairs = b.connections
    assert (lift.kind, lift.cost, lift.name) == ("lift", 5, "Lift 1")
    assert lift.stops == ((0, 1, 1), (1, 1, 1), (2, 1, 1))
    assert stairs.floors == (0, 1)
    for s in (b.state(0, 1, 1), b.state(2, 1, 1)):
        assert b.connection_of[s] == 0


def test_building_u_and_d_ride_to_the_next_stop_and_stay_elsewhere() -> None:
    b = Building.from_text(TEXT)
    low, mid, top = (b.state(f, 1, 1) for f in range(3))
    assert b.step(low, U) == mid and b.step(mid, U) == top and b.step(top, U) == top
    assert b.step(top, D) == mid and b.step(mid, D) == low and b.step(low, D) == low
    stairs_top = b.state(1, 1, 4)
    assert b.step(stairs_top, U) == stairs_top  # the stairs stop at ordinal 0
    plain = b.state(1, 2, 2)
    assert b.step(plain, U) == plain and b.step(plain, D) == plain
    # time: a ride is COST x the ordinals' difference; everything else one move
    assert b.durations[low, U] == 5 and b.durations[top, D] == 5
    assert b.durations[stairs_top, D] == 3 and b.durations[stairs_top, U] == 1
    assert b.durations[plain].tolist() == [1] * 6
    assert b.rides.tolist() == [[low, mid, 5, 0], [mid, top, 5, 0],
                                [b.state(0, 1, 4), stairs_top, 3, 1]]  # fmt: skip
    # from the start: N to the lift, U, E to the first goal: 3 actions, 1 + 5 + 1 moves of time
    assert b.distances_to(b.goals[0])[b.start] == 3
    assert b.times_to(b.goals[0])[b.start] == 7


def test_building_ride_time_counts_the_ordinals_travelled() -> None:
    """An express lift from ordinal 0 to ordinal 3 (a map without floors 1 and 2) travels
    three storeys in one action."""
    text = "connection: lift 4 0:0,0 3:0,0 Express\nfloor: 0 Lobby\nSG\nfloor: 3 Roof\n.G"
    b = Building.from_text(text)
    assert b.next_state[b.state(0, 0, 0), U] == b.state(1, 0, 0)
    assert b.durations[b.state(0, 0, 0), U] == 12


def test_building_text_round_trip_is_the_same_text() -> None:
    b = Building.from_text(TEXT)
    written = b.to_text()
    # written again: the stairs' stops, the floors' order, the rows as they were
    assert written == TEXT
    assert Building.from_text(written).to_text() == written
    # blank lines between floors and trailing spaces are not part of the map
    loose = TEXT.replace("floor: 0 ", "\n\nfloor: 0 ").replace("#S...#", "#S...#   ")
    assert Building.from_text(loose).to_text() == TEXT


def test_load_map_reads_either_kind_and_keeps_one_floor_files_as_they_are(
    tmp_path: Path,
) -> None:
    one = DEFAULT_MAP.read_text(encoding="utf-8")
    grid = load_map(one)
    assert isinstance(grid, GridDomain) and grid.to_text() + "\n" == one
    named = "resolution: 0.5\norigin: 0.0 0.0 0.0\ndestination: 0 2 Lab\nS.G\n..G"
    assert load_map(named).to_text() == named  # byte for byte
    assert not is_floors_text(named) and is_floors_text(TEXT)
    path = tmp_path / "hospital.txt"
    path.write_text(TEXT)
    b = load_map_file(path)
    assert isinstance(b, Building) and b.name == "hospital"


def test_a_one_floor_reader_refuses_floors_plainly() -> None:
    with pytest.raises(MapError) as refused:
        GridDomain.from_text(TEXT)
    message = str(refused.value)
    assert message.startswith("line 4: connection lines belong to a map of several floors")
    assert "`maze check` reads both" in message
    connection = "connection: lift 3 0:0,0 1:0,0 L\nS.G"
    with pytest.raises(MapError, match="line 1: connection lines belong"):
        load_map(connection)  # no floor: line: a one-floor map, which has no connections


@pytest.mark.parametrize(
    ("old", "new", "expected"),
    [
        (
            "#.G..#\n######\n######",
            "#.G.x#\n######\n######",
            "floor 1 'First floor', line 18, column 5: unknown character 'x'",
        ),
        (
            "#.G..#\n#....#",
            "#.G..#\n#...#",
            "floor 0 'Ground floor', line 14: ragged row: 5 characters where row 1 has 6",
        ),
        (
            "#.G..#\n######\n######",
            "#.G..#\n######",
            "floor 1 'First floor', line 16: 3 rows of 6 where floor -1 'Basement' has 4 rows "
            "of 6: every floor has the same rows",
        ),
        (
            "#....#",
            "#...S#",
            "2 starts (floor -1 'Basement', line 9, column 2; floor 0 'Ground "
            "floor', line 14, column 5): mark exactly one cell of the building with 'S'",
        ),
        (
            "#..#.#",
            "#..###",
            "line 5, column 22: connection 'Stairs A': stop [1, 4] on floor -1 "
            "'Basement' is a wall",
        ),
        (
            "-1:1,4 0:1,4",
            "-1:1,4 0:1,1",
            "line 5, column 29: connection 'Stairs A': stop [1, 1] on "
            "floor 0 'Ground floor' is a stop of 'Lift 1' too",
        ),
        (
            "-1:1,4 0:1,4",
            "-1:1,4 -1:2,4",
            "line 5, column 29: connection 'Stairs A': two stops on floor -1 'Basement'",
        ),
        (
            "-1:1,4 0:1,4",
            "-1:1,4 2:1,4",
            "line 5, column 29: connection 'Stairs A': no floor of "
            "ordinal 2 (the floors' ordinals are -1, 0, 1)",
        ),
        (
            "-1:1,4 0:1,4",
            "-1:1,4 0:9,4",
            "line 5, column 29: connection 'Stairs A': stop [9, 4] on "
            "floor 0 'Ground floor' is off its 4x6 map",
        ),
        ("-1:1,4 0:1,4", "-1:1,4 0:1 4", "line 5, column 29: '0:1' is not a stop"),
        ("stairs 3", "stair 3", "line 5, column 13: unknown kind 'stair': write connection: KIND"),
        (
            "stairs 3",
            "stairs 0",
            "line 5, column 20: cost '0' is not a number of moves from 1 to 1000",
        ),
        (
            " Stairs A\n",
            "\n",
            "line 5, column 34: a connection needs a kind, a cost, two stops or more and a name",
        ),
        (" Stairs A\n", " 1:1,4\n", "line 5, column 40: a connection's name is missing"),
        (
            "Stairs A\n",
            "Lift 1\n",
            "line 5: connection 'Lift 1': the name is given twice (line 4 names it first)",
        ),
        (
            "floor: 1 First",
            "floor: 0 First",
            "floor 0 'First floor', line 16: ordinal 0 after 0: "
            "floors are written in the order of their ordinals",
        ),
        (
            "floor: 1 First floor",
            "floor: 1 basement",
            "floor 1 'basement', line 16: the name 'basement' is given twice",
        ),
        (
            "floor: 1 First floor",
            "floor: 1 First floor elevation: -5",
            "floor 1 'First floor', line 16: elevation -5 m is not above the floor below's (0 m)",
        ),
        (
            "floor: 1 First floor",
            "floor: 1 First floor elevation: high",
            "line 16, column 33: elevation 'high' is not a height in metres",
        ),
        (
            "floor: 1 First floor",
            "floor: one First floor",
            "line 16, column 8: 'one' is not a floor's ordinal",
        ),
        ("floor: 1 First floor", "floor: 1", "line 16, column 9: a floor needs a name"),
        (
            "destination: 0 1 2",
            "destination: 0 1 3",
            "line 3, column 16: cell [1, 3] on floor 0 "
            "'Ground floor' is a free cell, not a destination",
        ),
        (
            "destination: 0 1 2",
            "destination: 4 1 2",
            "line 3, column 14: destination: no floor of ordinal 4",
        ),
        (
            "destination: 0 1 2 Radiology",
            "destination: 1 2 Radiology",
            "line 3, column 27: a "
            "destination on a map of several floors needs a floor, a row, a column and a name",
        ),
        (
            "#.G..#\n######\n######",
            "#.G.##\n####G#\n######",
            "floor 1 'First floor', line 19, column 5: goal unreachable from the start",
        ),
        (
            "######\nfloor: 0",
            "######\norigin: 0 0\nfloor: 0",
            "line 11: a origin line among the rows: header lines come before the first floor: line",
        ),
        ("resolution: 0.5", "resolution: 0.5\n#S.G#", "line 2: a row before the first floor: line"),
        ("resolution: 0.5", "level: 2", "line 1: unknown header 'level'"),
    ],
)
def test_building_refusals_name_the_floor_line_and_column(
    old: str, new: str, expected: str
) -> None:
    assert expected in str(refusal(changed(old, new)))


def test_building_refuses_a_single_floor_and_long_values_are_cut() -> None:
    one = "floor: 0 Ground\nS.G"
    assert "line 1: a map of several floors has two floors or more, this one has 1" in str(
        refusal(one)
    )
    long = str(refusal(changed("stairs 3", "s" + "x" * 500 + " 3")))
    assert "unknown kind 'sxxxxxxxx" in long and "...'" in long and len(long) < 400


def test_building_limits_are_checked_before_the_arrays(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(building_module, "MAX_CELLS", 71)  # 3 x 4 x 6 = 72
    assert "3 floors of 4 x 6 cells: a map of several floors holds at most 71 cells" in str(
        refusal(TEXT)
    )
    monkeypatch.setattr(floors_module, "MAX_FLOORS", 2)
    two_stops = changed("-1:1,1 0:1,1 1:1,1", "-1:1,1 0:1,1")
    assert "line 16: more than 2 floors: a map has at most 2" in str(refusal(two_stops))
    monkeypatch.setattr(floors_module, "MAX_CONNECTIONS", 1)
    assert "line 5: more than 1 connections" in str(refusal(two_stops))


def test_building_from_parts_checks_parts_made_in_code() -> None:
    floors = [Floor(0, "Ground", ("S.", "..")), Floor(1, "Top", ("G.", ".."))]
    lift = Connection("lift", 2, ((1, 1, 1), (0, 1, 1)), "Lift")  # stops in any order
    b = Building.from_parts(floors, [lift])
    assert b.connections[0].stops == ((0, 1, 1), (1, 1, 1))
    assert b.times_to(b.goals[0])[b.start] == 2 + 2 + 2
    with pytest.raises(MapError, match=r"floor 1 'Top': cell \[1, 0, 0\]: goal unreachable"):
        Building.from_parts(floors)
    walled = Connection("lift", 2, ((0, 1, 1), (1, 5, 5)), "Lift")
    with pytest.raises(MapError, match=r"connection 'Lift': stop \[5, 5\] on floor 1 'Top' is off"):
        Building.from_parts(floors, [walled])
    with pytest.raises(MapError, match="unknown kind 'elevator'"):
        Building.from_parts(floors, [Connection("elevator", 2, lift.stops, "Lift")])


def test_building_state_at_snaps_metres_to_a_cell_of_the_floor() -> None:
    b = Building.from_text(TEXT)
    x, y = b.frame.centre(1, 2, 4) if b.frame else (0.0, 0.0)
    assert b.cell(b.state_at(1, x, y)) == (1, 1, 2)
    with pytest.raises(ValueError, match=r"is a wall"):
        b.state_at(2, x - 1.0, y)
    with pytest.raises(ValueError, match="off the 3x4x6 map"):
        b.state(3, 0, 0)
    assert np.array_equal(b.state_of[b.cells[:, 0], b.cells[:, 1], b.cells[:, 2]],
                          np.arange(b.n_states))  # fmt: skip
    assert b.next_state[:, D].max() < b.n_states


def test_a_connection_of_more_stops_than_floors_is_refused_as_it_is_read(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(floors_module, "MAX_FLOORS", 3)
    many = changed("-1:1,4 0:1,4", "-1:1,4 0:1,4 1:1,4 2:1,4 3:1,4")
    assert "line 5, column 41: more than 3 stops: one a floor at most" in str(refusal(many))


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), kind=st.sampled_from(["maze", "building"]),
       header=st.booleans())  # fmt: skip
def test_load_map_writes_one_floor_maps_back_byte_for_byte(
    seed: int, kind: str, header: bool
) -> None:
    rng = np.random.default_rng(seed)
    make = generate_maze if kind == "maze" else generate_building
    rows = make(21, 25, rng, n_goals=3)
    grid = GridDomain.from_strings(rows)
    if header:
        names = [NamedCell(r, c, f"Room {i}") for i, (r, c) in enumerate(grid.goal_cells[:2])]
        grid = GridDomain.from_strings(rows, frame=Frame(0.25, (1.0, -2.5, 0.1)), names=names)
    text = grid.to_text() + "\n"
    again = load_map(text)
    assert isinstance(again, GridDomain) and again.to_text() + "\n" == text
