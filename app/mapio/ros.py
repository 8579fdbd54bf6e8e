"""ROS map_server maps: a YAML file naming an image and how to read it.

The keys (wiki.ros.org/map_server): ``image`` (path, relative to the YAML file), ``resolution``
(metres per pixel), ``origin`` (x, y, yaw of the lower-left pixel), ``occupied_thresh``,
``free_thresh``, ``negate`` and optionally ``mode`` (trinary, scale or raw). A pixel's
occupancy is ``(255 - v) / 255`` (``v / 255`` when ``negate``); above ``occupied_thresh`` it is
occupied, below ``free_thresh`` free, otherwise unknown (not walkable). In ``raw`` mode the
value is the occupancy in percent (over 100: unknown).

The YAML is a few lines: it is read only up to :data:`MAX_YAML_BYTES`, and without anchors and
aliases (``&a``, ``*a``), which let a small file stand for a huge value. The image must be in
the YAML file's folder or below it (after following symbolic links); an error about one
elsewhere says only that, never whether such a file exists.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from app.domain.grid import Frame
from app.mapio import Imported, MapImportError, brief, shorten, utf8
from app.mapio.budget import MemoryBudget
from app.mapio.raster import merge_cells, read_image

#: the largest map_server YAML read (they are a few hundred bytes)
MAX_YAML_BYTES = 64 * 1024

REQUIRED = ("image", "resolution", "origin", "occupied_thresh", "free_thresh", "negate")


def _number(meta: dict[str, Any], key: str, where: str) -> float:
    value = meta[key]
    if not _finite(value):
        raise MapImportError(f"{where}: {key} must be a number, got {shorten(value)}")
    return float(value)


def _finite(value: object) -> bool:
    """A number (not a bool) that is finite as a float."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:  # an integer beyond any float
        return False


class _AliasRefused(yaml.composer.ComposerError):  # type: ignore[misc]
    """An anchor or alias in a map_server YAML."""


class _NoAliasLoader(yaml.SafeLoader):  # type: ignore[misc]
    """PyYAML's safe loader, refusing anchors and aliases."""

    def compose_node(self, parent: Any, index: Any) -> Any:
        event = self.peek_event()
        if isinstance(event, yaml.AliasEvent) or getattr(event, "anchor", None) is not None:
            raise _AliasRefused(
                None,
                None,
                "anchors and aliases (&name, *name) are not allowed in a map_server YAML",
                event.start_mark,
            )
        return super().compose_node(parent, index)


def load_yaml(path: Path) -> Any:
    """The YAML document of ``path``: at most :data:`MAX_YAML_BYTES`, UTF-8, no anchors or
    aliases; errors in one line."""
    where = str(path)
    try:
        with path.open("rb") as f:
            raw = f.read(MAX_YAML_BYTES + 1)
    except OSError as exc:
        raise MapImportError(f"{where}: cannot read: {brief(exc.strerror or exc)}") from None
    if len(raw) > MAX_YAML_BYTES:
        raise MapImportError(
            f"{where}: larger than {MAX_YAML_BYTES // 1024} KiB: not a map_server YAML "
            "(which is a few lines)"
        )
    text = utf8(raw, where, "a YAML file")
    try:
        return yaml.load(text, Loader=_NoAliasLoader)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        at = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
        problem = exc.problem or exc.context or "cannot be parsed"
        what = "not a map_server YAML" if isinstance(exc, _AliasRefused) else "not a YAML file"
        raise MapImportError(f"{where}: {what}: {at}{brief(problem)}") from None
    except yaml.YAMLError as exc:
        raise MapImportError(f"{where}: not a YAML file: {brief(exc)}") from None
    except RecursionError:
        raise MapImportError(f"{where}: not a map_server YAML: nested too deeply") from None
    except (ValueError, OverflowError) as exc:  # an integer of too many digits, a bad date
        raise MapImportError(
            f"{where}: not a map_server YAML: a value cannot be read ({brief(exc, 80)})"
        ) from None


def image_inside(path: Path, image: str) -> Path:
    """The file ``image`` names, relative to the YAML file ``path`` (or absolute), if it is
    in that file's folder or below it, before and after following symbolic links; the same
    error whether or not a file outside exists."""
    folder = os.path.abspath(path.parent)
    real_folder = os.path.realpath(folder)
    named = os.path.normpath(os.path.join(folder, image))  # os.path.join keeps an absolute one
    real = os.path.realpath(named)
    if not (_within(named, folder) and _within(real, real_folder)):
        raise MapImportError(
            f"{path}: image {shorten(image)} is not inside the YAML file's folder "
            f"({folder}): only an image in that folder or below it is read"
        )
    if not os.path.isfile(real):
        raise MapImportError(f"{path}: image {shorten(image)} not found in {folder}")
    return Path(real)


def _within(child: str, folder: str) -> bool:
    return os.path.commonpath([child, folder]) == folder


def read_ros(path: Path, *, merge: int = 1, budget: MemoryBudget | None = None) -> Imported:
    k = merge
    where = str(path)
    meta = load_yaml(path)
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
    if not isinstance(origin, list) or len(origin) != 3 or not all(_finite(v) for v in origin):
        raise MapImportError(
            f"{where}: origin must be [x, y, yaw] (three numbers), got {shorten(origin)}"
        )
    occupied = _number(meta, "occupied_thresh", where)
    free_t = _number(meta, "free_thresh", where)
    if not 0 <= free_t <= occupied <= 1:
        raise MapImportError(
            f"{where}: need 0 <= free_thresh <= occupied_thresh <= 1, "
            f"got free_thresh {free_t}, occupied_thresh {occupied}"
        )
    negate = meta["negate"]
    if negate not in (0, 1, True, False):
        raise MapImportError(f"{where}: negate must be 0 or 1, got {shorten(negate)}")
    mode = meta.get("mode", "trinary")
    if not isinstance(mode, str) or mode.lower() not in ("trinary", "scale", "raw"):
        raise MapImportError(f"{where}: mode {shorten(mode)}: use trinary, scale or raw")
    mode = mode.lower()
    image = meta["image"]
    if not isinstance(image, str) or not image or "\0" in image:
        raise MapImportError(f"{where}: image must be a file name, got {shorten(image)}")
    grey, _ = read_image(image_inside(path, image), budget or MemoryBudget(), k)
    h, w = grey.shape
    # each grey level's occupancy, as map_server computes it, looked up for every pixel
    level = np.arange(256, dtype=np.float64)
    if mode == "raw":
        known = level <= 100
        p = level / 100.0
    else:
        p = level / 255.0 if negate else (255.0 - level) / 255.0
        known = np.ones(256, dtype=bool)
    blocked = (known & (p > occupied))[grey]
    free = (known & (p < free_t))[grey]
    del grey
    n_free, n_blocked = int(free.sum()), int(blocked.sum())  # never both: free_t <= occupied
    cells = merge_cells(free, blocked, k)
    del free, blocked
    frame = Frame(resolution * k, (float(origin[0]), float(origin[1]), float(origin[2])))
    notes = [
        f"ROS map {w}x{h} pixels at {resolution:g} m ({n_free} free, "
        f"{n_blocked} occupied, {w * h - n_free - n_blocked} unknown)"
    ]
    if k > 1:
        notes.append(
            f"merged {k}x{k} pixels per cell: {cells.shape[1]}x{cells.shape[0]} cells"
            f" of {resolution * k:g} m"
        )
    return Imported(cells, frame, notes)
