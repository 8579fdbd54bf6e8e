"""PUT /domains/{name} takes a map file as the project writes it (``maze import``, ``maze
generate``): as a text/plain body, or as the ``text`` of a JSON body; its header lines give the
resolution and origin, and a bad file is refused with ``maze check``'s words, naming the line
and column of the file."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from app.domain.grid import Frame, GridDomain, MapError
from app.service.config import Settings
from app.service.main import create_app
from tests.service.conftest import TINY

#: TINY as `maze import` writes a ROS map's: the resolution and origin first
FRAME = Frame(0.5, (-12.0, 4.5, 0.0))
FILE = GridDomain.from_strings(TINY, frame=FRAME).to_text() + "\n"
TEXT = {"Content-Type": "text/plain"}


def maze_check(text: str) -> str:
    """What `maze check` says of a map file's text (after "error: PATH: ")."""
    with pytest.raises(MapError) as refused:
        GridDomain.from_text(text)
    return str(refused.value)


def test_a_map_file_with_its_header_is_put_as_it_is(
    client: TestClient, admin: dict[str, str]
) -> None:
    assert FILE.startswith("resolution: 0.5\norigin: -12.0 4.5 0.0\n#######")
    r = client.put("/domains/lobby", content=FILE, headers=admin | TEXT)
    assert r.status_code == 201, r.text
    body = r.json()
    assert body["map"] == TINY and body["resolution"] == 0.5
    assert body["origin"] == [-12.0, 4.5, 0.0] and body["trajectories"] == 0
    # the same file again, with a charset: the same map (200, kept)
    again = client.put("/domains/lobby", content=FILE.encode(),
                       headers=admin | {"Content-Type": "text/plain; charset=utf-8"})  # fmt: skip
    assert again.status_code == 200 and again.json()["created_at"] == body["created_at"]
    # metres work: the centre of the start cell [5, 1]
    x, y = FRAME.centre(5, 1, len(TINY))
    created = client.post("/domains/lobby/sessions", json={"start": [5, 1]}).json()
    auth = {"Authorization": f"Bearer {created['token']}"}
    moved = client.post(f"/sessions/{created['session_id']}/positions",
                        json={"positions": [[x + 0.5, y]]}, headers=auth)  # fmt: skip
    assert moved.status_code == 200 and moved.json()[-1]["state"] == [5, 2]


def test_a_map_file_without_a_header_and_with_experts_from_the_query(
    client: TestClient, admin: dict[str, str]
) -> None:
    query = "?experts=anywhere&per_goal=3&seed=7&alpha0=0.5"
    r = client.put("/domains/plain" + query, content="\r\n".join(TINY), headers=admin | TEXT)
    assert r.status_code == 201, r.text
    body = r.json()
    assert body["resolution"] is None and body["alpha0"] == 0.5
    assert body["trajectories"] == 3 * 2  # per goal, two goals
    # the same as the JSON body's experts
    same = {"map": TINY, "alpha0": 0.5, "experts": {"source": "anywhere", "per_goal": 3, "seed": 7}}
    json_put = client.put("/domains/plain-json", json=same, headers=admin).json()
    prior = client.get("/domains/plain/prior").json()["theta"]
    assert prior == client.get("/domains/plain-json/prior").json()["theta"]
    assert json_put["trajectories"] == body["trajectories"]


def test_the_text_field_of_a_json_body_is_the_file(
    client: TestClient, admin: dict[str, str]
) -> None:
    r = client.put("/domains/lobby", json={"text": FILE, "alpha0": 2.0}, headers=admin)
    assert r.status_code == 201, r.text
    assert r.json()["resolution"] == 0.5 and r.json()["alpha0"] == 2.0
    both = client.put("/domains/lobby", json={"text": FILE, "map": TINY}, headers=admin)
    assert both.status_code == 422 and "one of them" in both.json()["detail"]
    neither = client.put("/domains/lobby", json={"alpha0": 2.0}, headers=admin)
    assert neither.status_code == 422 and "one of them" in neither.json()["detail"]
    frame = client.put("/domains/lobby", json={"text": FILE, "resolution": 1.0}, headers=admin)
    assert frame.status_code == 422 and "header lines" in frame.json()["detail"]


@pytest.mark.parametrize(
    "text",
    [
        FILE.replace("#G..#G#", "#G..xG#"),  # line 4 of the file (two header lines)
        FILE.replace("#.#.#.#", "#.#.#."),  # ragged
        FILE.replace("resolution: 0.5", "resolution: half"),  # a header line
        FILE.replace("origin:", "orgin:"),  # an unknown header
        "\n".join(TINY).replace("S", "."),  # no start
        "",
    ],
)
def test_a_bad_map_file_is_refused_as_maze_check_says(
    client: TestClient, admin: dict[str, str], text: str
) -> None:
    for body in ({"content": text, "headers": admin | TEXT},
                 {"json": {"text": text}, "headers": admin}):  # fmt: skip
        r = client.put("/domains/lobby", **body)
        assert r.status_code == 422, r.text
        assert r.json()["detail"] == f"map: {maze_check(text)}"
    assert "lobby" not in [d["name"] for d in client.get("/domains").json()]


def test_the_first_refusal_names_the_files_line_and_column(
    client: TestClient, admin: dict[str, str]
) -> None:
    r = client.put("/domains/lobby", content=FILE.replace("#G..#G#", "#G..xG#"),
                   headers=admin | TEXT)  # fmt: skip
    assert r.json()["detail"] == (
        "map: line 4, column 5: unknown character 'x': use '#' wall, '.' free, 'S' start, 'G' goal"
    )


def test_what_a_text_put_refuses_it_says(client: TestClient, admin: dict[str, str]) -> None:
    cases = [
        ("?per_goal=3", FILE, "per_goal and seed go with experts"),
        ("?experts=everywhere", FILE, "query.experts"),
        ("?alpha0=0", FILE, "query.alpha0"),
        ("", '{"map": ["S.G"]}', "this text/plain body is JSON"),
    ]
    for query, text, said in cases:
        r = client.put("/domains/lobby" + query, content=text, headers=admin | TEXT)
        assert r.status_code == 422 and said in r.json()["detail"], (query, r.text)
    latin = client.put("/domains/lobby", content="S.G\xe9".encode("latin-1"),
                       headers=admin | TEXT)  # fmt: skip
    assert latin.status_code == 422 and "not UTF-8 text" in latin.json()["detail"]
    # options in the query go with a text body only
    r = client.put("/domains/lobby?alpha0=2", json={"map": TINY}, headers=admin)
    assert r.status_code == 422 and "only go with a text/plain body" in r.json()["detail"]
    # a map file sent with no Content-Type is read as JSON, and the answer says how to send it
    r = client.put("/domains/lobby", content=FILE, headers=admin)
    assert r.status_code == 422 and "Content-Type: text/plain" in r.json()["detail"]
    r = client.put("/domains/lobby", content=b"", headers=admin)
    assert r.status_code == 422 and "no body" in r.json()["detail"]


def test_a_form_is_refused_saying_what_curl_d_sent_and_how_to_send_it(
    client: TestClient, admin: dict[str, str]
) -> None:
    form = {"Content-Type": "application/x-www-form-urlencoded"}
    r = client.post("/domains/default/sessions", content=b'{"kappa": 0.5}', headers=form)
    assert r.status_code == 415
    detail = r.json()["detail"]
    assert "curl -d" in detail and "-H 'Content-Type: application/json'" in detail
    r = client.put("/domains/lobby", content=FILE, headers=admin | form)
    assert r.status_code == 415 and "--data-binary @MAP.txt" in r.json()["detail"]
    # text/plain elsewhere: still JSON only
    r = client.post("/domains/default/sessions", content=b"{}", headers=TEXT)
    assert r.status_code == 415 and "text/plain" not in r.json()["detail"]


NAMED = "destination: 1 5 Café (east)\n" + "\n".join(TINY) + "\n"


def test_a_map_file_s_destination_lines_name_its_goals(
    client: TestClient, admin: dict[str, str]
) -> None:
    r = client.put("/domains/named", content=NAMED.encode(), headers=admin | TEXT)
    assert r.status_code == 201, r.text
    body = r.json()
    assert body["goals"] == [[1, 1], [1, 5]] and body["goal_names"] == [None, "Café (east)"]
    assert client.get("/domains/named").json()["goal_names"] == [None, "Café (east)"]
    listed = {d["name"]: d for d in client.get("/domains").json()}
    assert listed["named"]["goal_names"] == [None, "Café (east)"]
    # a map without names: one null per goal, nothing invented
    plain = client.put("/domains/plain", json={"map": TINY}, headers=admin).json()
    assert plain["goal_names"] == [None, None]


def test_names_change_with_the_same_map_and_its_data_stays(
    client: TestClient, admin: dict[str, str]
) -> None:
    first = {"map": TINY, "experts": {"per_goal": 2}}
    assert client.put("/domains/named", json=first, headers=admin).status_code == 201
    body = {"map": TINY, "destinations": [{"cell": [1, 1], "name": "Lobby"},
                                          {"cell": [1, 5], "name": "Exit"}]}  # fmt: skip
    again = client.put("/domains/named", json=body, headers=admin)
    assert again.status_code == 200, again.text
    assert again.json()["goal_names"] == ["Lobby", "Exit"]
    assert again.json()["trajectories"] == 4  # the same map keeps its trajectories


def test_names_are_kept_over_a_restart(settings: Settings) -> None:
    with TestClient(create_app(settings)) as c:
        admin = {"X-API-Key": c.app.state.service.admin_key}  # type: ignore[attr-defined]
        assert c.put("/domains/named", content=NAMED, headers=admin | TEXT).status_code == 201
    with TestClient(create_app(settings)) as c:
        assert c.get("/domains/named").json()["goal_names"] == [None, "Café (east)"]


@pytest.mark.parametrize(
    ("destinations", "words"),
    [
        ([{"cell": [1, 2], "name": "Hall"}], "destinations[0]: cell [1, 2] is a free cell"),
        ([{"cell": [1, 1], "name": "A"}, {"cell": [1, 5], "name": "a"}],
         "destinations[1]: the name 'a' is given twice (destinations[0] names it first)"),
        ([{"cell": [1, 1], "name": "<script>"}], "destinations[0]: the name '<script>' holds '<'"),
        ([{"cell": [1, 1], "name": "x" * 41}], "41 characters long"),
        ([{"cell": [1, 1], "name": " "}], "destinations[0]: a destination's name is missing"),
        ([{"cell": [99, 1], "name": "Far"}], "cell [99, 1] is off the 7x7 map"),
    ],
)  # fmt: skip
def test_a_bad_destination_in_a_json_body_is_refused_naming_it(
    client: TestClient, admin: dict[str, str], destinations: list[object], words: str
) -> None:
    r = client.put("/domains/named", json={"map": TINY, "destinations": destinations},
                   headers=admin)  # fmt: skip
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    assert detail.startswith("map: destinations[") and words in detail
    assert client.get("/domains/named").status_code == 404  # nothing was made


def test_a_bad_destination_line_is_refused_as_maze_check_says(
    client: TestClient, admin: dict[str, str]
) -> None:
    bad = "destination: 1 5 Exit\ndestination: 2 1 Hall\n" + "\n".join(TINY)
    r = client.put("/domains/named", content=bad, headers=admin | TEXT)
    assert r.status_code == 422, r.text
    assert r.json()["detail"] == f"map: {maze_check(bad)}"
    assert r.json()["detail"].startswith("map: line 2, column 14: cell [2, 1] is a free cell")
    # with text, the names are its lines, not a field
    both = {"text": NAMED, "destinations": [{"cell": [1, 1], "name": "Lobby"}]}
    r = client.put("/domains/named", json=both, headers=admin)
    assert r.status_code == 422 and "destination: ROW COL NAME" in r.json()["detail"]


def test_names_of_the_same_map_are_checked_as_a_new_map_s(
    client: TestClient, admin: dict[str, str]
) -> None:
    """The same rows put again are not read again (the grid is shared), but their names are
    checked all the same; a refused put changes nothing."""
    named = {"map": TINY, "destinations": [{"cell": [1, 5], "name": "Exit"}]}
    assert client.put("/domains/same", json=named, headers=admin).status_code == 201
    bad = {"map": TINY, "destinations": [{"cell": [5, 1], "name": "Start"}]}
    r = client.put("/domains/same", json=bad, headers=admin)
    assert r.status_code == 422 and "cell [5, 1] is the start" in r.json()["detail"]
    assert client.get("/domains/same").json()["goal_names"] == [None, "Exit"]
    renamed = {"map": TINY, "destinations": [{"cell": [1, 1], "name": "Lobby"}]}
    assert client.put("/domains/same", json=renamed, headers=admin).json()["goal_names"] == [
        "Lobby", None,
    ]  # fmt: skip


#: a map of two floors
FLOORS = (
    "connection: lift 4 0:1,1 1:1,1 Lift 1\n"
    "floor: 0 Ground floor\n#####\n#.S.#\n#####\n"
    "floor: 1 First floor\n#####\n#..G#\n#####\n"
)


def test_a_map_of_several_floors_is_read_checked_and_served(
    client: TestClient, admin: dict[str, str]
) -> None:
    for body in ({"content": FLOORS, "headers": admin | TEXT},
                 {"json": {"text": FLOORS}, "headers": admin}):  # fmt: skip
        r = client.put("/domains/tower", **body)
        assert r.status_code in (200, 201), r.text
        got = r.json()
        assert got["actions"] == ["N", "E", "S", "W", "U", "D"]
        assert got["start"] == [0, 1, 2] and got["goals"] == [[1, 1, 3]]
        assert [f["name"] for f in got["floors"]] == ["Ground floor", "First floor"]
        assert got["connections"] == [
            {"kind": "lift", "name": "Lift 1", "cost": 4, "stops": [[0, 1, 1], [1, 1, 1]]}
        ]
        assert got["map"] == ["#####", "#.S.#", "#####"]  # the lowest floor's rows
    # a mistake in it is named as `maze check` names it: floor, line, column
    bad = client.put("/domains/tower2", content=FLOORS.replace("#..G#", "#..Gx"),
                     headers=admin | TEXT)  # fmt: skip
    assert bad.status_code == 422
    assert bad.json()["detail"] == (
        "map: floor 1 'First floor', line 8, column 5: unknown character 'x': use '#' wall, '.' "
        "free, 'S' start, 'G' goal"
    )
    wall = client.put("/domains/tower2", content=FLOORS.replace("1:1,1", "1:0,1"),
                      headers=admin | TEXT)  # fmt: skip
    assert wall.status_code == 422
    assert wall.json()["detail"].startswith(
        "map: line 1, column 26: connection 'Lift 1': stop [0, 1] on floor 1 'First floor' is a "
        "wall"
    )
    assert "tower2" not in [d["name"] for d in client.get("/domains").json()]


def test_a_map_of_several_floors_past_the_cells_limit_is_refused_before_its_check(
    settings: Settings,
) -> None:
    small = settings.model_copy(update={"max_map_cells": 20})
    with TestClient(create_app(small)) as c:
        admin = {"X-API-Key": c.app.state.service.admin_key}  # type: ignore[attr-defined]
        r = c.put("/domains/tower", content=FLOORS, headers=admin | TEXT)
        assert r.status_code == 422
        assert r.json()["detail"] == (
            "map: 2 floors of 30 cells in all: this service takes maps of at most 20 cells "
            "(ADVISOR_MAX_MAP_CELLS)"
        )
