"""IMDF GeoJSON files read into checked records (longitude and latitude still).

Each file is a GeoJSON FeatureCollection whose features carry an ``id`` (a string), a
``feature_type`` (the file's), ``properties`` and a ``geometry`` (IMDF, OGC 20-094). What is
read of each, and what it must be:

========== ================================ ==========================================
file       geometry                         properties read
========== ================================ ==========================================
manifest   (not GeoJSON: an object)         ``version``, ``language``
venue      Polygon or MultiPolygon          ``name``, ``category``, ``display_point``
level      Polygon or MultiPolygon          ``ordinal`` (integer), ``name``, ``short_name``,
                                            ``outdoor``
unit       Polygon or MultiPolygon          ``category``, ``level_id``, ``name``,
                                            ``display_point``
opening    LineString                       ``category``, ``level_id``, ``name``
anchor     Point                            ``unit_id``
occupant   null (ignored)                   ``name``, ``category``, ``anchor_id``
amenity    Point                            ``category``, ``unit_ids``, ``name``
relation-  any (ignored)                    ``category``, ``origin``, ``intermediary``,
ship                                        ``destination`` (``{"id", "feature_type"}``)
========== ================================ ==========================================

Names are IMDF labels (``{"en": "Cardiology"}``): the manifest's language is taken, else its
first part (``en`` of ``en-US``), else English, else the first; control characters become
spaces and a name is cut to :data:`NAME_CHARS`. A reference to a feature that is not there (a
``level_id``, ``unit_id``, ``anchor_id``, a relationship's unit or opening) is an error naming
the file, the feature and the id.
"""

from __future__ import annotations

import json
import math
import unicodedata
from collections.abc import Iterator
from typing import Any

import numpy as np

from app.arrays import FloatArray
from app.mapio import MapImportError, brief, shorten, utf8

NAME_CHARS = 80

Rings = list[FloatArray]  # every ring of a polygon or multipolygon, (n, 2) lon/lat each


def load_json(data: bytes, where: str) -> Any:
    """A JSON document from bytes (UTF-8); one-line errors."""
    text = utf8(data, where, "JSON", bom=True)
    try:
        return json.loads(text, parse_constant=_no_constant)
    except json.JSONDecodeError as exc:
        raise MapImportError(
            f"{where}: not JSON: line {exc.lineno}, column {exc.colno}: {brief(exc.msg, 80)}"
        ) from None
    except RecursionError:
        raise MapImportError(f"{where}: not IMDF: nested too deeply") from None
    except ValueError as exc:  # an integer of too many digits, NaN or Infinity
        raise MapImportError(f"{where}: a value cannot be read ({brief(exc, 80)})") from None


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a JSON number")


def clean_name(text: str) -> str:
    """Control characters as spaces, runs of spaces as one, cut to :data:`NAME_CHARS`."""
    text = "".join(" " if unicodedata.category(ch)[0] == "C" else ch for ch in text[:1000])
    text = " ".join(text.split())
    return text if len(text) <= NAME_CHARS else text[: NAME_CHARS - 3] + "..."


class FileReader:
    """One GeoJSON file's features, with errors that name the file and the feature."""

    def __init__(self, where: str, name: str, doc: Any, language: str | None):
        self.where = f"{where}: {name}"
        self.kind = name.removesuffix(".geojson")
        self.language = language
        if not isinstance(doc, dict) or doc.get("type") != "FeatureCollection":
            raise MapImportError(f"{self.where}: not a GeoJSON FeatureCollection")
        features = doc.get("features")
        if not isinstance(features, list):
            raise MapImportError(f"{self.where}: 'features' must be a list")
        self.features = features

    def each(self) -> Iterator[tuple[str, str, dict[str, Any], Any]]:
        """(error prefix, id, properties, geometry) of every feature."""
        for i, f in enumerate(self.features):
            at = f"{self.where}: feature {i + 1}"
            if not isinstance(f, dict):
                raise MapImportError(f"{at}: not a GeoJSON Feature (an object)")
            fid = f.get("id")
            if not isinstance(fid, str) or not fid:
                raise MapImportError(f"{at}: 'id' must be a non-empty string, got {shorten(fid)}")
            at = f"{at} (id {shorten(fid, 40)})"
            ftype = f.get("feature_type")
            if ftype != self.kind:
                raise MapImportError(
                    f"{at}: feature_type must be {self.kind!r}, got {shorten(ftype)}"
                )
            props = f.get("properties")
            if not isinstance(props, dict):
                raise MapImportError(f"{at}: 'properties' must be an object")
            yield at, fid, props, f.get("geometry")

    # ---- properties ---------------------------------------------------------------------
    def text(self, at: str, props: dict[str, Any], key: str, required: bool = True) -> str:
        value = props.get(key)
        if value is None and not required:
            return ""
        if not isinstance(value, str) or not value:
            raise MapImportError(f"{at}: {key} must be a non-empty string, got {shorten(value)}")
        return value

    def label(self, at: str, props: dict[str, Any], key: str, required: bool = False) -> str:
        """An IMDF label's text in the manifest's language (a plain string is taken too)."""
        value = props.get(key)
        if value is None:
            if required:
                raise MapImportError(f'{at}: {key} is required (a label: {{"en": "..."}})')
            return ""
        if isinstance(value, str):
            return clean_name(value)
        if not isinstance(value, dict) or not value:
            raise MapImportError(
                f'{at}: {key} must be a label ({{"en": "..."}}), got {shorten(value)}'
            )
        lang = self.language or ""
        for key_ in (lang, lang.split("-")[0], "en"):
            if key_ in value and isinstance(value[key_], str):
                return clean_name(value[key_])
        first = next(iter(value.values()))
        if not isinstance(first, str):
            raise MapImportError(f"{at}: {key}'s texts must be strings, got {shorten(first)}")
        return clean_name(first)

    def ids(self, at: str, props: dict[str, Any], key: str) -> list[str]:
        value = props.get(key)
        if not isinstance(value, list) or not value or not all(isinstance(v, str) for v in value):
            raise MapImportError(f"{at}: {key} must be a list of ids, got {shorten(value)}")
        return value

    # ---- geometry -----------------------------------------------------------------------
    def geometry(self, at: str, geometry: Any, kinds: tuple[str, ...]) -> tuple[str, Any]:
        if not isinstance(geometry, dict) or geometry.get("type") not in kinds:
            got = geometry.get("type") if isinstance(geometry, dict) else geometry
            raise MapImportError(
                f"{at}: geometry must be {' or '.join(kinds)}, got {shorten(got, 40)}"
            )
        return geometry["type"], geometry.get("coordinates")

    def rings(self, at: str, geometry: Any) -> Rings:
        kind, coords = self.geometry(at, geometry, ("Polygon", "MultiPolygon"))
        polygons = [coords] if kind == "Polygon" else coords
        if not isinstance(polygons, list) or not polygons:
            raise MapImportError(f"{at}: a {kind} needs coordinates")
        out: Rings = []
        for polygon in polygons:
            if not isinstance(polygon, list) or not polygon:
                raise MapImportError(f"{at}: a polygon is a list of rings")
            for ring in polygon:
                pts = positions(ring, at)
                if len(pts) < 3:
                    raise MapImportError(f"{at}: a ring needs at least 3 positions")
                out.append(pts)
        return out

    def point(self, at: str, geometry: Any, what: str = "geometry") -> FloatArray:
        _, coords = self.geometry(at, geometry, ("Point",))
        pts = positions([coords], f"{at}: {what}")
        out: FloatArray = pts[0]
        return out

    def line(self, at: str, geometry: Any) -> FloatArray:
        _, coords = self.geometry(at, geometry, ("LineString",))
        pts = positions(coords, at)
        if len(pts) < 2:
            raise MapImportError(f"{at}: a LineString needs at least 2 positions")
        return pts

    def display_point(self, at: str, props: dict[str, Any]) -> FloatArray | None:
        value = props.get("display_point")
        if value is None:
            return None
        return self.point(at, value, "display_point")


def positions(value: Any, at: str) -> FloatArray:
    """GeoJSON positions ([lon, lat] or [lon, lat, alt]) as an (n, 2) array, checked."""
    if not isinstance(value, list):
        raise MapImportError(f"{at}: coordinates must be a list of positions")
    out = np.empty((len(value), 2), dtype=np.float64)
    for i, p in enumerate(value):
        if not (isinstance(p, list) and 2 <= len(p) <= 3 and all(_number(v) for v in p)):
            raise MapImportError(
                f"{at}: position {i + 1} must be [longitude, latitude], got {shorten(p, 40)}"
            )
        lon, lat = float(p[0]), float(p[1])
        if not (-180.0 <= lon <= 180.0 and -90.0 <= lat <= 90.0):
            raise MapImportError(
                f"{at}: position {i + 1} ({lon:g}, {lat:g}) is not a longitude in [-180, 180] "
                "and a latitude in [-90, 90]"
            )
        out[i] = lon, lat
    return out


def _number(v: object) -> bool:
    if isinstance(v, bool) or not isinstance(v, int | float):
        return False
    try:
        return math.isfinite(v)
    except OverflowError:
        return False
