"""Bad IMDF archives refused in one line: missing files, bad JSON and geometry, unknown ids,
extents past the budget, zip members that climb out, zip bombs, links out of the folder."""

from __future__ import annotations

import json
import os
import struct
import zipfile
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.mapio import MapImportError
from app.mapio.budget import MIB, MemoryBudget
from app.mapio.imdf import archive, open_imdf, read_imdf
from app.mapio.imdf.sample import to_lonlat
from tests.mapio.imdf_helpers import docs, features, write


def refused(path: Path, match: str, **kwargs: Any) -> str:
    with pytest.raises(MapImportError, match=match) as info:
        read_imdf(path, **kwargs)
    message = str(info.value)
    assert "\n" not in message and len(message) < 500, message
    return message


def changed(tmp_path: Path, change: Any, zipped: bool = True) -> Path:
    d = docs()
    change(d)
    return write(tmp_path, d, zipped)


@pytest.mark.parametrize("zipped", [True, False], ids=["zip", "folder"])
@pytest.mark.parametrize(
    "name", ["manifest.json", "venue.geojson", "level.geojson", "unit.geojson"]
)
def test_imdf_a_required_file_missing_is_named(tmp_path: Path, name: str, zipped: bool) -> None:
    d = docs()
    del d[name]
    path = write(tmp_path, d, zipped)
    if name == "manifest.json" and zipped:
        refused(path, "no manifest.json in the archive: not an IMDF archive")
    else:
        refused(path, f"no {name} in the archive: an IMDF archive needs manifest.json")


def test_imdf_optional_files_may_be_missing(tmp_path: Path) -> None:
    d = docs()
    for name in ("opening", "relationship", "anchor", "occupant", "amenity"):
        del d[f"{name}.geojson"]
    v = read_imdf(write(tmp_path, d))
    assert v.ordinals == (0, 1, 2) and not v.connections[0].source.endswith("relationships")


def test_imdf_not_an_archive(tmp_path: Path) -> None:
    refused(tmp_path / "none.zip", "no such file or folder")
    bad = tmp_path / "bad.zip"
    bad.write_text("hello")
    refused(bad, "not a zip archive")


def _raw(tmp_path: Path, name: str, data: bytes) -> Path:
    d = docs()
    path = write(tmp_path, d, zipped=False)
    (path / name).write_bytes(data)
    return path


@pytest.mark.parametrize(
    ("name", "data", "message"),
    [
        ("unit.geojson", b"{not json", r"unit.geojson: not JSON: line 1, column 2"),
        ("unit.geojson", b"\xff\xfe\x00", "unit.geojson: not JSON .not UTF-8 text."),
        ("unit.geojson", b"[1, 2]", "unit.geojson: not a GeoJSON FeatureCollection"),
        ("unit.geojson", b'{"type": "FeatureCollection"}', "'features' must be a list"),
        ("level.geojson", b'{"type": "FeatureCollection", "features": []}', "no level"),
        ("manifest.json", b'{"language": "en"}', "must be an object with a 'version'"),
        ("unit.geojson", b"[" * 100_000 + b"]" * 100_000, "nested too deeply"),
        ("unit.geojson", b'{"a": NaN}', "a value cannot be read .NaN is not a JSON number"),
        ("unit.geojson", b'{"a": ' + b"1" * 5000 + b"}", "a value cannot be read"),
    ],
)
def test_imdf_files_that_are_not_imdf_json(
    tmp_path: Path, name: str, data: bytes, message: str
) -> None:
    refused(_raw(tmp_path, name, data), message)


def _unit(d: dict[str, Any], k: int = 0) -> dict[str, Any]:
    out: dict[str, Any] = features(d, "unit")[k]
    return out


def _set(path: list[Any], value: Any, file: str = "unit", k: int = 0) -> Any:
    def change(d: dict[str, Any]) -> None:
        target: Any = features(d, file)[k]
        for key in path[:-1]:
            target = target[key]
        target[path[-1]] = value

    return change


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (
            _set(["geometry"], {"type": "Point", "coordinates": [0, 0]}),
            "geometry must be Polygon or MultiPolygon, got 'Point'",
        ),
        (_set(["geometry"], None), "geometry must be Polygon or MultiPolygon, got None"),
        (
            _set(["geometry", "coordinates"], [[[0, 0], [1, 1]]]),
            "a ring needs at least 3 positions",
        ),
        (
            _set(["geometry", "coordinates"], [[["a", 1], [0, 0], [1, 1]]]),
            r"position 1 must be \[longitude, latitude\], got \['a', 1\]",
        ),
        (
            _set(["geometry", "coordinates"], [[[0, 95], [0, 0], [1, 1]]]),
            r"position 1 \(0, 95\) is not a longitude",
        ),
        (_set(["geometry", "coordinates"], [[[True, 1], [0, 0], [1, 1]]]), "position 1 must be"),
        (
            _set(["geometry"], {"type": "Polygon", "coordinates": [[0, 0], [1, 1], [2, 0]]}),
            r"position 1 must be \[longitude",
        ),
        (
            _set(["geometry"], {"type": "Polygon", "coordinates": []}, "opening"),
            "geometry must be LineString, got 'Polygon'",
        ),
        (
            _set(["geometry"], {"type": "Polygon", "coordinates": []}, "anchor"),
            "geometry must be Point, got 'Polygon'",
        ),
        (
            _set(["properties", "level_id"], "nope"),
            "unit.geojson: feature 1 .id '.*'.: level_id 'nope' is not a feature of level.geojson",
        ),
        (_set(["properties", "level_id"], None), "level_id must be a non-empty string, got None"),
        (
            _set(["properties", "level_id"], "nope", "opening"),
            "opening.geojson: .* level_id 'nope' is not a feature of level.geojson",
        ),
        (
            _set(["properties", "unit_id"], "gone", "anchor"),
            "unit_id 'gone' is not a feature of unit.geojson",
        ),
        (
            _set(["properties", "anchor_id"], "gone", "occupant"),
            "anchor_id 'gone' is not a feature of anchor.geojson",
        ),
        (
            _set(["properties", "unit_ids"], ["gone"], "amenity"),
            "unit_ids' id 'gone' is not a feature of unit.geojson",
        ),
        (_set(["properties", "unit_ids"], "x", "amenity"), "unit_ids must be a list of ids"),
        (
            _set(["properties", "origin"], {"id": "gone", "feature_type": "unit"}, "relationship"),
            "origin unit 'gone' is not a feature of unit.geojson",
        ),
        (_set(["properties", "origin"], "gone", "relationship"), "origin must be a reference"),
        (
            _set(["properties", "ordinal"], 1.5, "level"),
            r"ordinal must be a whole number .*got 1.5",
        ),
        (_set(["properties", "ordinal"], True, "level"), "ordinal must be a whole number"),
        (_set(["properties", "name"], 3, "occupant"), "name must be a label"),
        (_set(["properties", "name"], None, "occupant"), "name is required"),
        (_set(["feature_type"], "room"), "feature_type must be 'unit', got 'room'"),
        (_set(["id"], 7), "'id' must be a non-empty string, got 7"),
        (_set(["properties"], []), "'properties' must be an object"),
    ],
)
def test_imdf_bad_features_are_named_with_their_file_and_id(
    tmp_path: Path, change: Any, message: str
) -> None:
    path = changed(tmp_path, change)
    refused(path, message)


def test_imdf_duplicate_ids_and_many_venues(tmp_path: Path) -> None:
    def twice(d: dict[str, Any]) -> None:
        features(d, "unit")[1]["id"] = features(d, "unit")[0]["id"]

    refused(changed(tmp_path, twice), "the id is given to another feature of the file too")

    def two_venues(d: dict[str, Any]) -> None:
        features(d, "venue").append(features(d, "venue")[0])

    refused(changed(tmp_path, two_venues), "holds 2 venues: an IMDF archive holds one")


def test_imdf_values_in_errors_are_cut_short(tmp_path: Path) -> None:
    long = "x" * 10_000
    message = refused(changed(tmp_path, _set(["properties", "level_id"], long)), "level_id 'xxx")
    assert "..." in message and len(message) < 300

    def long_id(d: dict[str, Any]) -> None:
        features(d, "unit")[0]["id"] = long
        features(d, "unit")[0]["geometry"] = None

    message = refused(changed(tmp_path, long_id), r"feature 1 \(id 'xxx.*\.\.\.\): geometry")
    assert len(message) < 300


def test_imdf_features_far_from_the_reference_point_are_refused(tmp_path: Path) -> None:
    far = [to_lonlat(5000, 0), to_lonlat(5010, 0), to_lonlat(5010, 10), to_lonlat(5000, 0)]
    message = refused(
        changed(tmp_path, _set(["geometry", "coordinates"], [far])),
        "a feature lies 4,99. m from the venue's reference point .its display_point.: at most "
        "2,000 m are read",
    )
    assert "projection" in message
    refused(
        changed(tmp_path, _set(["geometry", "coordinates"], to_lonlat(0, 3000), "anchor")),
        "an anchor, amenity or display point lies more than 2,000 m",
    )


def test_imdf_an_extent_past_the_budget_is_refused_before_drawing(tmp_path: Path) -> None:
    wide = [to_lonlat(-1500, -1000), to_lonlat(1500, -1000), to_lonlat(1500, 1000)]
    path = changed(tmp_path, _set(["geometry", "coordinates"], [[*wide, wide[0]]], "level"))
    message = refused(
        path,
        r"3 level\(s\) of 20,00. x 30,00. cells .3,000 x 2,000 m at 0.1 m a "
        r"cell. would need about .* MiB to import, more than the memory budget of "
        r"768 MiB: raise the budget with --max-memory MIB, or give a coarser "
        r"--resolution \(such as ",
        resolution=0.1,
    )
    coarser = float(message.rsplit("such as ", 1)[1].rstrip(")"))
    v = read_imdf(path, coarser)  # the suggestion fits
    assert v.frame.resolution == coarser


def test_imdf_geojson_past_the_budget_is_refused_before_parsing(tmp_path: Path) -> None:
    path = write(tmp_path)
    with pytest.raises(
        MapImportError,
        match="bytes of GeoJSON would need up to .* to read "
        r"\(32 bytes a byte at most\), more than the memory budget of 1 MiB",
    ):
        open_imdf(path, MemoryBudget.of_mib(1))


def _zip(path: Path, members: dict[str, bytes], method: int = zipfile.ZIP_DEFLATED) -> Path:
    with zipfile.ZipFile(path, "w", method) as zf:
        for name, data in members.items():
            zf.writestr(name, data)
    return path


def _members() -> dict[str, bytes]:
    return {name: json.dumps(doc).encode() for name, doc in docs().items()}


@pytest.mark.parametrize(
    "evil", ["../unit.geojson", "/etc/passwd", "a/../../b", "C:/x", "a\\..\\b"]
)
def test_imdf_zip_members_that_climb_out_refuse_the_archive(tmp_path: Path, evil: str) -> None:
    path = _zip(tmp_path / "evil.zip", {**_members(), evil: b"{}"})
    refused(path, "is an absolute path or climbs out with '..': the archive is not read")


def test_imdf_a_zip_bomb_member_is_refused_before_it_is_expanded(tmp_path: Path) -> None:
    members = _members()
    members["unit.geojson"] = b" " * (40 * MIB)  # 40 MiB of spaces: some 40 KiB compressed
    path = _zip(tmp_path / "bomb.zip", members)
    assert path.stat().st_size < 200_000
    refused(path, r"unit.geojson: .* bytes that expand to 41,943,040 .* looks like a zip bomb")


def test_imdf_a_member_larger_than_allowed_is_refused(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(archive, "MAX_FILE_BYTES", 1000)
    refused(write(tmp_path), "level.geojson: declares .* bytes, more than the 0 MiB a file")
    refused(write(tmp_path, zipped=False), "level.geojson: .* bytes, more than the 0 MiB")


def test_imdf_a_member_longer_than_its_header_says_is_refused(tmp_path: Path) -> None:
    members = _members()
    path = _zip(tmp_path / "lying.zip", members, zipfile.ZIP_STORED)
    data = bytearray(path.read_bytes())
    size = len(members["unit.geojson"])
    # the unit file's sizes in its local header and in the central directory, made smaller
    name = b"unit.geojson"
    for sig, off in ((b"PK\x03\x04", 18), (b"PK\x01\x02", 20)):
        at = 0
        while (at := data.find(sig, at)) >= 0:
            name_at = at + (30 if sig == b"PK\x03\x04" else 46)
            if bytes(data[name_at : name_at + len(name)]) == name:
                struct.pack_into("<LL", data, at + off, size - 100, size - 100)
            at += 4
    path.write_bytes(bytes(data))
    refused(path, "unit.geojson: the archive is damaged: Bad CRC-32")


def test_imdf_a_zip_of_too_many_members_is_refused_from_its_end_record(tmp_path: Path) -> None:
    members = _members() | {f"extra/{i}.txt": b"" for i in range(1001)}
    refused(
        _zip(tmp_path / "many.zip", members),
        "the zip lists 1,013 members in .* bytes: an IMDF archive holds a few files",
    )


def test_imdf_two_venues_in_one_zip_and_a_folder_inside_it(tmp_path: Path) -> None:
    members = _members()
    inside = {f"hospital/{k}": v for k, v in members.items()}
    v = read_imdf(_zip(tmp_path / "inside.zip", inside))
    assert v.ordinals == (0, 1, 2)
    both = inside | {f"other/{k}": v for k, v in members.items()}
    refused(
        _zip(tmp_path / "both.zip", both),
        "2 manifest.json files .in 'hospital', 'other'.: give one venue's archive",
    )


def test_imdf_an_encrypted_member_is_refused(tmp_path: Path) -> None:
    path = _zip(tmp_path / "enc.zip", _members(), zipfile.ZIP_STORED)
    data = bytearray(path.read_bytes())
    at = 0
    while (at := data.find(b"PK\x01\x02", at)) >= 0:  # the encrypted flag, central directory
        data[at + 8] |= 1
        at += 4
    path.write_bytes(bytes(data))
    refused(path, "manifest.json: encrypted: only plain archives are read|encrypted")


@pytest.mark.parametrize("exists", [True, False])
def test_imdf_a_link_out_of_the_folder_is_one_message_whether_it_exists_or_not(
    tmp_path: Path, exists: bool
) -> None:
    path = write(tmp_path, zipped=False)
    outside = tmp_path / "secret.geojson"
    if exists:
        outside.write_text(json.dumps(docs()["unit.geojson"]))
    os.remove(path / "unit.geojson")
    os.symlink(outside, path / "unit.geojson")
    message = refused(path, "unit.geojson is a link to a place outside the folder")
    assert "secret" not in message and "exist" not in message


def test_imdf_a_link_inside_the_folder_is_read(tmp_path: Path) -> None:
    path = write(tmp_path, zipped=False)
    (path / "units.json").write_bytes((path / "unit.geojson").read_bytes())
    os.remove(path / "unit.geojson")
    os.symlink(path / "units.json", path / "unit.geojson")
    assert read_imdf(path).ordinals == (0, 1, 2)


def test_imdf_a_resolution_that_is_not_a_length_is_refused(tmp_path: Path) -> None:
    path = write(tmp_path)
    refused(path, "resolution must be a positive number of metres, got 0", resolution=0.0)
    refused(path, "storey height must be a positive", storey_height=float("nan"))


@pytest.fixture(scope="module")
def hospital_zip(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    return write(tmp_path_factory.mktemp("zip")).read_bytes()


@settings(max_examples=150, deadline=None)
@given(st.data())
def test_imdf_a_damaged_zip_is_refused_in_one_line_or_read(
    hospital_zip: bytes, tmp_path_factory: pytest.TempPathFactory, data: st.DataObject
) -> None:
    """Any archive cut short or with bytes changed: a MapImportError (the zlib error, a zip
    version zipfile does not read, a name that is not UTF-8, an empty name were tracebacks
    found this way) or a venue, nothing else."""
    raw = bytearray(hospital_zip)
    if data.draw(st.booleans()):
        raw = raw[: data.draw(st.integers(0, len(raw) - 1))]
    else:
        for _ in range(data.draw(st.integers(1, 20))):
            raw[data.draw(st.integers(0, len(raw) - 1))] = data.draw(st.integers(0, 255))
    path = tmp_path_factory.mktemp("damaged") / "damaged.zip"
    path.write_bytes(bytes(raw))
    try:
        read_imdf(path)
    except MapImportError as exc:
        assert "\n" not in str(exc) and len(str(exc)) < 500


def test_imdf_a_zip_member_with_no_name_is_refused(tmp_path: Path) -> None:
    path = _zip(tmp_path / "noname.zip", {**_members(), "x": b"{}"})
    raw = path.read_bytes()
    at = raw.rfind(b"PK\x01\x02")  # the last member's directory entry: its name, made empty
    raw = raw[: at + 28] + b"\x00\x00" + raw[at + 30 : at + 46] + raw[at + 47 :]
    end = raw.rfind(b"PK\x05\x06")
    size = struct.unpack_from("<L", raw, end + 12)[0] - 1  # the directory, a byte shorter
    raw = raw[: end + 12] + struct.pack("<L", size) + raw[end + 16 :]
    path.write_bytes(raw)
    refused(path, "a member has no name: the archive is damaged")
