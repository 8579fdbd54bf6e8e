"""Helpers for the IMDF tests: the sample hospital written into a test's folder, changed at
will, and the cells of a rectangle of its plan."""

from __future__ import annotations

import copy
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np

from app.mapio.imdf.sample import DEPTH, WIDTH, fid, hospital, write_archive
from app.mapio.venue import Venue

_DOCS = hospital()


def docs() -> dict[str, Any]:
    """A fresh copy of the hospital's documents, to change."""
    return copy.deepcopy(_DOCS)


def write(tmp_path: Path, documents: dict[str, Any] | None = None, zipped: bool = True) -> Path:
    name = "hospital.zip" if zipped else "hospital"
    return write_archive(documents if documents is not None else docs(), tmp_path / name)


def features(documents: dict[str, Any], name: str) -> list[dict[str, Any]]:
    out: list[dict[str, Any]] = documents[f"{name}.geojson"]["features"]
    return out


def drop(documents: dict[str, Any], name: str, feature_id: str) -> None:
    documents[f"{name}.geojson"]["features"] = [
        f for f in features(documents, name) if f["id"] != feature_id
    ]


def unit_id(ordinal: int, key: str) -> str:
    return fid("unit", ordinal, key)


def box_cells(
    venue: Venue, box: tuple[float, float, float, float], shrink: float = 0.0
) -> set[tuple[int, int]]:
    """The cells whose centre lies in a rectangle of the plan (metres from the building's
    south-west corner), shrunk by ``shrink`` metres on every side."""
    x0, y0, x1, y1 = box
    rows, cols = venue.shape
    out: set[tuple[int, int]] = set()
    for r in range(rows):
        for c in range(cols):
            x, y = venue.frame.centre(r, c, rows)
            bx, by = x + WIDTH / 2, y + DEPTH / 2
            if x0 + shrink < bx < x1 - shrink and y0 + shrink < by < y1 - shrink:
                out.add((r, c))
    return out


def reachable(free: np.ndarray, start: tuple[int, int]) -> set[tuple[int, int]]:
    """The free cells a 4-connected walk from ``start`` reaches."""
    seen = {start}
    todo = deque([start])
    rows, cols = free.shape
    while todo:
        r, c = todo.popleft()
        for dr, dc in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            n = (r + dr, c + dc)
            if 0 <= n[0] < rows and 0 <= n[1] < cols and free[n] and n not in seen:
                seen.add(n)
                todo.append(n)
    return seen
