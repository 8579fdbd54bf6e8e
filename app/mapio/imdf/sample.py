"""A small hospital written as an IMDF archive: the tests' fixture, and an example to import.

Three levels (ordinals 0, 1, 2) of a 40 x 20 m building, the same plan on each: a corridor
4 m wide along the middle (two walkway units), a row of 8 x 8 m rooms on each side, each with a
1.2 m door onto the corridor; on the north side a lift (``Lift 1``, 4 x 4 m, its door on the
corridor), a plant shaft above it (structure) and a stairwell (``Stairs A``, 4 x 8 m, a door).
On the ground floor the main entrance is a lobby open to the corridor, and a store has no door.
Departments are occupants anchored in their rooms (Radiology, Cardiology, ...), the information
desk and the first floor's restrooms are amenities, a few rooms are named units. The lift is a
relationship (origin ground floor, intermediary first, destination second), the stairs are
only stacked, and an escalator joins the ground floor's south-east corner to the first floor's
room west of it by a relationship only. Positions are metres east and north of the venue's
display point, written as longitude and latitude with
:class:`~app.mapio.venue.LocalProjection`.

``python -m app.mapio.imdf.sample hospital.zip`` (or a folder name) writes it.
"""

from __future__ import annotations

import json
import sys
import uuid
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from app.mapio.venue import LocalProjection

#: the venue's display point (a made-up hospital in London)
LON0, LAT0 = -0.1340, 51.5246
WIDTH, DEPTH = 40.0, 20.0
#: the corridor's south and north edges, metres north of the building's south wall
CORRIDOR = (8.0, 12.0)
DOOR = 1.2

_NS = uuid.UUID("6c1f0a52-3b7e-4d0c-9a57-0b6f3c1d2e4f")


@dataclass(frozen=True)
class Room:
    """A unit of the plan: its level, category, name (may be empty), its rectangle in metres
    (west, south, east, north, from the building's south-west corner), whether it has a door
    onto the corridor, and the occupant or amenity in it (name, category, kind)."""

    ordinal: int
    key: str
    category: str
    name: str
    box: tuple[float, float, float, float]
    door: bool = True
    tenant: tuple[str, str, str] | None = None  # (name, category, "occupant" | "amenity")


def _row(ordinal: int, south: bool, rooms: list[tuple[str, str, str, Any]]) -> list[Room]:
    y0, y1 = (0.0, CORRIDOR[0]) if south else (CORRIDOR[1], DEPTH)
    out = []
    for k, (key, category, name, tenant) in enumerate(rooms):
        x0 = [0.0, 8.0, 16.0, 24.0, 32.0][k] if south else [0.0, 8.0, 24.0, 32.0][k]
        x1 = x0 + 8.0
        door = category not in ("lobby", "escalator") and key != "store"
        out.append(Room(ordinal, key, category, name, (x0, y0, x1, y1), door, tenant))
    return out


def plan() -> list[Room]:
    """Every unit of the hospital."""
    rooms: list[Room] = []
    for o in (0, 1, 2):
        rooms += [
            Room(o, "corridor-w", "walkway", "", (0.0, CORRIDOR[0], 20.0, CORRIDOR[1]), False),
            Room(o, "corridor-e", "walkway", "", (20.0, CORRIDOR[0], WIDTH, CORRIDOR[1]), False),
            Room(o, "lift", "elevator", "Lift 1", (16.0, 12.0, 20.0, 16.0)),
            Room(o, "shaft", "structure", "", (16.0, 16.0, 20.0, DEPTH), False),
            Room(o, "stairs", "stairs", "Stairs A", (20.0, 12.0, 24.0, DEPTH)),
        ]
    occ, am = "occupant", "amenity"
    rooms += _row(
        0,
        True,
        [
            ("entrance", "lobby", "Main entrance", ("Information", "information", am)),
            ("radiology", "room", "", ("Radiology", "radiology", occ)),
            ("emergency", "room", "", ("Emergency", "urgentcare", occ)),
            ("pharmacy", "room", "", ("Pharmacy", "pharmacy", occ)),
            ("escalator", "escalator", "Escalator", None),
        ],
    )
    rooms += _row(
        0,
        False,
        [
            ("registration", "room", "Registration", None),
            ("store", "storage", "Store", None),
            ("restroom", "restroom", "", None),
            ("office", "office", "", None),
        ],
    )
    rooms += _row(
        1,
        True,
        [
            ("cardiology", "room", "", ("Cardiology", "cardiology", occ)),
            ("room-102", "room", "Room 1.02", None),
            ("dermatology", "room", "", ("Dermatology", "dermatology", occ)),
            ("escalator", "escalator", "Escalator", None),
            ("waiting", "waitingroom", "Waiting area", None),
        ],
    )
    rooms += _row(
        1,
        False,
        [
            ("laboratory", "laboratory", "", ("Laboratory", "laboratorytesting", occ)),
            ("office", "office", "", None),
            ("restroom", "restroom", "", ("Restrooms", "restroom", am)),
            ("room-108", "room", "", None),
        ],
    )
    rooms += _row(
        2,
        True,
        [
            ("maternity", "room", "", ("Maternity", "obgyn", occ)),
            ("dialysis", "room", "", ("Dialysis", "dialysis", occ)),
            ("cafeteria", "foodservice", "", ("Cafeteria", "cafeteria", occ)),
            ("chapel", "room", "Chapel", None),
            ("oncology", "room", "", ("Oncology", "medicalcenter", occ)),
        ],
    )
    rooms += _row(
        2,
        False,
        [
            ("neurology", "room", "", ("Neurology", "medicalcenter", occ)),
            ("office", "office", "", None),
            ("restroom", "restroom", "", None),
            ("room-208", "room", "", None),
        ],
    )
    return rooms


LEVELS = {0: ("Ground floor", "G"), 1: ("First floor", "1"), 2: ("Second floor", "2")}


def fid(*parts: object) -> str:
    """A feature's id: a UUID made from its parts (the same every time)."""
    return str(uuid.uuid5(_NS, "/".join(map(str, parts))))


def to_lonlat(x: float, y: float) -> list[float]:
    """Metres from the building's south-west corner to [longitude, latitude]."""
    lon, lat = LocalProjection(LON0, LAT0).to_lonlat(x - WIDTH / 2, y - DEPTH / 2)
    return [round(lon, 10), round(lat, 10)]


def _box(box: tuple[float, float, float, float]) -> dict[str, Any]:
    x0, y0, x1, y1 = box
    ring = [to_lonlat(x, y) for x, y in ((x0, y0), (x1, y0), (x1, y1), (x0, y1), (x0, y0))]
    return {"type": "Polygon", "coordinates": [ring]}


def _point(x: float, y: float) -> dict[str, Any]:
    return {"type": "Point", "coordinates": to_lonlat(x, y)}


def _middle(box: tuple[float, float, float, float]) -> tuple[float, float]:
    return (box[0] + box[2]) / 2, (box[1] + box[3]) / 2


def _feature(kind: str, key: object, geometry: Any, **props: Any) -> dict[str, Any]:
    return {
        "id": fid(kind, key),
        "type": "Feature",
        "feature_type": kind,
        "geometry": geometry,
        "properties": props,
    }


def _collection(kind: str, features: list[dict[str, Any]]) -> dict[str, Any]:
    return {"type": "FeatureCollection", "name": kind, "features": features}


def door_line(room: Room) -> list[tuple[float, float]]:
    """The door of a room with one: 1.2 m in the middle of its corridor side."""
    x0, y0, x1, y1 = room.box
    y = y1 if y1 <= CORRIDOR[0] else y0
    mid = (x0 + x1) / 2
    return [(mid - DOOR / 2, y), (mid + DOOR / 2, y)]


def hospital() -> dict[str, Any]:
    """Every file of the archive, by name: JSON documents."""
    rooms = plan()
    outline = (0.0, 0.0, WIDTH, DEPTH)
    uid = {(r.ordinal, r.key): fid("unit", r.ordinal, r.key) for r in rooms}
    ref = {"type": "Point", "coordinates": to_lonlat(WIDTH / 2, DEPTH / 2)}
    docs: dict[str, Any] = {
        "manifest.json": {
            "version": "1.0.0",
            "created": "2026-01-01T00:00:00Z",
            "generated_by": "app.mapio.imdf.sample",
            "language": "en",
            "extensions": None,
        }
    }
    address = _feature(
        "address",
        "main",
        None,
        address="1 Example Street",
        unit=None,
        locality="London",
        province="GB-LND",
        country="GB",
        postal_code="WC1 0AA",
        postal_code_ext=None,
        postal_code_vanity=None,
    )
    venue_box = (-5.0, -5.0, WIDTH + 5.0, DEPTH + 5.0)
    venue = _feature(
        "venue",
        "main",
        _box(venue_box),
        category="healthcarefacility",
        restriction=None,
        name={"en": "Example Hospital"},
        alt_name=None,
        hours=None,
        phone=None,
        website=None,
        display_point=ref,
        address_id=address["id"],
    )
    building = _feature(
        "building",
        "main",
        None,
        category="unspecified",
        restriction=None,
        name={"en": "Main building"},
        alt_name=None,
        display_point=ref,
        address_id=address["id"],
    )
    footprint = _feature(
        "footprint",
        "main",
        _box(outline),
        category="ground",
        name=None,
        building_ids=[building["id"]],
    )
    levels = [
        _feature(
            "level",
            o,
            _box(outline),
            category="unspecified",
            restriction=None,
            outdoor=False,
            ordinal=o,
            name={"en": name},
            short_name={"en": short},
            display_point=ref,
            address_id=None,
            building_ids=[building["id"]],
        )
        for o, (name, short) in LEVELS.items()
    ]
    units, openings, anchors, occupants, amenities = [], [], [], [], []
    for r in rooms:
        units.append(
            _feature(
                "unit",
                f"{r.ordinal}/{r.key}",
                _box(r.box),
                category=r.category,
                restriction=None,
                accessibility=None,
                name={"en": r.name} if r.name else None,
                alt_name=None,
                level_id=fid("level", r.ordinal),
                display_point=None,
            )
        )
        units[-1]["id"] = uid[(r.ordinal, r.key)]
        if r.door:
            openings.append(
                _feature(
                    "opening",
                    f"{r.ordinal}/{r.key}",
                    {"type": "LineString", "coordinates": [to_lonlat(*p) for p in door_line(r)]},
                    category="pedestrian",
                    accessibility=None,
                    access_control=None,
                    door={"type": "swinging", "automatic": False, "material": "wood"},
                    name=None,
                    alt_name=None,
                    display_point=None,
                    level_id=fid("level", r.ordinal),
                )
            )
        if r.tenant is None:
            continue
        name, category, kind = r.tenant
        where = _point(*_middle(r.box))
        if kind == "amenity":
            amenities.append(
                _feature(
                    "amenity",
                    f"{r.ordinal}/{r.key}",
                    where,
                    category=category,
                    accessibility=None,
                    name={"en": name},
                    alt_name=None,
                    hours=None,
                    phone=None,
                    website=None,
                    unit_ids=[uid[(r.ordinal, r.key)]],
                    address_id=None,
                    correlation_id=None,
                )
            )
            continue
        anchor = _feature(
            "anchor", f"{r.ordinal}/{r.key}", where, address_id=None, unit_id=units[-1]["id"]
        )
        anchors.append(anchor)
        occupants.append(
            _feature(
                "occupant",
                f"{r.ordinal}/{r.key}",
                None,
                name={"en": name},
                category=category,
                anchor_id=anchor["id"],
                hours=None,
                phone=None,
                website=None,
                validity=None,
                correlation_id=None,
            )
        )

    def ref_to(o: int, key: str) -> dict[str, str]:
        return {"id": uid[(o, key)], "feature_type": "unit"}

    relationships = [
        _feature(
            "relationship",
            "lift",
            None,
            category="elevator",
            direction="undirected",
            origin=ref_to(0, "lift"),
            intermediary=[ref_to(1, "lift")],
            destination=ref_to(2, "lift"),
            hours=None,
        ),
        _feature(
            "relationship",
            "escalator",
            None,
            category="escalator",
            direction="undirected",
            origin=ref_to(0, "escalator"),
            intermediary=None,
            destination=ref_to(1, "escalator"),
            hours=None,
        ),
        _feature(  # within the ground floor: through the radiology door
            "relationship",
            "radiology",
            None,
            category="traversal",
            direction="undirected",
            origin=ref_to(0, "entrance"),
            intermediary=[{"id": fid("opening", "0/radiology"), "feature_type": "opening"}],
            destination=ref_to(0, "radiology"),
            hours=None,
        ),
    ]
    for name, kind, features in (
        ("address", "address", [address]),
        ("venue", "venue", [venue]),
        ("building", "building", [building]),
        ("footprint", "footprint", [footprint]),
        ("level", "level", levels),
        ("unit", "unit", units),
        ("opening", "opening", openings),
        ("anchor", "anchor", anchors),
        ("occupant", "occupant", occupants),
        ("amenity", "amenity", amenities),
        ("relationship", "relationship", relationships),
    ):
        docs[f"{name}.geojson"] = _collection(kind, features)
    return docs


def write_archive(docs: dict[str, Any], path: Path) -> Path:
    """The documents written as a .zip (``path`` ending in .zip) or into a folder."""
    if path.suffix.lower() == ".zip":
        with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
            for name, doc in docs.items():
                zf.writestr(name, json.dumps(doc, indent=1))
        return path
    path.mkdir(parents=True, exist_ok=True)
    for name, doc in docs.items():
        (path / name).write_text(json.dumps(doc, indent=1), encoding="utf-8")
    return path


if __name__ == "__main__":  # pragma: no cover - a command for people
    if len(sys.argv) != 2:
        sys.exit("usage: python -m app.mapio.imdf.sample OUT.zip|OUT_FOLDER")
    print(write_archive(hospital(), Path(sys.argv[1])))
