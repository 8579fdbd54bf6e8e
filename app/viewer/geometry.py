"""Geometry for the maze scene: cell coordinates, meshes, and per-instance arrays.

The map lies in the z = 0 plane with z up; cell ``(row, col)`` has its centre at
``x = col + 0.5, y = rows - row - 0.5``, so row 0 is at the top of a top-down view and north
(action N) points to +y. Everything here is numpy only, so it is tested without a browser.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from itertools import chain

import numpy as np
import numpy.typing as npt

from app.arrays import BoolArray, FloatArray, IntArray
from app.domain.grid import N_ACTIONS, GridDomain

#: Heading of each action in the plane (radians from +x), in the order N, E, S, W.
ACTION_ANGLES = np.array([np.pi / 2, 0.0, -np.pi / 2, np.pi])
#: Unit vector of each action in the plane, (4, 2).
ACTION_VECTORS = np.stack([np.cos(ACTION_ANGLES), np.sin(ACTION_ANGLES)], axis=1).round(12)
#: How far from a cell's centre an arrow with probability 1 reaches (in cells).
ARROW_REACH = 0.48


def cell_centres(domain: GridDomain, cells: npt.ArrayLike, z: float = 0.0) -> FloatArray:
    """World coordinates (N, 3) of the centres of ``cells`` ((N, 2) rows and columns)."""
    rc = np.asarray(cells, dtype=np.float64).reshape(-1, 2)
    rows = domain.shape[0]
    out = np.empty((rc.shape[0], 3))
    out[:, 0] = rc[:, 1] + 0.5
    out[:, 1] = rows - rc[:, 0] - 0.5
    out[:, 2] = z
    return out


def fit_height(
    rows: int, cols: int, fov: float, aspect: float, top: float = 0.0, margin: float = 1.04
) -> float:
    """Height above the floor of a camera looking straight down at the middle of a
    ``rows`` x ``cols`` map, so that the map fills its view: the map's longer side (for the
    view's ``aspect``, width / height) spans ``1 / margin`` of the view, its parts ``top``
    above the floor (the tops of the walls, nearer the camera) included. ``fov`` is the
    vertical field of view in radians.

    At height h the view covers 2 (h - z) tan(fov / 2) vertically at height z, ``aspect``
    times that across; both must hold the map's extent times ``margin``.
    """
    if not 0.0 < fov < math.pi or not aspect > 0.0:
        raise ValueError(f"fov must be in (0, pi) and aspect positive, got {fov}, {aspect}")
    half_extent = margin * max(rows / 2, cols / (2 * aspect))
    return top + half_extent / math.tan(fov / 2)


def z_rotations(angles: npt.ArrayLike) -> FloatArray:
    """Quaternions (N, 4) as w, x, y, z for rotations by ``angles`` about the z axis."""
    half = np.asarray(angles, dtype=np.float64) / 2
    zeros = np.zeros_like(half)
    return np.stack([np.cos(half), zeros, zeros, np.sin(half)], axis=-1)


def box_mesh() -> tuple[FloatArray, IntArray]:
    """A unit cube centred on the origin: vertices (8, 3), outward-facing triangles (12, 3)."""
    v = np.array(
        [[x, y, z] for z in (-0.5, 0.5) for y in (-0.5, 0.5) for x in (-0.5, 0.5)],
        dtype=np.float64,
    )
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    faces = [(a, b, c) for a, b, c, _ in quads] + [(a, c, d) for a, _, c, d in quads]
    return v, np.array(faces, dtype=np.int64)


def flat_arrow_mesh(
    shaft: float = 0.3, head: float = 0.8, head_start: float = 0.55
) -> tuple[FloatArray, IntArray]:
    """A flat arrow in the z = 0 plane from x = 0 to x = 1 along +x, facing +z.

    ``shaft`` and ``head`` are full widths; per-instance scales stretch it to a probability.
    """
    s, h = shaft / 2, head / 2
    v = np.array(
        [[0, -s, 0], [head_start, -s, 0], [head_start, s, 0], [0, s, 0],
         [head_start, -h, 0], [1, 0, 0], [head_start, h, 0]],
        dtype=np.float64,
    )  # fmt: skip
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6]], dtype=np.int64)
    return v, faces


def wall_cells(domain: GridDomain) -> IntArray:
    """(N, 2) rows and columns of the walls."""
    return np.argwhere(domain.walls).astype(np.int64)


def prior_arrows(
    domain: GridDomain, theta: npt.ArrayLike, z: float = 0.02
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """One flat arrow per free cell and action, for :func:`flat_arrow_mesh`.

    Returns positions (S*4, 3), orientations (S*4, 4), per-axis scales (S*4, 3) whose length
    is ``ARROW_REACH * theta_s(a)``, and opacities (S*4,) that also grow with ``theta_s(a)``.
    Instance ``4 * s + a`` is action ``a`` of state ``s``.
    """
    th = np.asarray(theta, dtype=np.float64)
    if th.shape != (domain.n_states, N_ACTIONS):
        raise ValueError(f"theta must have shape ({domain.n_states}, 4), got {th.shape}")
    positions = np.repeat(cell_centres(domain, domain.cells, z), N_ACTIONS, axis=0)
    wxyzs = np.tile(z_rotations(ACTION_ANGLES), (domain.n_states, 1))
    p = th.ravel()
    scales = np.stack([ARROW_REACH * p, np.full_like(p, 0.45), np.ones_like(p)], axis=1)
    return positions, wxyzs, scales, arrow_opacity(p)


def arrow_opacity(p: npt.ArrayLike) -> FloatArray:
    """Opacity of an arrow drawn for probability ``p``: faint when unlikely, solid when sure."""
    return np.clip(0.15 + 0.85 * np.asarray(p, dtype=np.float64), 0.0, 1.0)


def path_segments(
    domain: GridDomain, paths: Sequence[Sequence[tuple[int, int]]], z: float = 0.0
) -> tuple[FloatArray, IntArray, FloatArray]:
    """Line segments joining consecutive cells of each path, for all paths in one pass.

    Returns segments (N, 2, 3), the path each belongs to (N,), and its age along its path
    (N,): 1 for the segment reaching the newest cell, near 0 for the oldest. Steps that stayed
    put (a bump into a wall) make no segment.
    """
    lengths = np.fromiter((len(p) for p in paths), dtype=np.int64, count=len(paths))
    total = int(lengths.sum())
    flat = np.fromiter(chain.from_iterable(chain.from_iterable(paths)), np.float64, 2 * total)
    points = cell_centres(domain, flat.reshape(-1, 2), z)
    owner = np.repeat(np.arange(len(paths)), lengths)
    index = np.arange(total) - np.repeat(np.cumsum(lengths) - lengths, lengths)
    keep = (owner[1:] == owner[:-1]) & np.any(points[1:] != points[:-1], axis=1)
    segments = np.stack([points[:-1], points[1:]], axis=1)[keep]
    seg_owner = owner[1:][keep]
    age = index[1:][keep] / np.maximum(lengths - 1, 1)[seg_owner]
    return segments, seg_owner, age


def advice_arrows(
    domain: GridDomain,
    cells: npt.ArrayLike,
    probabilities: npt.ArrayLike,
    reach: float,
    min_p: float,
    z: float = 0.0,
) -> tuple[FloatArray, IntArray]:
    """Arrows for advice given at ``cells`` (N, 2) with ``probabilities`` (N, 4): from the
    cell's centre towards each action, ``reach * p`` long, for actions with ``p >= min_p``.

    Returns start/end points (M, 2, 3) and, for each arrow, the row of ``cells`` it belongs to.
    """
    rc = np.asarray(cells, dtype=np.float64).reshape(-1, 2)
    p = np.asarray(probabilities, dtype=np.float64).reshape(-1)
    start = np.repeat(cell_centres(domain, rc, z), N_ACTIONS, axis=0)
    end = start.copy()
    end[:, :2] += np.tile(ACTION_VECTORS, (len(rc), 1)) * (reach * p)[:, None]
    keep = p >= min_p
    owner = np.repeat(np.arange(len(rc)), N_ACTIONS)[keep]
    return np.stack([start[keep], end[keep]], axis=1), owner


def kl_to_expected(theta: npt.ArrayLike, p_normal: float) -> FloatArray:
    """KL[theta_s || P(A | s, H)] in nats for every state, when P(M1 | H) = ``p_normal``.

    P(A | s, H) = p_normal * theta_s + (1 - p_normal) / 4                  # eq. (4)
    KL[theta_s || P(A | s, H)] = sum_a theta_s(a) log(theta_s(a) / P(a | s, H))  # eq. (6)
    """
    if not 0.0 <= p_normal <= 1.0:
        raise ValueError(f"p_normal must be in [0, 1], got {p_normal}")
    th = np.asarray(theta, dtype=np.float64)
    mix = p_normal * th + (1.0 - p_normal) / N_ACTIONS
    with np.errstate(divide="ignore", invalid="ignore"):
        terms = np.where(th > 0, th * (np.log(th) - np.log(mix)), 0.0)
    out: FloatArray = np.maximum(terms.sum(axis=1), 0.0)
    return out


def advised_cells(theta: npt.ArrayLike, kappa: float, p_normal: float = 0.0) -> BoolArray:
    """States where an explorer with P(M1 | H) = ``p_normal`` would be advised at ``kappa``.

    With ``p_normal = 0`` (a lost explorer: the uniform model is certain) this is
    KL[theta_s || uniform] >= kappa, the most advice any explorer can get at ``kappa``.
    """
    mask: BoolArray = kl_to_expected(theta, p_normal) >= kappa
    return mask
