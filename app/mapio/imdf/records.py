"""An IMDF archive's features as checked records (longitude and latitude still), and the
reading of them: every file's JSON parsed within the memory budget, every reference between
features resolved (see :mod:`app.mapio.imdf.features` for what is read of each file)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from app.arrays import FloatArray
from app.mapio import MapImportError, shorten
from app.mapio.budget import MemoryBudget
from app.mapio.imdf.archive import Archive
from app.mapio.imdf.features import FileReader, Rings, load_json

#: the relationship references that join places (others, such as amenities, are not read)
PLACES = ("unit", "opening")


@dataclass
class VenueRec:
    id: str
    name: str
    category: str
    rings: Rings
    display_point: FloatArray | None


@dataclass
class LevelRec:
    id: str
    ordinal: int
    name: str
    short_name: str
    outdoor: bool
    rings: Rings


@dataclass
class UnitRec:
    id: str
    level_id: str
    category: str
    name: str
    rings: Rings
    display_point: FloatArray | None


@dataclass
class OpeningRec:
    id: str
    level_id: str
    category: str
    name: str
    line: FloatArray


@dataclass
class AnchorRec:
    id: str
    unit_id: str
    point: FloatArray


@dataclass
class OccupantRec:
    id: str
    name: str
    category: str
    anchor_id: str


@dataclass
class AmenityRec:
    id: str
    category: str
    name: str
    unit_ids: list[str]
    point: FloatArray


@dataclass
class RelationshipRec:
    id: str
    category: str
    refs: list[tuple[str, str]]  # (feature_type, id): origin, intermediaries, destination


@dataclass
class Records:
    """Everything read from an archive, checked, in file order."""

    language: str | None
    venue: VenueRec
    levels: list[LevelRec]
    units: list[UnitRec]
    openings: list[OpeningRec] = field(default_factory=list)
    anchors: list[AnchorRec] = field(default_factory=list)
    occupants: list[OccupantRec] = field(default_factory=list)
    amenities: list[AmenityRec] = field(default_factory=list)
    relationships: list[RelationshipRec] = field(default_factory=list)
    n_bytes: int = 0  # of the GeoJSON read


def read_records(archive: Archive, budget: MemoryBudget) -> Records:
    """Every file of ``archive`` the reader uses, checked; refused before parsing when the
    JSON would take more than ``budget``."""
    where = archive.where
    budget.check_json(where, sum(archive.sizes.values()))
    manifest = load_json(archive.read("manifest.json"), f"{where}: manifest.json")
    if not isinstance(manifest, dict) or not isinstance(manifest.get("version"), str):
        raise MapImportError(
            f"{where}: manifest.json: must be an object with a 'version' (IMDF's \"1.0.0\")"
        )
    language = manifest.get("language")
    language = language if isinstance(language, str) else None

    def features(name: str) -> FileReader | None:
        if name not in archive.sizes:
            return None
        doc = load_json(archive.read(name), f"{where}: {name}")
        return FileReader(where, name, doc, language)

    venue = _venue(features("venue.geojson"))
    levels = _levels(features("level.geojson"))
    level_ids = {lv.id for lv in levels}
    units = _units(features("unit.geojson"), level_ids)
    unit_ids = {u.id for u in units}
    records = Records(language, venue, levels, units, n_bytes=sum(archive.sizes.values()))
    records.openings = _openings(features("opening.geojson"), level_ids)
    records.anchors = _anchors(features("anchor.geojson"), unit_ids)
    records.occupants = _occupants(features("occupant.geojson"), {a.id for a in records.anchors})
    records.amenities = _amenities(features("amenity.geojson"), unit_ids)
    known = {"unit": unit_ids, "opening": {o.id for o in records.openings}}
    records.relationships = _relationships(features("relationship.geojson"), known)
    return records


def _unique(seen: set[str], fid: str, at: str) -> None:
    if fid in seen:
        raise MapImportError(f"{at}: the id is given to another feature of the file too")
    seen.add(fid)


def _known(at: str, key: str, value: str, ids: set[str], file: str) -> None:
    if value not in ids:
        raise MapImportError(f"{at}: {key} {shorten(value, 40)} is not a feature of {file}")


def _venue(r: FileReader | None) -> VenueRec:
    assert r is not None
    got = [
        VenueRec(
            fid,
            r.label(at, props, "name"),
            r.text(at, props, "category", required=False),
            r.rings(at, geometry),
            r.display_point(at, props),
        )
        for at, fid, props, geometry in r.each()
    ]
    if len(got) != 1:
        raise MapImportError(f"{r.where}: holds {len(got)} venues: an IMDF archive holds one")
    return got[0]


def _levels(r: FileReader | None) -> list[LevelRec]:
    assert r is not None
    out: list[LevelRec] = []
    seen: set[str] = set()
    for at, fid, props, geometry in r.each():
        _unique(seen, fid, at)
        ordinal = props.get("ordinal")
        if isinstance(ordinal, bool) or not isinstance(ordinal, int) or abs(ordinal) > 999:
            raise MapImportError(
                f"{at}: ordinal must be a whole number (0 the ground level, -1 below, 1 above; "
                f"at most 999 either way), got {shorten(ordinal)}"
            )
        outdoor = props.get("outdoor", False)
        name = r.label(at, props, "name") or f"level {ordinal}"
        short = r.label(at, props, "short_name") or str(ordinal)
        out.append(LevelRec(fid, ordinal, name, short, outdoor is True, r.rings(at, geometry)))
    if not out:
        raise MapImportError(f"{r.where}: no level: a venue needs at least one")
    return out


def _units(r: FileReader | None, level_ids: set[str]) -> list[UnitRec]:
    assert r is not None
    out: list[UnitRec] = []
    seen: set[str] = set()
    for at, fid, props, geometry in r.each():
        _unique(seen, fid, at)
        level_id = r.text(at, props, "level_id")
        _known(at, "level_id", level_id, level_ids, "level.geojson")
        category = r.text(at, props, "category")
        name = r.label(at, props, "name")
        rings = r.rings(at, geometry)
        out.append(UnitRec(fid, level_id, category, name, rings, r.display_point(at, props)))
    return out


def _openings(r: FileReader | None, level_ids: set[str]) -> list[OpeningRec]:
    if r is None:
        return []
    out: list[OpeningRec] = []
    seen: set[str] = set()
    for at, fid, props, geometry in r.each():
        _unique(seen, fid, at)
        level_id = r.text(at, props, "level_id")
        _known(at, "level_id", level_id, level_ids, "level.geojson")
        category = r.text(at, props, "category", required=False)
        out.append(
            OpeningRec(fid, level_id, category, r.label(at, props, "name"), r.line(at, geometry))
        )
    return out


def _anchors(r: FileReader | None, unit_ids: set[str]) -> list[AnchorRec]:
    if r is None:
        return []
    out: list[AnchorRec] = []
    seen: set[str] = set()
    for at, fid, props, geometry in r.each():
        _unique(seen, fid, at)
        unit_id = r.text(at, props, "unit_id")
        _known(at, "unit_id", unit_id, unit_ids, "unit.geojson")
        out.append(AnchorRec(fid, unit_id, r.point(at, geometry)))
    return out


def _occupants(r: FileReader | None, anchor_ids: set[str]) -> list[OccupantRec]:
    if r is None:
        return []
    out: list[OccupantRec] = []
    seen: set[str] = set()
    for at, fid, props, _ in r.each():
        _unique(seen, fid, at)
        anchor_id = r.text(at, props, "anchor_id")
        _known(at, "anchor_id", anchor_id, anchor_ids, "anchor.geojson")
        name = r.label(at, props, "name", required=True)
        out.append(OccupantRec(fid, name, r.text(at, props, "category", required=False), anchor_id))
    return out


def _amenities(r: FileReader | None, unit_ids: set[str]) -> list[AmenityRec]:
    if r is None:
        return []
    out: list[AmenityRec] = []
    seen: set[str] = set()
    for at, fid, props, geometry in r.each():
        _unique(seen, fid, at)
        ids = r.ids(at, props, "unit_ids")
        for unit_id in ids:
            _known(at, "unit_ids' id", unit_id, unit_ids, "unit.geojson")
        category = r.text(at, props, "category")
        name = r.label(at, props, "name")
        out.append(AmenityRec(fid, category, name, ids, r.point(at, geometry)))
    return out


def _relationships(r: FileReader | None, known: dict[str, set[str]]) -> list[RelationshipRec]:
    if r is None:
        return []
    out: list[RelationshipRec] = []
    seen: set[str] = set()
    for at, fid, props, _ in r.each():
        _unique(seen, fid, at)
        category = r.text(at, props, "category")
        inter = props.get("intermediary")
        if inter is not None and not isinstance(inter, list):
            inter = [inter]  # one reference where the spec has a list of them
        refs = [
            ref
            for key, value in (
                ("origin", [props.get("origin")]),
                ("intermediary", inter or []),
                ("destination", [props.get("destination")]),
            )
            for item in value
            if (ref := _reference(at, key, item, known)) is not None
        ]
        out.append(RelationshipRec(fid, category, refs))
    return out


def _reference(at: str, key: str, value: Any, known: dict[str, set[str]]) -> tuple[str, str] | None:
    """A relationship's reference to a unit or an opening; ``None`` when absent or to another
    kind of feature (not read)."""
    if value is None:
        return None
    if (
        not isinstance(value, dict)
        or not isinstance(value.get("id"), str)
        or not isinstance(value.get("feature_type"), str)
    ):
        raise MapImportError(
            f'{at}: {key} must be a reference {{"id": ..., "feature_type": ...}}, '
            f"got {shorten(value)}"
        )
    kind, fid = value["feature_type"], value["id"]
    if kind not in PLACES:
        return None
    _known(at, f"{key} {kind}", fid, known[kind], f"{kind}.geojson")
    return kind, fid
