"""Geometry on a building of several floors: each floor at its height, the connections between
stops, arrows for U and D, the kappa shading over six actions, the camera that sees every floor."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.advice.advisor import Advisor
from app.advice.models import AdviceTables
from app.domain.building import Building, D, U
from app.domain.floorplans import STOREY_HEIGHT, generate_floors
from app.domain.grid import Frame, GridDomain
from app.viewer import geometry as geo
from app.viewer import storeys

seeds = st.integers(0, 2**32 - 1)


def rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``v`` rotated by the unit quaternion ``q`` (w, x, y, z): q v q*."""
    conjugate = q * np.array([1.0, -1.0, -1.0, -1.0])
    return geo.quaternion_product(geo.quaternion_product(q, np.array([0.0, *v])), conjugate)[1:]


def with_elevations(building: Building, heights: list[float | None]) -> Building:
    floors = [replace(f, elevation=h) for f, h in zip(building.floors, heights, strict=True)]
    return Building(tuple(floors), building.connections, name=building.name)


def test_floors_stack_at_their_elevations_scaled_alike(tower: Building) -> None:
    """The tower's floors are 4 m apart on 20 x 20 cells of 1 m: drawn to scale they would be
    4 units apart, so every height is stretched until the storey is STOREY_SHARE of the rows."""
    share = storeys.STOREY_SHARE
    levels = storeys.floor_levels(tower)
    assert [f.elevation for f in tower.floors] == [0.0, STOREY_HEIGHT]
    assert storeys.metres_to_units(tower) == pytest.approx(share * 20 / 4.0)
    np.testing.assert_allclose(levels, [0.0, share * 20])
    # a frame of 0.05 m cells: to scale (80 units) is already far enough apart, and kept
    fine = Building(tower.floors, tower.connections, frame=Frame(0.05))
    np.testing.assert_allclose(storeys.floor_levels(fine), [0.0, 80.0])
    assert storeys.floor_levels(GridDomain.from_strings(["S.G"])).tolist() == [0.0]


def test_floors_without_elevation_are_placed_between_or_a_storey_beyond() -> None:
    b = generate_floors(20, 20, 4, np.random.default_rng(1), n_goals=1)
    assert storeys.elevations(with_elevations(b, [None] * 4)).tolist() == [0.0, 4.0, 8.0, 12.0]
    given_ = with_elevations(b, [None, 3.0, None, 9.0])
    assert storeys.elevations(given_).tolist() == [-1.0, 3.0, 6.0, 9.0]
    levels = storeys.floor_levels(given_)
    assert levels[0] == 0.0 and np.all(np.diff(levels) > 0)
    # proportions kept: the smallest gap (3 m) is STOREY_SHARE of the rows (20)
    least = storeys.STOREY_SHARE * 20
    np.testing.assert_allclose(np.diff(levels), np.array([4.0, 3.0, 3.0]) * least / 3.0)


def test_cell_centres_on_a_building_lie_on_their_floor(tower: Building) -> None:
    levels = storeys.floor_levels(tower)
    cells = tower.cells
    centres = geo.cell_centres(tower, cells, z=0.25)
    one_floor = GridDomain.from_strings(tower.floors[0].rows)
    np.testing.assert_allclose(centres[:, :2], geo.cell_centres(one_floor, cells[:, 1:])[:, :2])
    np.testing.assert_allclose(centres[:, 2], levels[cells[:, 0]] + 0.25)
    assert geo.floor_of(tower, cells).tolist() == cells[:, 0].tolist()
    assert geo.floor_at(tower, centres[:, 2]).tolist() == cells[:, 0].tolist()
    top = storeys.floor_levels(tower)[1]
    assert geo.floor_at(tower, [-3.0, top - 0.1, top, 500.0]).tolist() == [0, 0, 1, 1]
    parts = geo.floor_states(tower)
    assert [p.start for p in parts] == [0, int((cells[:, 0] == 0).sum())]
    assert parts[-1].stop == tower.n_states
    assert all(np.all(cells[p, 0] == f) for f, p in enumerate(parts))


@given(seeds)
@settings(max_examples=20, deadline=None)
def test_action_directions_follow_the_moves_and_rides(seed: int) -> None:
    """Every move's shift of a cell's centre points along ACTION_DIRECTIONS: the compass moves
    by one cell, U straight up by a storey, D straight down."""
    rng = np.random.default_rng(seed)
    b = generate_floors(20, 20, int(rng.integers(2, 4)), rng, n_goals=1)
    s = np.arange(b.n_states)
    for a in range(6):
        moved = b.next_state[s, a] != s
        shift = geo.cell_centres(b, b.cells[b.next_state[s[moved], a]]) - geo.cell_centres(
            b, b.cells[s[moved]]
        )
        length = np.linalg.norm(shift, axis=1, keepdims=True)
        along = np.tile(geo.ACTION_DIRECTIONS[a], (len(shift), 1))
        np.testing.assert_allclose(shift / length, along, atol=1e-12)
        if a < 4:
            np.testing.assert_allclose(length, 1.0)
    assert (b.next_state[:, U] != s).any() and (b.next_state[:, D] != s).any()


def test_action_rotations_turn_the_flat_arrow_along_each_action() -> None:
    for q, direction in zip(geo.ACTION_ROTATIONS, geo.ACTION_DIRECTIONS, strict=True):
        assert np.linalg.norm(q) == pytest.approx(1.0)
        np.testing.assert_allclose(rotate(q, np.array([1.0, 0.0, 0.0])), direction, atol=1e-12)
    # U and D stand in the x-z plane: seen from the south (the oblique camera), not edge on
    for q in geo.ACTION_ROTATIONS[4:]:
        np.testing.assert_allclose(np.abs(rotate(q, np.array([0.0, 0.0, 1.0]))), [0, 1, 0],
                                   atol=1e-12)  # fmt: skip
    # the compass rotations are z_rotations' as before
    np.testing.assert_array_equal(geo.ACTION_ROTATIONS[:4], geo.z_rotations(geo.ACTION_ANGLES))


def test_a_connections_segments_join_its_stops_floor_to_floor(tower: Building) -> None:
    for index, c in enumerate(tower.connections):
        stops = geo.cell_centres(tower, c.stops, 0.05)
        straight = geo.connection_segments(tower, index, 0, 0.05)
        np.testing.assert_allclose(straight, np.stack([stops[:-1], stops[1:]], axis=1))
        stairs = geo.connection_segments(tower, index, 2, 0.05)
        assert stairs.shape == (4 * (len(c.stops) - 1), 2, 3)
        np.testing.assert_allclose(stairs[0, 0], stops[0])
        np.testing.assert_allclose(stairs[-1, 1], stops[-1])
        np.testing.assert_allclose(stairs[1:, 0], stairs[:-1, 1])  # one unbroken line
        assert np.all(np.diff(stairs[:, :, 2].ravel()) >= 0)  # always climbing
        # zigzagging across its cell, never out of it
        assert np.all(np.abs(stairs[:, :, 0] - stops[0, 0]) <= geo.FLIGHT_SWING + 1e-12)
        assert np.ptp(stairs[:, :, 0]) == pytest.approx(2 * geo.FLIGHT_SWING)


def test_advice_arrows_draw_up_and_down_straight_up_and_down(tower: Building) -> None:
    stop = tower.connections[0].stops[0]
    probabilities = np.array([[0.05, 0.05, 0.05, 0.05, 0.7, 0.1]])
    points, row = geo.advice_arrows(tower, [stop], probabilities, reach=0.8, min_p=0.08)
    assert row.tolist() == [0, 0]  # U and D only: the compass moves are under min_p
    start = geo.cell_centres(tower, [stop])[0]
    np.testing.assert_allclose(points[:, 0], [start, start])
    np.testing.assert_allclose(points[0, 1], start + np.array([0.0, 0.0, 0.8 * 0.7]))
    np.testing.assert_allclose(points[1, 1], start - np.array([0.0, 0.0, 0.8 * 0.1]))


def test_prior_arrows_on_a_building_six_per_cell(tower: Building, tower_theta: np.ndarray) -> None:
    positions, wxyzs, scales, _ = geo.prior_arrows(tower, tower_theta)
    assert positions.shape == (6 * tower.n_states, 3)
    s = tower.n_states - 1  # on the upper floor
    np.testing.assert_allclose(
        positions[6 * s + U], geo.cell_centres(tower, [tower.cell(s)], 0.02)[0]
    )
    np.testing.assert_allclose(wxyzs[6 * s + D], geo.ACTION_ROTATIONS[D])
    np.testing.assert_allclose(scales[:, 0], geo.ARROW_REACH * tower_theta.ravel())
    with pytest.raises(ValueError, match=r"theta must have shape \(\d+, 6\)"):
        geo.prior_arrows(tower, tower_theta[:, :4])


def test_path_segments_on_a_building_ride_from_floor_to_floor(tower: Building) -> None:
    (f0, r, c), (f1, r1, c1) = tower.connections[0].stops[:2]
    path = [(f0, r + 1, c), (f0, r, c), (f1, r1, c1), (f1, r1, c1)]
    if tower.state_of[f0, r + 1, c] < 0:
        path[0] = (f0, r - 1, c)
    segments, owner, age = geo.path_segments(tower, [path], z=0.1)
    assert len(segments) == 2 and owner.tolist() == [0, 0]
    np.testing.assert_allclose(segments[1], geo.cell_centres(tower, path[1:3], 0.1))
    assert geo.floor_at(tower, segments[:, 0, 2]).tolist() == [f0, f0]  # a ride leaves floor 0
    assert segments[1, 1, 2] - segments[1, 0, 2] == pytest.approx(storeys.floor_levels(tower)[1])
    np.testing.assert_allclose(age, [1 / 3, 2 / 3])


@given(seeds, st.floats(0.0, 1.4))
@settings(max_examples=25, deadline=None)
def test_kl_to_expected_over_six_actions_matches_the_advisor(seed: int, kappa: float) -> None:
    """On a building the shading compares the KL over six actions, in four actions' units
    (kl_scale), with kappa, as the advisor does: its start decisions at P(M1 | H) = 1/2."""
    rng = np.random.default_rng(seed)
    theta = rng.dirichlet(np.full(6, rng.choice([0.1, 1.0, 10.0])), size=30)
    theta[rng.random(30) < 0.2] = 1 / 6
    advisor = Advisor(AdviceTables.paper(theta), kappa=kappa)
    decisions = [advisor.decide(s) for s in range(len(theta))]
    np.testing.assert_allclose(geo.kl_to_expected(theta, 0.5), [d.kl for d in decisions],
                               rtol=1e-9, atol=1e-12)  # fmt: skip
    mask = geo.advised_cells(theta, kappa, p_normal=0.5)
    clear = np.array([abs(d.kl - kappa) > 1e-9 for d in decisions])
    assert np.array_equal(mask[clear], np.array([d.advise for d in decisions])[clear])
    certain = np.zeros((1, 6))
    certain[0, 0] = 1.0
    assert geo.kl_to_expected(certain, 0.0)[0] == pytest.approx(math.log(4))


@given(st.floats(0.3, 2.5), st.floats(0.3, 4.0), st.integers(5, 200), st.integers(5, 200),
       st.floats(1.0, 300.0))  # fmt: skip
def test_stack_camera_sees_every_corner_and_fills_the_view(
    fov: float, aspect: float, rows: int, cols: int, height: float
) -> None:
    corners = np.array([[x, y, z] for x in (0, cols) for y in (0, rows) for z in (0, height)])
    position, look_at, up = storeys.stack_camera(corners, fov, aspect, margin=1.04)
    np.testing.assert_allclose(look_at, [cols / 2, rows / 2, height / 2])
    assert up.tolist() == [0.0, 0.0, 1.0]
    forward = (look_at - position) / np.linalg.norm(look_at - position)
    assert forward[1] > 0 and forward[2] < 0  # looking north and down
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    true_up = np.cross(right, forward)
    p = corners - position
    depth = p @ forward
    ndc = np.stack([p @ right / (depth * math.tan(fov / 2) * aspect),
                    p @ true_up / (depth * math.tan(fov / 2))], axis=1)  # fmt: skip
    assert np.all(depth > 0)
    assert np.abs(ndc).max() == pytest.approx(1 / 1.04)
