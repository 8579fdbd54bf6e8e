"""Destinations have names: a map file's ``destination: ROW COL NAME`` header lines, checked
with the map (each error naming its line and column), kept in the order of the goals, and
written back by ``to_text``."""

from __future__ import annotations

import pytest

from app.domain.generate import generate_building_domain
from app.domain.grid import (
    NAME_MAX,
    Frame,
    GridDomain,
    MapError,
    NamedCell,
    check_name,
    plain_names,
)

ROWS = ["#######", "#G..#G#", "#.#.#.#", "#S....#", "#######"]  # goals [1, 1] and [1, 5]


def text(*header: str) -> str:
    return "\n".join([*header, *ROWS])


def refusal(map_text: str) -> MapError:
    with pytest.raises(MapError) as refused:
        GridDomain.from_text(map_text)
    return refused.value


def test_names_are_kept_in_the_order_of_the_goals() -> None:
    grid = GridDomain.from_text(text("destination: 1 5 Café (east)", "destination: 1 1 Lobby"))
    assert grid.goal_cells == [(1, 1), (1, 5)]
    assert grid.goal_names == ("Lobby", "Café (east)")
    assert [grid.goal_label(i) for i in range(2)] == ["Lobby", "Café (east)"]


def test_a_map_may_name_some_destinations_or_none() -> None:
    some = GridDomain.from_text(text("destination: 1 5   Room 12-B  "))
    assert some.goal_names == (None, "Room 12-B")  # spaces around a name are not part of it
    assert [some.goal_label(i) for i in range(2)] == ["G0", "Room 12-B"]
    none = GridDomain.from_text(text())
    assert none.goal_names is None and none.goal_label(1) == "G1"
    assert none.to_text() == "\n".join(ROWS)  # no header invented


def test_to_text_writes_the_names_after_the_frame_and_reads_back() -> None:
    grid = GridDomain.from_strings(
        ROWS, frame=Frame(0.5, (1.0, 2.0, 0.0)), names=[NamedCell(1, 5, "Exit")]
    )
    written = grid.to_text()
    assert written.splitlines()[:3] == [
        "resolution: 0.5", "origin: 1.0 2.0 0.0", "destination: 1 5 Exit",
    ]  # fmt: skip
    again = GridDomain.from_text(written)
    assert again.goal_names == (None, "Exit") and again.frame == grid.frame
    assert again.rows_text == grid.rows_text


@pytest.mark.parametrize(
    ("header", "where", "words"),
    [
        ("destination: 3 1 Start", "line 1, column 14", "cell [3, 1] is the start"),
        ("destination: 1 2 Hall", "line 1, column 14", "cell [1, 2] is a free cell"),
        ("destination: 0 0 Hall", "line 1, column 14", "cell [0, 0] is a wall"),
        ("destination: 9 1 Hall", "line 1, column 14", "cell [9, 1] is off the 5x7 map"),
        ("destination: 1 x Hall", "line 1, column 16", "'x' is not a row or column number"),
        ("destination: -1 1 Hall", "line 1, column 14", "'-1' is not a row or column number"),
        ("destination: 1 1", "line 1, column 17", "needs a row, a column and a name"),
        ("destination: 1 1 <b>Hall", "line 1, column 18", "holds '<'"),
        ("destination: 1 1 *Hall", "line 1, column 18", "holds '*'"),
        ("destination: 1 1 -Hall", "line 1, column 18", "starts with '-'"),
        ("destination: 1 1 " + "x" * (NAME_MAX + 1), "line 1, column 18", "41 characters"),
    ],
)
def test_a_bad_destination_line_is_refused_naming_line_and_column(
    header: str, where: str, words: str
) -> None:
    error = refusal(text("resolution: 1", header))  # the second line of the text
    assert str(error).startswith(where.replace("line 1", "line 2") + ": ")
    assert words in str(error)


def test_a_cell_or_a_name_given_twice_is_refused() -> None:
    twice = refusal(text("destination: 1 1 Lobby", "destination: 1 1 Hall"))
    assert str(twice).startswith("line 2, column 14: cell [1, 1] is named twice")
    assert "line 1 names it first" in str(twice)
    same = refusal(text("destination: 1 1 Lobby", "destination: 1 5 LOBBY"))
    assert str(same).startswith("line 2, column 18: the name 'LOBBY' is given twice")


def test_an_error_in_the_rows_still_counts_the_header_lines() -> None:
    error = refusal("destination: 1 1 Lobby\n" + "\n".join([*ROWS[:2], "#.#x#.#", *ROWS[3:]]))
    assert (error.line, error.column) == (4, 4)


def test_names_given_as_cells_say_which_one_is_wrong() -> None:
    with pytest.raises(MapError, match=r"^destinations\[1\]: cell \[2, 1\] is a free cell"):
        GridDomain.from_strings(
            ROWS, names=[NamedCell(1, 1, "A", label="destinations[0]"),
                         NamedCell(2, 1, "B", label="destinations[1]")],
        )  # fmt: skip


@pytest.mark.parametrize("seed", range(4))
def test_every_destination_of_a_generated_building_can_be_named(seed: int) -> None:
    grid = generate_building_domain(48, 40, seed)
    names = [NamedCell(r, c, f"Room {i}") for i, (r, c) in enumerate(grid.goal_cells)][::-1]
    named = GridDomain.from_strings(list(grid.rows_text), names=names)
    assert named.goal_names == tuple(f"Room {i}" for i in range(len(grid.goals)))
    assert GridDomain.from_text(named.to_text()).goal_names == named.goal_names


def test_names_from_elsewhere_are_made_plain_and_each_its_own() -> None:
    """An imported venue's names: characters a name may not hold become spaces, a name too
    long is cut, one given twice is numbered, one left empty is no name; each change noted."""
    given = [
        ((1, 1), "Café: <Level 2>"), ((1, 2), "Restroom"), ((1, 3), "restroom"),
        ((1, 4), "*** "), ((1, 5), "A" * 60), ((1, 6), "Exit"),
    ]  # fmt: skip
    named, notes = plain_names(given)
    assert [(n.row, n.col, n.name) for n in named] == [
        (1, 1, "Café Level 2"), (1, 2, "Restroom"), (1, 3, "restroom 2"), (1, 5, "A" * NAME_MAX),
        (1, 6, "Exit"),
    ]  # fmt: skip
    assert all(check_name(n) == n.name for n in named)  # every one a name a map may hold
    assert len(notes) == 4  # Exit and Restroom as they were
    assert notes[2].startswith("destination [1, 4] '*** ' written without a name")
