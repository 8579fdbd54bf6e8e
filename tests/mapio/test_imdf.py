"""Reading an IMDF archive (the sample hospital) into a venue: levels, walls and doors,
connections between levels, named destinations, positions snapped to cells."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.mapio.imdf import read_imdf
from app.mapio.imdf.sample import CORRIDOR, WIDTH, fid, plan, to_lonlat
from app.mapio.venue import Venue
from tests.mapio.imdf_helpers import (
    box_cells,
    docs,
    drop,
    features,
    reachable,
    unit_id,
    write,
)

ROOMS = {(r.ordinal, r.key): r for r in plan()}
CORRIDOR_BOX = (0.0, CORRIDOR[0], WIDTH, CORRIDOR[1])


@pytest.fixture(scope="module")
def venue(tmp_path_factory: pytest.TempPathFactory) -> Venue:
    return read_imdf(write(tmp_path_factory.mktemp("imdf")), 0.5)


def corridor_cell(v: Venue) -> tuple[int, int]:
    first: tuple[int, int] = min(box_cells(v, CORRIDOR_BOX, shrink=1.0))
    return first


def room_cells(v: Venue, ordinal: int, key: str, shrink: float = 0.0) -> set[tuple[int, int]]:
    return box_cells(v, ROOMS[(ordinal, key)].box, shrink)


@pytest.mark.parametrize("zipped", [True, False], ids=["zip", "folder"])
def test_imdf_levels_by_ordinal_with_names_and_elevations(tmp_path: Path, zipped: bool) -> None:
    v = read_imdf(write(tmp_path, zipped=zipped), 0.5, storey_height=3.5)
    assert v.name == "Example Hospital"
    assert v.ordinals == (0, 1, 2)
    assert [(lv.name, lv.short_name) for lv in v.levels] == [
        ("Ground floor", "G"),
        ("First floor", "1"),
        ("Second floor", "2"),
    ]
    assert [lv.elevation for lv in v.levels] == [0.0, 3.5, 7.0]
    assert all(lv.free.shape == v.shape for lv in v.levels)
    # 40 x 20 m at 0.5 m, with a margin: the same grid on every level
    assert v.shape[0] >= 40 and v.shape[1] >= 80 and v.frame.resolution == 0.5


def test_imdf_rooms_are_walled_and_entered_only_through_their_door(venue: Venue) -> None:
    free = venue.level(0).free
    inside = room_cells(venue, 0, "radiology", shrink=0.5)  # one cell in from its walls
    assert all(free[c] for c in inside)
    whole = room_cells(venue, 0, "radiology")
    rim = whole - inside
    # its side on the corridor is wall but for the 1.2 m door (two cells at 0.5 m)
    corridor_side = {c for c in rim if c[0] == min(r for r, _ in whole)}
    assert sum(free[c] for c in corridor_side) == 2
    walk = reachable(free, corridor_cell(venue))
    assert inside <= walk
    # the store has no opening: free inside, reached from nowhere
    store = room_cells(venue, 0, "store", shrink=0.5)
    assert store and all(free[c] for c in store) and not store & walk
    assert any("Store (level 0)" in n and "no opening" in n for n in venue.notes)


def test_imdf_a_room_without_its_door_is_not_reached(tmp_path: Path) -> None:
    d = docs()
    drop(d, "opening", fid("opening", "0/radiology"))
    d["relationship.geojson"]["features"] = [
        f for f in features(d, "relationship") if f["id"] != fid("relationship", "radiology")
    ]
    v = read_imdf(write(tmp_path, d), 0.5)
    walk = reachable(v.level(0).free, corridor_cell(v))
    assert not room_cells(v, 0, "radiology", shrink=0.5) & walk
    assert room_cells(v, 0, "emergency", shrink=0.5) <= walk


def test_imdf_walls_between_rooms_and_none_between_open_units(venue: Venue) -> None:
    free = venue.level(0).free
    radiology = room_cells(venue, 0, "radiology")
    emergency = room_cells(venue, 0, "emergency")
    # two rooms side by side: each keeps a wall on the shared side (two cells thick)
    east = max(c for _, c in radiology)
    west = min(c for _, c in emergency)
    assert west == east + 1
    assert not any(free[r, c] for r, c in radiology | emergency if c in (east, west))
    # the corridor is two walkway units: no wall where they meet; the lobby is open to it
    corridor = box_cells(venue, CORRIDOR_BOX)
    assert all(free[c] for c in corridor)
    lobby = room_cells(venue, 0, "entrance")
    assert all(free[c] for c in lobby if c[0] == min(r for r, _ in lobby))


def stop_cells(venue: Venue, name: str, ordinal: int) -> set[tuple[int, int]]:
    c = next(c for c in venue.connections if c.name == name)
    stop = next(s for s in c.stops if s.ordinal == ordinal)
    return {tuple(x) for x in stop.cells.tolist()}


def test_imdf_connections_join_the_right_cells_of_each_level(venue: Venue) -> None:
    kinds = {c.name: (c.kind, c.ordinals, c.source) for c in venue.connections}
    assert kinds == {
        "Lift 1": ("elevator", (0, 1, 2), "stacked units and relationships"),
        "Stairs A": ("stairs", (0, 1, 2), "stacked units"),
        "Escalator": ("escalator", (0, 1), "relationships"),
    }
    for o in (0, 1, 2):
        free = venue.level(o).free
        for name, key in (("Lift 1", "lift"), ("Stairs A", "stairs")):
            want = {c for c in room_cells(venue, o, key) if free[c]}
            assert stop_cells(venue, name, o) == want and want
            assert stop_cells(venue, name, o) & reachable(free, corridor_cell(venue))
    # the escalator: the ground floor's south-east unit, the first floor's one west of it
    assert stop_cells(venue, "Escalator", 0) == room_cells(venue, 0, "escalator")
    assert stop_cells(venue, "Escalator", 1) == room_cells(venue, 1, "escalator")
    assert not room_cells(venue, 0, "escalator") & room_cells(venue, 1, "escalator")


def test_imdf_connections_without_relationships(tmp_path: Path) -> None:
    d = docs()
    d["relationship.geojson"]["features"] = []
    v = read_imdf(write(tmp_path, d), 0.5)
    kinds = {c.name: (c.kind, c.ordinals, c.source) for c in v.connections}
    # the lift and stairs are stacked; the escalator's units do not overlap: no connection
    assert kinds == {
        "Lift 1": ("elevator", (0, 1, 2), "stacked units"),
        "Stairs A": ("stairs", (0, 1, 2), "stacked units"),
    }


def test_imdf_destinations_are_named_free_cells_of_their_rooms(venue: Venue) -> None:
    got = {(d.name, d.ordinal): d for d in venue.destinations}
    tenants = {(r.tenant[0], r.ordinal): r.key for r in ROOMS.values() if r.tenant is not None}
    named = {(r.name, r.ordinal): r.key for r in ROOMS.values() if r.name}
    assert set(tenants) <= set(got)
    for (name, ordinal), key in tenants.items():
        d = got[(name, ordinal)]
        assert venue.level(ordinal).free[d.cell]
        assert d.cell in room_cells(venue, ordinal, key)
        assert d.source == ROOMS[(ordinal, key)].tenant[2]  # type: ignore[index]
    # named rooms with nobody in them are destinations by their name; passages are not
    for name in ("Registration", "Room 1.02", "Waiting area", "Chapel", "Store"):
        ordinal = next(o for (n, o) in named if n == name)
        assert got[(name, ordinal)].source == "unit"
        assert got[(name, ordinal)].cell in room_cells(venue, ordinal, named[(name, ordinal)])
    assert not {n for n, _ in got} & {"Lift 1", "Stairs A", "Escalator", "Main entrance"}
    assert len(venue.destinations) == len(tenants) + 5


def test_imdf_a_destinations_position_snaps_to_its_cell(venue: Venue) -> None:
    anchors = {a["id"]: a for a in features(docs(), "anchor")}
    for occupant in features(docs(), "occupant"):
        anchor = anchors[occupant["properties"]["anchor_id"]]
        lon, lat = anchor["geometry"]["coordinates"]
        d = next(d for d in venue.destinations if d.feature == occupant["id"])
        assert venue.cell_of(lon, lat) == d.cell
        assert venue.cell_at(*venue.projection.to_xy(lon, lat)) == d.cell


@settings(max_examples=100, deadline=None)
@given(st.data())
def test_imdf_positions_in_metres_snap_to_the_cell_holding_them(
    venue: Venue, data: st.DataObject
) -> None:
    rows, cols = venue.shape
    r = data.draw(st.integers(0, rows - 1))
    c = data.draw(st.integers(0, cols - 1))
    du, dv = data.draw(st.floats(-0.49, 0.49)), data.draw(st.floats(-0.49, 0.49))
    x, y = venue.frame.centre(r, c, rows)
    x, y = x + du * venue.frame.resolution, y + dv * venue.frame.resolution
    assert venue.cell_at(x, y) == (r, c)
    assert venue.cell_of(*venue.projection.to_lonlat(x, y)) == (r, c)


def test_imdf_a_coarser_resolution_keeps_the_plan(tmp_path: Path) -> None:
    v = read_imdf(write(tmp_path), 1.0)
    assert v.frame.resolution == 1.0
    free = v.level(1).free
    walk = reachable(free, corridor_cell(v))
    d = next(d for d in v.destinations if d.name == "Cardiology")
    assert d.cell in walk
    # the lift (4 m: four cells, two inside its walls) still has free cells on every level
    assert [c.name for c in v.connections] == ["Lift 1", "Stairs A", "Escalator"]


def test_imdf_levels_of_one_ordinal_are_one_level_and_names_follow_the_language(
    tmp_path: Path,
) -> None:
    d = docs()
    d["manifest.json"]["language"] = "fr-FR"
    ground = next(f for f in features(d, "level") if f["properties"]["ordinal"] == 0)
    annex = {**ground, "id": "annex-ground", "properties": dict(ground["properties"])}
    annex["properties"]["name"] = {"en": "Annex ground", "fr": "Annexe rez"}
    ground["properties"]["name"] = {"en": "Ground floor", "fr": "Rez-de-chaussée"}
    features(d, "level").append(annex)
    v = read_imdf(write(tmp_path, d), 0.5)
    assert v.level(0).name == "Rez-de-chaussée / Annexe rez"
    assert v.level(0).ids == (fid("level", 0), "annex-ground")
    assert v.level(1).name == "First floor"  # no French: English


def test_imdf_names_are_cleaned_and_cut(tmp_path: Path) -> None:
    d = docs()
    occupant = features(d, "occupant")[0]
    occupant["properties"]["name"] = {"en": "Cardio\x1b[31mlogy\n" + "x" * 200}
    v = read_imdf(write(tmp_path, d), 0.5)
    name = next(x.name for x in v.destinations if x.feature == occupant["id"])
    assert "\x1b" not in name and "\n" not in name and len(name) == 80
    assert name.startswith("Cardio [31mlogy x") and name.endswith("...")


def test_imdf_unit_ids_are_those_of_the_plan() -> None:
    units = {f["id"] for f in features(docs(), "unit")}
    assert unit_id(0, "radiology") in units and len(units) == len(ROOMS)


def test_imdf_a_relationship_between_openings_joins_their_doors(tmp_path: Path) -> None:
    d = docs()
    features(d, "relationship").append(
        {
            "id": "stairs-doors",
            "type": "Feature",
            "feature_type": "relationship",
            "geometry": None,
            "properties": {
                "category": "stairs",
                "direction": "undirected",
                "origin": {"id": fid("opening", "0/stairs"), "feature_type": "opening"},
                "intermediary": None,
                "destination": {"id": fid("opening", "1/stairs"), "feature_type": "opening"},
            },
        }
    )
    v = read_imdf(write(tmp_path, d), 0.5)
    doors = next(c for c in v.connections if c.name == "stairs 2")
    assert (doors.kind, doors.ordinals, doors.source) == ("stairs", (0, 1), "relationships")
    for stop in doors.stops:
        cells = {tuple(x) for x in stop.cells.tolist()}
        # the 1.2 m door at 0.5 m: two cells wide, a cell each side of the line
        assert len(cells) == 4 and all(v.level(stop.ordinal).free[c] for c in cells)
        rows = {r for r, _ in cells}
        stairs = room_cells(v, stop.ordinal, "stairs")
        assert len(rows) == 2 and len(cells & stairs) == 2


def test_imdf_units_too_small_for_a_cell_are_noted_and_not_destinations(tmp_path: Path) -> None:
    d = docs()
    closet = dict(features(d, "unit")[0])
    corners = ((41.3, 5.3), (41.45, 5.3), (41.45, 5.45), (41.3, 5.45), (41.3, 5.3))
    box = [to_lonlat(x, y) for x, y in corners]  # no cell centre (at .25 and .75 m) inside
    closet["id"] = "closet"
    closet["geometry"] = {"type": "Polygon", "coordinates": [box]}
    closet["properties"] = closet["properties"] | {"category": "room", "name": {"en": "Closet"}}
    features(d, "unit").append(closet)
    v = read_imdf(write(tmp_path, d), 0.5)
    assert any("hold no free cell at 0.5 m" in n and "Closet" in n for n in v.notes)
    assert any("left out" in n and "Closet" in n for n in v.notes)
    assert "Closet" not in {x.name for x in v.destinations}
