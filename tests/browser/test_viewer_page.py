"""The viser viewer, reading the service over HTTP: a browser connects and its scene holds the
maze."""

from __future__ import annotations

import subprocess
import sys
from typing import Any

import numpy as np
import pytest
from playwright.sync_api import Page, expect

from app.domain.building import Building
from app.domain.floorplans import generate_floors
from app.viewer.controls import ALL_FLOORS, LAYER_LABELS, PLOT_TITLE
from app.viewer.storeys import floor_levels
from app.viewer.viewer import ClientView
from tests.browser.conftest import ADMIN, Service, screenshot, wait_until
from tests.viewer.conftest import choose

pytestmark = pytest.mark.browser

SCENE_NODES = {
    "/maze/walls", "/maze/floor", "/maze/start", "/maze/goals", "/prior/arrows",
    "/shading/cells", "/paths/lines", "/markers/points", "/advice/arrows",
}  # fmt: skip


def test_viewer_page_connects_and_shows_maze_prior_and_sessions(
    service: Service, page: Page
) -> None:
    sessions = [service.new_session(moves)[0] for moves in ("EEEEN", "SSWWNNEE", "EEEWWWEEE")]
    # `python -m app simulate` fills the scene with several explorers (sessions kept open)
    operator = {"X-API-Key": service.operator_key}  # live sessions are an operator's to see
    before = {
        s["session_id"] for s in service.http.get("/overview", headers=operator).json()["sessions"]
    }
    simulate = [
        sys.executable, "-m", "app", "simulate", "--server", service.base, "--explorers", "4",
        "--episodes", "4", "--steps", "60", "--keep", "--seed", "1",
    ]  # fmt: skip
    ran = subprocess.run(simulate, capture_output=True, text=True, timeout=120, check=False)
    assert ran.returncode == 0, ran.stderr
    overview = service.http.get("/overview", headers=operator).json()
    simulated = {s["session_id"] for s in overview["sessions"]}
    simulated -= before
    assert len(simulated) == 4
    viewer = service.viewer
    server = viewer.server
    assert server is not None
    assert service.http.get("/viewer").json()["port"] == viewer.port

    page.goto(f"http://127.0.0.1:{viewer.port}/")
    expect(page.get_by_text("Connecting")).to_have_count(0, timeout=30_000)
    wait_until(lambda: len(server.get_clients()) == 1, what="the viewer to see the browser")
    wait_until(
        lambda: (
            viewer.scene is not None and set(sessions) | simulated <= set(viewer.scene.session_ids)
        ),
        what="the pump to draw the sessions",
    )
    with viewer._lock:  # the pump's tick holds it: a scene read between two of its updates
        scene = viewer.scene
        assert scene is not None
        domain = scene.domain
        view = next(iter(viewer.views.values()))  # the browser's own scene
        names = set(view.client.scene._handle_from_node_name)
        assert names >= SCENE_NODES, SCENE_NODES - names
        assert scene.walls is not None and scene.prior_arrows is not None
        assert scene.walls.batched_positions.shape == (int(domain.walls.sum()), 3)
        assert scene.prior_arrows.batched_positions.shape == (4 * domain.n_states, 3)
        drawn: dict[str, Any] = scene.session_nodes  # handles of several kinds
        assert drawn["/markers/points"].points.shape[0] == len(scene.session_ids) >= 7

    # pick a session in the GUI (server side: the browser's panel follows). The pick wakes the
    # pump, which shows the session at once (not after its paced wait); then the browser
    # renders what the pump sent
    controls = viewer.controls
    assert controls is not None
    choose(controls.session, sessions[2])
    wait_until(
        lambda: controls.plot.visible and f"**{sessions[2]}**" in controls.stats.content,
        what="the pump to show the picked session",
    )
    expect(page.get_by_text(PLOT_TITLE)).to_be_visible()
    expect(page.get_by_text("p_normal")).to_have_count(0)  # one name for P(M1|H)
    expect(page.get_by_text("steps 9", exact=False)).to_be_visible()
    # what the advisor believes: plain words first, the paper's symbol second
    believes = page.get_by_text("moves like someone who knows the building", exact=False)
    expect(believes.first).to_be_visible()
    expect(believes.first).to_contain_text("(P(M1|H))")
    # the legend says what each thing drawn is, by the layers' names
    for entry in (*LAYER_LABELS.values(), "destinations"):
        expect(page.get_by_text(entry, exact=False).first).to_be_attached()
    # the picker lists the sessions most recently active first (the feed's order)
    with viewer._lock:
        view = next(iter(viewer.views.values()))
        options = view.controls.session.options[1:]
        assert scene is not None
    latest = service.http.get("/overview", headers=operator).json()["sessions"]
    assert list(options) == [s["session_id"] for s in latest if s["session_id"] in options]

    # the browser really renders the scene: walls, floor and arrows make a varied image
    client = next(iter(server.get_clients().values()))
    image = client.get_render(240, 320, timeout=60.0)
    assert image.shape[:2] == (240, 320)
    assert np.asarray(image, dtype=np.float64).std() > 10.0
    # the maze fills the canvas the panel leaves (docked at the right, not over the maze)
    canvas = page.locator("canvas").last.bounding_box()
    assert canvas is not None and canvas["width"] < 1280 - 250
    wait_until(lambda: fitted(view), what="the camera to fit the maze to the canvas")
    # the software-rendering notice (swiftshader here) hides a corner of the maze: closed
    notice = page.get_by_role("alert").filter(has_text="Software WebGL")
    notice.get_by_role("button").click()
    expect(notice).to_have_count(0)
    screenshot(page, "viewer")
    page.get_by_text("not drawn)", exact=False).scroll_into_view_if_needed()
    expect(page.get_by_text("the more often experts moved that way", exact=False)).to_be_visible()
    screenshot(page, "viewer-legend")


def fitted(view: ClientView) -> bool:
    """Whether the browser's camera looks at the maze from where it fills its canvas (down
    on a one-floor map or the floor shown, from the south and above on every floor)."""
    camera = view.client.camera
    scene = view.scene
    if scene is None:
        return False
    position, look_at, _ = scene.camera(camera.fov, camera.aspect)
    return bool(np.allclose(camera.position, position) and np.allclose(camera.look_at, look_at))


TOWER = generate_floors(20, 20, 2, np.random.default_rng(3), n_goals=3, purpose="hospital")


def test_viewer_page_shows_a_building_floor_by_floor(service: Service, page: Page) -> None:
    """A building of two floors, read over HTTP: stacked at their heights with the stairs and
    lifts between them, explorers on each floor; the panel's floor filter shows one alone."""
    admin = {"X-API-Key": ADMIN}
    body = {"text": TOWER.to_text(), "experts": {"per_goal": 2}}
    put = service.http.put("/domains/tower", json=body, headers=admin)
    assert put.status_code == 201, put.text
    upstairs = list(TOWER.connections[0].stops[1])  # a lift's stop on the upper floor
    walks = {"upstairs": (upstairs, "SSWWNN"), "ground": (list(TOWER.cell(TOWER.start)), "NNNEE")}
    ids = {}
    for name, (start, moves) in walks.items():
        made = service.http.post("/domains/tower/sessions", json={"kappa": 0.0, "start": start})
        assert made.status_code == 201, made.text
        sid, token = made.json()["session_id"], made.json()["token"]
        service.move(sid, {"Authorization": f"Bearer {token}"}, start, moves)
        ids[name] = sid
    viewer = service.viewer
    server = viewer.server
    assert server is not None
    page.goto(f"http://127.0.0.1:{viewer.port}/")
    expect(page.get_by_text("Connecting")).to_have_count(0, timeout=30_000)
    wait_until(lambda: len(server.get_clients()) == 1, what="the viewer to see the browser")
    wait_until(lambda: viewer.controls is not None, what="the browser's controls")
    controls = viewer.controls
    assert controls is not None
    choose(controls.domain, "tower")
    wait_until(
        lambda: (
            viewer.scene is not None
            and isinstance(viewer.scene.domain, Building)
            and set(ids.values()) <= set(viewer.scene.session_ids)
        ),
        what="the pump to draw the building and its sessions",
    )
    with viewer._lock:
        view = next(iter(viewer.views.values()))
        scene = view.scene
        assert scene is not None
        names = set(view.client.scene._handle_from_node_name)
        for f in range(TOWER.n_floors):
            assert {f"/maze/f{f}/walls", f"/maze/f{f}/name", f"/prior/f{f}/arrows"} <= names
            assert f"/markers/f{f}/points" in names  # an explorer on each floor
        assert {"/maze/connections/lift", "/maze/connections/stairs"} <= names
        assert TOWER.goal_names is not None
        for i, (f, _, _) in enumerate(TOWER.goal_cells):
            label: Any = view.client.scene._handle_from_node_name[f"/maze/f{f}/goal_labels/G{i}"]
            assert label.text == TOWER.goal_names[i]
    # the floor filter is in the browser's panel; every floor first, from the south and above
    floors = page.get_by_label("Floors", exact=True)
    expect(floors).to_be_visible()
    wait_until(lambda: fitted(view), what="the camera to see every floor")
    notice = page.get_by_role("alert").filter(has_text="Software WebGL")
    notice.get_by_role("button").click()
    expect(notice).to_have_count(0)
    client = next(iter(server.get_clients().values()))
    image = client.get_render(240, 320, timeout=60.0)
    assert np.asarray(image, dtype=np.float64).std() > 10.0
    screenshot(page, "viewer-floors")
    # one floor alone, picked in the browser's dropdown: the other floor hidden, seen from above
    floors.click()
    page.get_by_role("option", name="Floor 1", exact=True).click()
    wait_until(lambda: scene.shown_floor == 1, what="the floor filter to reach the pump")
    wait_until(lambda: fitted(view), what="the camera to look down on floor 1")
    assert not any(frame.visible for frame in scene.floor_frames[0])
    assert all(frame.visible for frame in scene.floor_frames[1])
    assert scene.connections is not None and not scene.connections.visible
    assert view.client.camera.look_at[2] == pytest.approx(floor_levels(TOWER)[1])
    screenshot(page, "viewer-floors-upstairs")
    floors.click()
    page.get_by_role("option", name=ALL_FLOORS, exact=True).click()
    wait_until(lambda: scene.shown_floor is None, what="every floor again")
    assert all(frame.visible for frames in scene.floor_frames for frame in frames)
    choose(controls.domain, "default")  # as the other tests expect to find it
    wait_until(lambda: viewer.scene is not None and not isinstance(viewer.scene.domain, Building),
               what="the one-floor map again")  # fmt: skip
