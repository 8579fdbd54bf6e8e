"""MazeScene against a real viser server (no browser): which nodes exist and what they hold."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import replace
from typing import Any

import numpy as np
import pytest
import viser
from viser import BatchedMeshHandle

from app.domain.building import Building
from app.domain.floorplans import generate_floors
from app.domain.grid import N_ACTIONS, GridDomain
from app.viewer import geometry as geo
from app.viewer.scene import DETAIL_CELLS, LAYERS, WALL_HEIGHT, MazeScene, top_down_camera
from app.viewer.storeys import floor_levels
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


@pytest.fixture
def stacked(
    server: viser.ViserServer, tower: Building, tower_theta: np.ndarray
) -> Iterator[MazeScene]:
    maze = MazeScene(server, tower, tower_theta)
    yield maze
    maze.remove()


def test_scene_stacks_a_buildings_floors_each_its_own_walls(
    stacked: MazeScene, tower: Building
) -> None:
    levels = floor_levels(tower)
    assert stacked.walls is None and len(stacked.floor_walls) == tower.n_floors == 2
    for f, walls in enumerate(stacked.floor_walls):
        assert walls.batched_positions.shape == (int(tower.walls[f].sum()), 3)
        np.testing.assert_allclose(walls.batched_positions[:, 2], levels[f] + WALL_HEIGHT / 2)
    names = nodes(stacked.server)
    for f, floor in enumerate(tower.floors):
        maze = {f"/maze/f{f}/{leaf}" for leaf in ("walls", "floor", "name", "stops")}
        assert maze | {f"/prior/f{f}/arrows", f"/shading/f{f}/cells"} <= names
        label = stacked.server.scene._handle_from_node_name[f"/maze/f{f}/name"]
        assert floor.name in label.text  # type: ignore[attr-defined]
    assert "/maze/f0/start" in names and "/maze/f1/start" not in names
    arrows = stacked.floor_arrows
    assert sum(len(a.batched_positions) for a in arrows) == 6 * tower.n_states


def test_scene_labels_each_destination_by_name_on_its_floor(
    stacked: MazeScene, tower: Building
) -> None:
    handles = stacked.server.scene._handle_from_node_name
    assert tower.goal_names is not None
    for i, (f, r, c) in enumerate(tower.goal_cells):
        label: Any = handles[f"/maze/f{f}/goal_labels/G{i}"]
        assert label.text == tower.goal_names[i]
        centre = geo.cell_centres(tower, [(f, r, c)])[0]
        np.testing.assert_allclose(label.position[:2], centre[:2], atol=1e-6)
        assert label.position[2] == pytest.approx(floor_levels(tower)[f] + 0.206)


def test_scene_labels_each_stop_by_its_connection_name(stacked: MazeScene, tower: Building) -> None:
    handles = stacked.server.scene._handle_from_node_name
    assert tower.connections
    for i, c in enumerate(tower.connections):
        assert c.name
        for f, r, col in c.stops:
            label: Any = handles[f"/maze/f{f}/stop_labels/C{i}"]
            assert label.text == c.name
            centre = geo.cell_centres(tower, [(f, r, col)])[0]
            np.testing.assert_allclose(label.position[:2], centre[:2], atol=1e-6)
    on = {f for c in tower.connections for f, _, _ in c.stops}
    labelled = {n.split("/")[2] for n in handles if "/stop_labels/" in n}
    assert labelled == {f"f{f}" for f in on}


def test_scene_draws_stairs_and_lifts_between_the_floors(
    stacked: MazeScene, tower: Building
) -> None:
    handles: Any = stacked.server.scene._handle_from_node_name
    lifts, stairs = handles["/maze/connections/lift"], handles["/maze/connections/stairs"]
    kinds = [c.kind for c in tower.connections]
    assert len(lifts.points) == kinds.count("lift")  # one straight shaft a lift
    assert len(stairs.points) == 4 * kinds.count("stairs")  # two flights up and back
    assert not np.array_equal(lifts.colors[0, 0], stairs.colors[0, 0])
    bottom, top = floor_levels(tower)[[0, -1]]
    assert np.allclose(np.sort(lifts.points[:, :, 2], axis=1), [bottom + 0.05, top + 0.05])


def test_scene_shows_one_floor_and_hides_the_others(
    stacked: MazeScene, tower: Building, tower_theta: np.ndarray
) -> None:
    walker = walk(tower, tower_theta, "up", 3, np.random.default_rng(4), kappa=0.0)
    upstairs = tower.state(*tower.connections[0].stops[1])
    here = tower.cell(upstairs)
    up = replace(
        walker, path=[here], position=here, advice=[(0, here, tuple(tower_theta[upstairs]))]
    )
    s = tower.start
    on = next(tower.step(s, a) for a in range(4) if tower.step(s, a) != s)
    ground = [tower.cell(s), tower.cell(on)]  # two cells of the ground floor
    other = replace(walker, session_id="down", path=ground, position=ground[-1], advice=[])
    assert stacked.update_sessions([up, other], picked="up")
    drawn: Any = stacked.session_nodes
    assert {"/markers/f0/points", "/markers/f1/points", "/markers/f1/picked",
            "/advice/f1/arrows", "/paths/f0/lines"} <= set(drawn)  # fmt: skip
    assert "/markers/f0/picked" not in drawn and "/paths/f1/lines" not in drawn
    assert drawn["/markers/f1/points"].points.shape == (1, 3)
    vertical = drawn["/advice/f1/arrows"].points
    assert np.isclose(vertical[:, 0, :2], vertical[:, 1, :2], atol=1e-6).all(axis=1).any()  # U, D
    stacked.show_floor(1)
    assert [frame.visible for frame in stacked.floor_frames[0]] == [False] * (len(LAYERS) + 1)
    assert all(frame.visible for frame in stacked.floor_frames[1])
    assert stacked.connections is not None and not stacked.connections.visible
    position, look_at, _ = stacked.camera(1.2, 1.5)
    assert look_at[2] == floor_levels(tower)[1] and position[:2].tolist() == look_at[:2].tolist()
    stacked.show_floor(None)
    assert all(frame.visible for frames in stacked.floor_frames for frame in frames)
    assert stacked.connections.visible
    position, look_at, up = stacked.camera(1.2, 1.5)
    assert up.tolist() == [0.0, 0.0, 1.0] and position[1] < look_at[1] < position[2]
    with pytest.raises(ValueError, match="no floor 2"):
        stacked.show_floor(2)


def test_scene_shades_a_buildings_cells_floor_by_floor(
    stacked: MazeScene, tower_theta: np.ndarray
) -> None:
    count = stacked.shade(tower_theta, 0.3, 0.0)
    expected = geo.advised_cells(tower_theta, 0.3, 0.0)
    assert count == int(expected.sum())
    opacities = np.concatenate([s.batched_opacities for s in stacked.floor_shading])  # type: ignore[union-attr]
    assert np.array_equal(opacities > 0, expected)


def test_scene_draws_a_big_building_as_an_image_a_floor(server: viser.ViserServer) -> None:
    big = generate_floors(80, 80, 3, np.random.default_rng(5), n_goals=2)
    assert big.n_states > DETAIL_CELLS
    theta = np.full((big.n_states, 6), 1 / 6)
    maze = MazeScene(server, big, theta)
    try:
        assert maze.shade(theta, 0.0) == big.n_states
        names = nodes(server)
        assert {
            "/maze/f0/image",
            "/maze/f2/image",
            "/shading/f0/image",
            "/shading/f2/image",
        } <= names
        assert maze.floor_walls == [] and maze.floor_arrows == []
    finally:
        maze.remove()
