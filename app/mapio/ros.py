"""ROS map_server maps: a YAML file naming an image and how to read it.

The keys (wiki.ros.org/map_server): ``image`` (path, relative to the YAML file), ``resolution``
(metres per pixel), ``origin`` (x, y, yaw of the lower-left pixel), ``occupied_thresh``,
``free_thresh``, ``negate`` and optionally ``mode`` (trinary, scale or raw). A pixel's
occupancy is ``(255 - v) / 255`` (``v / 255`` when ``negate``); above ``occupied_thresh`` it is
occupied, below ``free_thresh`` free, otherwise unknown (not walkable). In ``raw`` mode the
value is the occupancy in percent (over 100: unknown).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from app.domain.grid import Frame
from app.mapio import Imported, MapImportError
from app.mapio.raster import merge_cells, read_image

REQUIRED = ("image", "resolution", "origin", "occupied_thresh", "free_thresh", "negate")


def _number(meta: dict[str, Any], key: str, where: str) -> float:
    value = meta[key]
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise MapImportError(f"{where}: {key} must be a number, got {value!r}")
    return float(value)


def read_ros(path: Path, *, merge: int = 1) -> Imported:
    k = merge
    where = str(path)
    try:
        meta = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise MapImportError(f"{where}: not a YAML file: {exc}") from None
    if not isinstance(meta, dict):
        raise MapImportError(
            f"{where}: a map_server YAML is a mapping of keys ({', '.join(REQUIRED)})"
        )
    missing = [key for key in REQUIRED if key not in meta]
    if missing:
        raise MapImportError(f"{where}: missing key(s) {', '.join(missing)}")
    resolution = _number(meta, "resolution", where)
    if resolution <= 0:
        raise MapImportError(
            f"{where}: resolution must be positive metres per pixel, got {resolution}"
        )
    origin = meta["origin"]
    if (
        not isinstance(origin, list)
        or len(origin) != 3
        or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in origin)
        or not all(math.isfinite(v) for v in origin)
    ):
        raise MapImportError(f"{where}: origin must be [x, y, yaw] (three numbers), got {origin!r}")
    occupied = _number(meta, "occupied_thresh", where)
    free_t = _number(meta, "free_thresh", where)
    if not 0 <= free_t <= occupied <= 1:
        raise MapImportError(
            f"{where}: need 0 <= free_thresh <= occupied_thresh <= 1, "
            f"got free_thresh {free_t}, occupied_thresh {occupied}"
        )
    negate = meta["negate"]
    if negate not in (0, 1, True, False):
        raise MapImportError(f"{where}: negate must be 0 or 1, got {negate!r}")
    mode = str(meta.get("mode", "trinary")).lower()
    if mode not in ("trinary", "scale", "raw"):
        raise MapImportError(f"{where}: mode {mode!r}: use trinary, scale or raw")
    image = meta["image"]
    if not isinstance(image, str) or not image:
        raise MapImportError(f"{where}: image must be a file name, got {image!r}")
    image_path = Path(image) if Path(image).is_absolute() else path.parent / image
    if not image_path.is_file():
        raise MapImportError(f"{where}: image {image!r} not found (looked for {image_path})")
    grey, _ = read_image(image_path)
    if mode == "raw":
        v = grey.astype(np.float64)
        known = v <= 100
        p = v / 100.0
    else:
        level = grey.astype(np.float64)
        p = level / 255.0 if negate else (255.0 - level) / 255.0
        known = np.ones(grey.shape, dtype=bool)
    blocked = known & (p > occupied)
    free = known & (p < free_t)
    cells = merge_cells(free, blocked, k)
    frame = Frame(resolution * k, (float(origin[0]), float(origin[1]), float(origin[2])))
    h, w = grey.shape
    notes = [
        f"ROS map {w}x{h} pixels at {resolution:g} m ({int(free.sum())} free, "
        f"{int(blocked.sum())} occupied, {int((~free & ~blocked).sum())} unknown)"
    ]
    if k > 1:
        notes.append(
            f"merged {k}x{k} pixels per cell: {cells.shape[1]}x{cells.shape[0]} cells"
            f" of {resolution * k:g} m"
        )
    return Imported(cells, frame, notes)
