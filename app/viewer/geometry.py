"""Geometry for the maze scene: cell coordinates, meshes, and per-instance arrays.

The map lies in the z = 0 plane with z up; cell ``(row, col)`` has its centre at
``x = col + 0.5, y = rows - row - 0.5``, so row 0 is at the top of a top-down view and north
(action N) points to +y. One scene unit is one cell. On a building (a map of several floors)
cell ``(floor, row, col)`` has the same x and y, and floor ``floor`` lies in the plane
``z = floor_levels(building)[floor]`` (:mod:`app.viewer.storeys` says how metres become scene
units); actions U and D point to +z and -z. Every function here takes either kind of domain
and its cells (``[row, col]`` or ``[floor, row, col]``). Everything is numpy only, so it is
tested without a browser.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from itertools import chain, pairwise

import numpy as np
import numpy.typing as npt

from app.advice.models import kl_scale
from app.arrays import BoolArray, FloatArray, IntArray
from app.domain.building import Building, Domain
from app.viewer.storeys import floor_levels

#: Heading of each action in the plane (radians from +x), in the order N, E, S, W.
ACTION_ANGLES = np.array([np.pi / 2, 0.0, -np.pi / 2, np.pi])
#: Unit vector of each action in the plane, (4, 2).
ACTION_VECTORS = np.stack([np.cos(ACTION_ANGLES), np.sin(ACTION_ANGLES)], axis=1).round(12)
#: Unit vector of each action in the scene, (6, 3): N, E, S, W in the plane, U up, D down.
ACTION_DIRECTIONS = np.vstack(
    [np.column_stack([ACTION_VECTORS, np.zeros(4)]), [[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]]]
)
#: How far from a cell's centre an arrow with probability 1 reaches (in cells).
ARROW_REACH = 0.48
#: How far from the cell's centre a flight of stairs swings (cells).
FLIGHT_SWING = 0.3


def cell_centres(domain: Domain, cells: npt.ArrayLike, z: float = 0.0) -> FloatArray:
    """World coordinates (N, 3) of the centres of ``cells`` ((N, 2) rows and columns, or on a
    building (N, 3) floors, rows and columns), ``z`` above their floor."""
    width = domain.width
    fc = np.asarray(cells, dtype=np.float64).reshape(-1, width)
    rows = domain.shape[-2]
    out = np.empty((fc.shape[0], 3))
    out[:, 0] = fc[:, -1] + 0.5
    out[:, 1] = rows - fc[:, -2] - 0.5
    out[:, 2] = z
    if width == 3:
        out[:, 2] += floor_levels(domain)[fc[:, 0].astype(np.int64)]
    return out


def floor_of(domain: Domain, cells: npt.ArrayLike) -> IntArray:
    """The floor (index) of each of ``cells``: 0 for every cell of a one-floor map."""
    fc = np.asarray(cells, dtype=np.int64).reshape(-1, domain.width)
    out: IntArray = fc[:, 0].copy() if domain.width == 3 else np.zeros(len(fc), dtype=np.int64)
    return out


def floor_at(domain: Domain, z: npt.ArrayLike) -> IntArray:
    """The floor each height ``z`` of the scene stands on: the highest floor at or below it
    (the lowest floor for what lies below every floor)."""
    levels = floor_levels(domain)
    at = np.searchsorted(levels, np.asarray(z, dtype=np.float64), side="right") - 1
    out: IntArray = np.maximum(at, 0).astype(np.int64)
    return out


def floor_states(domain: Domain) -> list[slice]:
    """The states of each floor, lowest first: a building numbers its states floor by floor,
    so each floor's are one slice (a one-floor map's: all of them)."""
    if domain.width == 2:
        return [slice(0, domain.n_states)]
    bounds = np.searchsorted(domain.cells[:, 0], np.arange(domain.shape[0] + 1))
    return [slice(int(lo), int(hi)) for lo, hi in pairwise(bounds)]


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


def quaternion_product(q: npt.ArrayLike, r: npt.ArrayLike) -> FloatArray:
    """The rotation ``r`` then ``q`` (Hamilton product q r), quaternions as w, x, y, z."""
    w1, x1, y1, z1 = np.asarray(q, dtype=np.float64)
    w2, x2, y2, z2 = np.asarray(r, dtype=np.float64)
    return np.array([
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
    ])  # fmt: skip


def _upright(angle: float) -> FloatArray:
    """Stand a flat arrow (along +x in the z = 0 plane) up in the x-z plane, then turn it by
    ``angle`` about y: -pi/2 points it up, pi/2 down (seen from the south, the oblique view)."""
    half = math.pi / 4
    stand = np.array([math.cos(half), math.sin(half), 0.0, 0.0])  # pi/2 about x
    turn = np.array([math.cos(angle / 2), 0.0, math.sin(angle / 2), 0.0])
    return quaternion_product(turn, stand)


#: The rotation of a flat arrow (:func:`flat_arrow_mesh`) for each action, (6, 4): N, E, S, W
#: about z, U and D standing in the x-z plane pointing up and down.
ACTION_ROTATIONS = np.vstack(
    [z_rotations(ACTION_ANGLES), _upright(-math.pi / 2), _upright(math.pi / 2)]
)


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


def wall_cells(domain: Domain) -> IntArray:
    """(N, 2) rows and columns of the walls (on a building (N, 3), floor by floor)."""
    return np.argwhere(domain.walls).astype(np.int64)


def prior_arrows(
    domain: Domain, theta: npt.ArrayLike, z: float = 0.02
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """One flat arrow per free cell and action, for :func:`flat_arrow_mesh`.

    Returns positions (S*A, 3), orientations (S*A, 4), per-axis scales (S*A, 3) whose length
    is ``ARROW_REACH * theta_s(a)``, and opacities (S*A,) that also grow with ``theta_s(a)``.
    Instance ``A * s + a`` is action ``a`` of state ``s`` (A: the domain's actions, 4 or 6;
    U and D stand upright, :data:`ACTION_ROTATIONS`).
    """
    th = np.asarray(theta, dtype=np.float64)
    n, a = domain.n_states, domain.n_actions
    if th.shape != (n, a):
        raise ValueError(f"theta must have shape ({n}, {a}), got {th.shape}")
    positions = np.repeat(cell_centres(domain, domain.cells, z), a, axis=0)
    wxyzs = np.tile(ACTION_ROTATIONS[:a], (n, 1))
    p = th.ravel()
    scales = np.stack([ARROW_REACH * p, np.full_like(p, 0.45), np.ones_like(p)], axis=1)
    return positions, wxyzs, scales, arrow_opacity(p)


def arrow_opacity(p: npt.ArrayLike) -> FloatArray:
    """Opacity of an arrow drawn for probability ``p``: faint when unlikely, solid when sure."""
    return np.clip(0.15 + 0.85 * np.asarray(p, dtype=np.float64), 0.0, 1.0)


def path_segments(
    domain: Domain, paths: Sequence[Sequence[tuple[int, ...]]], z: float = 0.0
) -> tuple[FloatArray, IntArray, FloatArray]:
    """Line segments joining consecutive cells of each path, for all paths in one pass.

    Returns segments (N, 2, 3), the path each belongs to (N,), and its age along its path
    (N,): 1 for the segment reaching the newest cell, near 0 for the oldest. Steps that stayed
    put (a bump into a wall) make no segment; a ride is a segment from floor to floor.
    """
    width = domain.width
    lengths = np.fromiter((len(p) for p in paths), dtype=np.int64, count=len(paths))
    total = int(lengths.sum())
    flat = np.fromiter(chain.from_iterable(chain.from_iterable(paths)), np.float64, width * total)
    points = cell_centres(domain, flat.reshape(-1, width), z)
    owner = np.repeat(np.arange(len(paths)), lengths)
    index = np.arange(total) - np.repeat(np.cumsum(lengths) - lengths, lengths)
    keep = (owner[1:] == owner[:-1]) & np.any(points[1:] != points[:-1], axis=1)
    segments = np.stack([points[:-1], points[1:]], axis=1)[keep]
    seg_owner = owner[1:][keep]
    age = index[1:][keep] / np.maximum(lengths - 1, 1)[seg_owner]
    return segments, seg_owner, age


def advice_arrows(
    domain: Domain,
    cells: npt.ArrayLike,
    probabilities: npt.ArrayLike,
    reach: float,
    min_p: float,
    z: float = 0.0,
) -> tuple[FloatArray, IntArray]:
    """Arrows for advice given at ``cells`` (N, 2) with ``probabilities`` (N, 4) (on a
    building (N, 3) and (N, 6)): from the cell's centre towards each action (U straight up, D
    straight down), ``reach * p`` long, for actions with ``p >= min_p``.

    Returns start/end points (M, 2, 3) and, for each arrow, the row of ``cells`` it belongs to.
    """
    a = domain.n_actions
    fc = np.asarray(cells, dtype=np.float64).reshape(-1, domain.width)
    p = np.asarray(probabilities, dtype=np.float64).reshape(-1)
    start = np.repeat(cell_centres(domain, fc, z), a, axis=0)
    end = start + np.tile(ACTION_DIRECTIONS[:a], (len(fc), 1)) * (reach * p)[:, None]
    keep = p >= min_p
    owner = np.repeat(np.arange(len(fc)), a)[keep]
    return np.stack([start[keep], end[keep]], axis=1), owner


def connection_segments(
    building: Building, index: int, flights: int = 0, z: float = 0.0
) -> FloatArray:
    """Line segments (M, 2, 3) of connection ``index``, ``z`` above the floors: from each stop
    to the next one up, straight (``flights`` 0: a lift, a ramp) or zigzagging across the cell
    (``flights`` flights up and back, as stairs go), the ends at the stops' centres."""
    stops = building.connections[index].stops
    parts = []
    for low, high in pairwise(cell_centres(building, stops, z)):
        n = 2 * flights if flights else 1
        t = np.linspace(0.0, 1.0, n + 1)[:, None]
        points = low + t * (high - low)
        if flights:
            swing = np.where(np.arange(n + 1) % 2 == 1, FLIGHT_SWING, -FLIGHT_SWING)
            swing[[0, -1]] = 0.0
            points[:, 0] += swing
        parts.append(np.stack([points[:-1], points[1:]], axis=1))
    return np.concatenate(parts) if parts else np.zeros((0, 2, 3))


def kl_to_expected(theta: npt.ArrayLike, p_normal: float) -> FloatArray:
    """KL[theta_s || P(A | s, H)] in nats for every state, when P(M1 | H) = ``p_normal``, over
    theta's A actions (4, or 6 on a building) in four actions' units, as the rule compares it
    with kappa (``kl_scale``: log 4 / log A, exactly 1 for four).

    P(A | s, H) = p_normal * theta_s + (1 - p_normal) / A                  # eq. (4)
    KL[theta_s || P(A | s, H)] = sum_a theta_s(a) log(theta_s(a) / P(a | s, H))  # eq. (6)
    """
    if not 0.0 <= p_normal <= 1.0:
        raise ValueError(f"p_normal must be in [0, 1], got {p_normal}")
    th = np.asarray(theta, dtype=np.float64)
    a = th.shape[1]
    mix = p_normal * th + (1.0 - p_normal) / a
    with np.errstate(divide="ignore", invalid="ignore"):
        terms = np.where(th > 0, th * (np.log(th) - np.log(mix)), 0.0)
    out: FloatArray = np.maximum(terms.sum(axis=1), 0.0)
    scale = kl_scale(a)
    return out if scale == 1.0 else out * scale


def advised_cells(theta: npt.ArrayLike, kappa: float, p_normal: float = 0.0) -> BoolArray:
    """States where an explorer with P(M1 | H) = ``p_normal`` would be advised at ``kappa``.

    With ``p_normal = 0`` (a lost explorer: the uniform model is certain) this is
    KL[theta_s || uniform] >= kappa, the most advice any explorer can get at ``kappa``.
    """
    mask: BoolArray = kl_to_expected(theta, p_normal) >= kappa
    return mask
