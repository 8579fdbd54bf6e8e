"""MazeScene against a real viser server (no browser): which nodes exist and what they hold."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
import viser
from viser import BatchedMeshHandle

from app.domain.grid import N_ACTIONS, GridDomain
from app.viewer import geometry as geo
from app.viewer.scene import LAYERS, WALL_HEIGHT, MazeScene, top_down_camera
from tests.viewer.conftest import walk


@pytest.fixture
def scene(server: viser.ViserServer, domain: GridDomain, theta: np.ndarray) -> Iterator[MazeScene]:
    maze = MazeScene(server, domain, theta)
    yield maze
    maze.remove()


def nodes(server: viser.ViserServer) -> set[str]:
    return set(server.scene._handle_from_node_name)


def test_scene_draws_walls_as_one_batched_mesh(scene: MazeScene, domain: GridDomain) -> None:
    assert {"/maze/walls", "/maze/floor", "/maze/start", "/maze/goals"} <= nodes(scene.server)
    assert scene.walls is not None  # instances: a small map
    walls = scene.walls.batched_positions
    assert walls.shape == (int(domain.walls.sum()), 3)
    expected = geo.cell_centres(domain, np.argwhere(domain.walls))[:, :2]
    np.testing.assert_allclose(walls[:, :2], expected, atol=1e-6)
    labels = {n for n in nodes(scene.server) if n.startswith("/maze/goal_labels/")}
    assert len(labels) == len(domain.goals)


def test_scene_prior_arrows_follow_theta(
    scene: MazeScene, domain: GridDomain, theta: np.ndarray
) -> None:
    arrows = scene.prior_arrows
    assert arrows is not None
    assert arrows.batched_positions.shape == (domain.n_states * N_ACTIONS, 3)
    assert arrows.batched_scales is not None
    np.testing.assert_allclose(arrows.batched_scales[:, 0], geo.ARROW_REACH * theta.ravel(), 1e-6)
    new = np.roll(theta, 1, axis=1)
    scene.set_prior(new)
    assert arrows.batched_scales is not None and arrows.batched_opacities is not None
    np.testing.assert_allclose(arrows.batched_scales[:, 0], geo.ARROW_REACH * new.ravel(), 1e-6)
    np.testing.assert_allclose(arrows.batched_opacities, geo.arrow_opacity(new.ravel()), 1e-6)


def test_scene_shading_marks_exactly_the_advised_cells(scene: MazeScene, theta: np.ndarray) -> None:
    for kappa, p in [(0.0, 0.0), (0.3, 0.0), (0.3, 0.6), (1.39, 0.0)]:
        count = scene.shade(theta, kappa, p)
        expected = geo.advised_cells(theta, kappa, p)
        assert count == int(expected.sum())
        assert isinstance(scene.shading, BatchedMeshHandle)
        opacities = scene.shading.batched_opacities
        assert opacities is not None and np.array_equal(opacities > 0, expected)
    assert scene.shade(theta, 0.0) == len(theta)  # kappa = 0: advise everywhere


def test_scene_draws_sessions_and_removes_them(
    scene: MazeScene, domain: GridDomain, theta: np.ndarray
) -> None:
    rng = np.random.default_rng(1)
    sessions = [walk(domain, theta, f"s{i}", 40, rng, kappa=0.05) for i in range(3)]
    assert scene.update_sessions(sessions, picked="s1")
    drawn: dict[str, Any] = scene.session_nodes  # handles of several kinds
    assert {"/paths/lines", "/markers/points", "/advice/arrows", "/markers/picked"} <= set(drawn)
    assert drawn["/markers/points"].points.shape == (3, 3)
    here = geo.cell_centres(domain, [sessions[1].position])[0, :2]
    points = np.asarray(drawn["/markers/points"].points, dtype=np.float64)
    assert np.isclose(points[:, :2], here, atol=1e-3).all(axis=1).any()
    # arrows start at cells where advice was given
    starts = drawn["/advice/arrows"].points[:, 0, :2]
    advised = geo.cell_centres(domain, [cell for s in sessions for _, cell, _ in s.advice])[:, :2]
    assert all(np.isclose(advised, p, atol=1e-5).all(axis=1).any() for p in starts)
    assert not scene.update_sessions(sessions, picked="s1")  # nothing new: nothing redrawn
    assert scene.update_sessions([], picked=None)
    assert scene.session_nodes == {}
    assert not {"/paths/lines", "/markers/points", "/advice/arrows"} & nodes(scene.server)


def test_scene_sessions_keep_distinct_colours_while_they_live(
    scene: MazeScene, domain: GridDomain, theta: np.ndarray
) -> None:
    rng = np.random.default_rng(2)
    sessions = [walk(domain, theta, f"c{i}", 3, rng) for i in range(5)]
    scene.update_sessions(sessions)
    colours = {s.session_id: scene.colour(s.session_id) for s in sessions}
    assert len(set(colours.values())) == 5
    scene.update_sessions(sessions[2:])
    assert all(scene.colour(s.session_id) == colours[s.session_id] for s in sessions[2:])


def test_scene_layers_toggle_their_frames(scene: MazeScene) -> None:
    for layer in LAYERS:
        scene.set_layer(layer, False)
        assert not scene.frames[layer].visible
        scene.set_layer(layer, True)
        assert scene.frames[layer].visible
    with pytest.raises(ValueError, match="unknown layer"):
        scene.set_layer("ceiling", True)


def test_top_down_camera_looks_straight_down_with_north_up(domain: GridDomain) -> None:
    position, look_at, up = top_down_camera(domain, fov=1.2, aspect=1.5)
    rows, cols = domain.shape
    assert look_at.tolist() == [cols / 2, rows / 2, 0.0]
    assert position[:2].tolist() == look_at[:2].tolist()
    assert position[2] == geo.fit_height(rows, cols, 1.2, 1.5, top=WALL_HEIGHT)
    assert up.tolist() == [0.0, 1.0, 0.0]
