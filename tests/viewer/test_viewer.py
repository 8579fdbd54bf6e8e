"""The Viewer's pump and controls, fed plain snapshots (no service, no browser)."""

from __future__ import annotations

import threading
import time
from dataclasses import replace
from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from viser import _messages

from app.domain.building import Building
from app.domain.generate import generate_domain
from app.domain.grid import GridDomain
from app.viewer import geometry as geo
from app.viewer.controls import ALL_FLOORS, LOST_PICKED, NONE, PLOT_TITLE, SLIDER_KAPPA_HIGH
from app.viewer.scene import DEFAULT_FOV, WALL_HEIGHT
from app.viewer.state import Destination, DomainView, Figure, Snapshot
from app.viewer.storeys import floor_levels
from app.viewer.viewer import Viewer, pump_wait
from tests.viewer.conftest import Browser, FakeFeed, choose, free_port, wait_until, walk


def snapshot(domain: GridDomain, theta: np.ndarray, n_sessions: int, version: int = 0) -> Snapshot:
    rng = np.random.default_rng(7)
    sessions = [walk(domain, theta, f"w{i}", 30 + 10 * i, rng) for i in range(n_sessions)]
    return Snapshot({domain.name: DomainView(domain, theta, version)}, sessions)


def test_viewer_tick_draws_the_first_domain(
    viewer: Viewer, feed: FakeFeed, domain: GridDomain, theta: np.ndarray
) -> None:
    feed.snapshot = snapshot(domain, theta, 2)
    viewer.tick()
    assert viewer.controls is not None and viewer.scene is not None
    assert viewer.controls.domain.options == (domain.name,)
    assert viewer.controls.picked_domain == domain.name
    assert viewer.scene.domain is domain
    assert viewer.controls.session.options == (NONE, "w0", "w1")
    assert set(viewer.scene.session_ids) == {"w0", "w1"}
    view = next(iter(viewer.views.values()))
    assert view.client.camera.look_at[2] == 0.0  # looking down at the map


def test_viewer_session_options_follow_the_live_sessions(
    viewer: Viewer, feed: FakeFeed, domain: GridDomain, theta: np.ndarray
) -> None:
    feed.snapshot = snapshot(domain, theta, 3)
    viewer.tick()
    assert viewer.controls is not None
    choose(viewer.controls.session, "w2")
    viewer.tick()
    assert "steps **50**" in viewer.controls.stats.content
    assert viewer.controls.plot.visible
    x, y = viewer.controls.plot.data
    assert x[-1] == 50 and len(x) == len(y) == 51
    feed.snapshot = snapshot(domain, theta, 2)  # w2 ended
    viewer.tick()
    assert viewer.controls.session.options == (NONE, "w0", "w1")
    assert viewer.controls.picked_session is None
    assert viewer.controls.stats.content == "No session picked."


def test_viewer_session_picker_lists_the_most_recently_active_first(
    viewer: Viewer, feed: FakeFeed, domain: GridDomain, theta: np.ndarray
) -> None:
    """The feed gives sessions most recently active first (as the service's snapshot does);
    the picker keeps that order, not the ids' (w0 is the longest walk, w2 the latest)."""
    snap = snapshot(domain, theta, 3)
    by_id = {s.session_id: s for s in snap.sessions}
    feed.snapshot = Snapshot(snap.domains, [by_id["w2"], by_id["w0"], by_id["w1"]])
    viewer.tick()
    assert viewer.controls is not None
    assert viewer.controls.session.options == (NONE, "w2", "w0", "w1")
    choose(viewer.controls.session, "w0")
    feed.snapshot = Snapshot(snap.domains, [by_id["w1"], by_id["w2"], by_id["w0"]])  # w1 moved
    viewer.tick()
    assert viewer.controls.session.options == (NONE, "w1", "w2", "w0")
    assert viewer.controls.picked_session == "w0"  # the pick stays while the order changes


def test_viewer_panel_has_a_legend_and_one_name_for_p_m1_h(
    viewer: Viewer, feed: FakeFeed, domain: GridDomain, theta: np.ndarray
) -> None:
    feed.snapshot = snapshot(domain, theta, 1)
    viewer.tick()
    controls = viewer.controls
    assert controls is not None
    legend = controls.legend.content
    for drawn in ("walls", "start", "destinations", "prior arrows", "kappa shading",
                  "Session markers", "Session paths", "Advice given"):  # fmt: skip
        assert drawn in legend
    # each layer's checkbox is named as the legend names it, plain words first
    assert all(box.label in legend for box in controls.layers.values())
    assert controls.plot.title == PLOT_TITLE == "Knows the way (P(M1|H)) over time"
    choose(controls.session, "w0")
    viewer.tick()
    shown = (legend, controls.stats.content, controls.shading_text.content, controls.plot.title)
    assert all("p_normal" not in text for text in shown)
    assert "P(M1|H)" in controls.stats.content
    assert controls.shading_text.content.startswith("Shaded: **")
    assert "looks lost" in controls.shading_text.content


def test_viewer_panel_says_what_the_advisor_believes_plain_words_first(
    viewer: Viewer, feed: FakeFeed, domain: GridDomain, theta: np.ndarray
) -> None:
    """The picked session's figures as its strategy says them (the one that says most in
    bold, its tone marked), and the destination its advice leads to, by name."""
    base = snapshot(domain, theta, 1)
    figures = (Figure("looks lost", "P(lost|H)", 0.97, "neutral"),
               Figure("on its way", "P(M1|H)", 0.03, "neutral"))  # fmt: skip
    to = Destination(1, domain.cell(domain.goals[1]), "Lecture hall B")
    led = replace(base.sessions[0], figures=figures, headline=0, leads_to=to)
    feed.snapshot = replace(base, sessions=[led])
    viewer.tick()
    controls = viewer.controls
    assert controls is not None
    choose(controls.session, "w0")
    viewer.tick()
    stats = controls.stats.content
    assert (
        "looks lost **97%** (P\\(lost\\|H\\)) (being handled); on its way 3% (P\\(M1\\|H\\))"
        in stats
    )
    assert f"advice leads to **Lecture hall B \\(G1\\)** {list(to.cell)}" in stats
    # a name cannot inject markup into the panel
    odd = replace(led, leads_to=Destination(1, to.cell, "<b>x</b> *y*"))
    feed.snapshot = replace(base, sessions=[odd])
    viewer.tick()
    assert "<b>" not in controls.stats.content and "\\*y\\*" in controls.stats.content


def camera(width: int, height: int, fov: float = DEFAULT_FOV) -> _messages.ViewerCameraMessage:
    """The camera message a browser sends when its canvas is ``width`` x ``height``."""
    return _messages.ViewerCameraMessage(
        wxyz=(1.0, 0.0, 0.0, 0.0), position=(0.0, 0.0, 10.0), fov=fov, near=0.01, far=1000.0,
        image_height=height, image_width=width, look_at=(0.0, 0.0, 0.0),
        up_direction=(0.0, 1.0, 0.0),
    )  # fmt: skip


def test_viewer_fits_the_maze_to_the_browsers_window(
    feed: FakeFeed, domain: GridDomain, theta: np.ndarray
) -> None:
    """The camera is put where the maze fills the canvas the browser reports; when the window
    changes size (or the fit button is pressed) it is put there again."""
    feed.snapshot = snapshot(domain, theta, 1)
    viewer = Viewer(feed, port=free_port())
    viewer.start(pump=False)
    browser = Browser(viewer.port)
    try:
        wait_until(lambda: len(viewer.views) == 1)
        view = next(iter(viewer.views.values()))
        rows, cols = domain.shape

        def fits(width: int, height: int, fov: float) -> bool:
            cam = view.client.camera
            if (cam.image_width, cam.image_height) != (width, height):
                return False  # the browser's message has not arrived yet
            viewer.tick()
            # what the camera sees at the tops of the walls, half the width and height
            half_v = (cam.position[2] - WALL_HEIGHT) * np.tan(fov / 2)
            half_h = half_v * width / height
            filled = max(rows / 2 / half_v, cols / 2 / half_h)
            centred = np.allclose(cam.position[:2], [cols / 2, rows / 2])
            return centred and bool(np.isclose(cam.look_at[2], 0.0)) and 0.95 < filled <= 1.0

        for width, height, fov in [(1600, 800, DEFAULT_FOV), (500, 900, 1.0), (900, 900, 0.6)]:
            browser.send(camera(width, height, fov))
            wait_until(lambda w=width, h=height, f=fov: fits(w, h, f))  # type: ignore[misc]
        # a person zoomed out; the window kept its size: the camera is left where they put it
        cam = view.client.camera
        cam.position = (cols / 2, rows / 2, 500.0)
        viewer.tick()
        assert cam.position[2] == 500.0
        # the person clicks the fit button in their panel: the maze fills the window again
        button = view.controls.fit
        browser.send(_messages.GuiUpdateMessage(button._impl.uuid, {"value": True}))
        wait_until(lambda: view.controls._fit_asked)
        viewer.tick()
        assert fits(900, 900, 0.6)
    finally:
        browser.close()
        viewer.stop()


def test_viewer_kappa_slider_and_lost_mode_drive_the_shading(
    viewer: Viewer, feed: FakeFeed, domain: GridDomain, theta: np.ndarray
) -> None:
    feed.snapshot = snapshot(domain, theta, 1)
    viewer.tick()
    controls, scene = viewer.controls, viewer.scene
    assert controls is not None and scene is not None
    for kappa in (0.1, 0.8):
        choose(controls.kappa, kappa)
        viewer.tick()
        assert scene.shaded.sum() == geo.advised_cells(theta, kappa, 0.0).sum()
        assert f"kappa = {kappa:.2f}" in controls.shading_text.content
    choose(controls.session, "w0")
    choose(controls.lost, LOST_PICKED)
    viewer.tick()
    p = feed.snapshot.sessions[0].p_normal
    assert np.array_equal(scene.shaded, geo.advised_cells(theta, 0.8, p))


def test_viewer_updates_the_prior_when_its_version_changes(
    viewer: Viewer, feed: FakeFeed, domain: GridDomain, theta: np.ndarray
) -> None:
    feed.snapshot = snapshot(domain, theta, 0)
    viewer.tick()
    new = np.roll(theta, 2, axis=1)
    feed.snapshot = Snapshot({domain.name: DomainView(domain, new, 1)})
    viewer.tick()
    assert viewer.scene is not None and viewer.scene.prior_arrows is not None
    scales = viewer.scene.prior_arrows.batched_scales
    assert scales is not None
    scales = scales[:, 0]
    np.testing.assert_allclose(scales, geo.ARROW_REACH * new.ravel(), rtol=1e-6)


def test_viewer_layer_checkboxes_hide_layers(
    viewer: Viewer, feed: FakeFeed, domain: GridDomain, theta: np.ndarray
) -> None:
    feed.snapshot = snapshot(domain, theta, 1)
    viewer.tick()
    assert viewer.controls is not None and viewer.scene is not None
    choose(viewer.controls.layers["prior"], False)
    viewer.tick()
    assert not viewer.scene.frames["prior"].visible
    assert viewer.scene.frames["paths"].visible


def test_viewer_switches_domains_and_clears_when_none_left(
    viewer: Viewer, feed: FakeFeed, domain: GridDomain, theta: np.ndarray
) -> None:
    other = generate_domain(7, 9, seed=1, n_goals=2)
    other_theta = np.full((other.n_states, 4), 0.25)
    feed.snapshot = Snapshot(
        {domain.name: DomainView(domain, theta), other.name: DomainView(other, other_theta)}
    )
    viewer.tick()
    assert viewer.controls is not None
    choose(viewer.controls.domain, other.name)
    viewer.tick()
    assert viewer.scene is not None and viewer.scene.domain is other
    assert viewer.scene.walls is not None
    assert viewer.scene.walls.batched_positions.shape[0] == int(other.walls.sum())
    feed.snapshot = Snapshot()
    viewer.tick()
    assert viewer.scene is None
    assert viewer.controls.domain.options == (NONE,)


def test_viewer_pump_ticks_by_itself_and_survives_a_failing_feed(
    domain: GridDomain, theta: np.ndarray
) -> None:
    good = snapshot(domain, theta, 1)
    ticked = threading.Event()
    calls = {"n": 0}

    def flaky() -> Snapshot:
        calls["n"] += 1
        if calls["n"] == 1:
            raise RuntimeError("feed failed once")
        ticked.set()
        return good

    viewer = Viewer(flaky, port=free_port(), rate_hz=50.0, idle_rate_hz=50.0)
    viewer.start()
    try:
        time.sleep(0.3)
        assert calls["n"] == 0  # no browser, no tick: nothing is read for no one
        browser = Browser(viewer.port)
        assert ticked.wait(timeout=10.0)
        # the pump is not per event: it read the feed, it did not get pushed to
        assert calls["n"] >= 2
        wait_until(lambda: viewer.scene is not None and viewer.scene.domain is domain)
        browser.close()
    finally:
        viewer.stop()


def test_a_control_change_wakes_the_pump_from_its_paced_wait(
    domain: GridDomain, theta: np.ndarray
) -> None:
    """A choice is applied at once, not after the pump's wait (here 1,000 s: as after a tick
    that took 100 s at a 10 % share), so what a person picks shows without delay."""
    feed = FakeFeed()
    feed.snapshot = snapshot(domain, theta, 2)
    viewer = Viewer(feed, port=free_port(), rate_hz=0.001, idle_rate_hz=0.001)
    viewer.start()
    browser = Browser(viewer.port)  # its connecting wakes the pump at once
    try:
        wait_until(lambda: viewer.ticks >= 1)  # the first tick, then a 1,000 s wait
        assert viewer.ticks == 1  # its own choice of the domain did not wake it
        assert viewer.controls is not None and viewer.controls.session.options[-1] == "w1"
        ticks = viewer.ticks
        choose(viewer.controls.session, "w1")  # from code, as a browser's change arrives
        wait_until(lambda: viewer.ticks > ticks, timeout=10.0)
        wait_until(lambda: viewer.controls is not None and viewer.controls.plot.visible)
        assert "**w1**" in viewer.controls.stats.content
    finally:
        browser.close()
        viewer.stop()


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [({"rate_hz": 0.0}, "rate_hz"), ({"idle_rate_hz": -1.0}, "idle_rate_hz"),
     ({"max_share": 0.0}, "max_share"), ({"max_share": 1.5}, "max_share")],
)  # fmt: skip
def test_viewer_refuses_bad_pacing(kwargs: dict[str, float], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        Viewer(Snapshot, **dict[str, Any](kwargs))


@given(st.floats(0.0, 2.0), st.floats(0.01, 2.0), st.floats(0.01, 1.0))
def test_pump_wait_keeps_the_rate_and_caps_the_share(
    elapsed: float, period: float, share: float
) -> None:
    wait = pump_wait(elapsed, period, share)
    assert wait >= 0.0
    assert elapsed + wait >= period - 1e-12  # never faster than the rate
    if elapsed > 0:
        assert elapsed / (elapsed + wait) <= share + 1e-9  # never more than the share
    if elapsed <= share * period:  # a cheap tick: the plain fixed rate
        assert elapsed + wait == pytest.approx(period)


def test_viewer_shows_a_goal_aware_sessions_goal_posterior(
    viewer: Viewer, feed: FakeFeed, domain: GridDomain, theta: np.ndarray
) -> None:
    snap = snapshot(domain, theta, 1)
    cells = [domain.cell(g) for g in domain.goals]
    p = [0.0] + [1.0 / (len(cells) - 1)] * (len(cells) - 1)
    goals = [(c, q, i == 0) for i, (c, q) in enumerate(zip(cells, p, strict=True))]
    aware = replace(snap.sessions[0], session_id="g", strategy="goal_aware", goals=goals)
    feed.snapshot = Snapshot(snap.domains, [*snap.sessions, aware])
    viewer.tick()
    assert viewer.controls is not None
    choose(viewer.controls.session, "g")
    viewer.tick()
    text = viewer.controls.stats.content
    assert "strategy `goal_aware`" in text and "Where it may be going (P(goal|H))" in text
    assert f"G0 {list(cells[0])}: ~~ruled out~~" in text
    assert f"G1 {list(cells[1])}: **{p[1]:.2f}**" in text
    choose(viewer.controls.session, "w0")
    viewer.tick()
    assert "Where it may be going" not in viewer.controls.stats.content


@pytest.mark.parametrize(
    ("sent", "kept"),
    [(float("nan"), 0.5), (-5.0, 0.0), (1e308, SLIDER_KAPPA_HIGH), (float("inf"), 0.5), ("x", 0.5),
     (True, 0.5), (0.3, 0.3)],
)  # fmt: skip
def test_a_kappa_no_slider_gives_is_put_back_in_range(
    viewer: Viewer, feed: FakeFeed, domain: GridDomain, theta: np.ndarray, sent: object,
    kept: float,
) -> None:  # fmt: skip
    """Any page can send the viewer's kappa a value its slider would never give: the pump
    shades with a kappa in range and puts the slider back."""
    feed.snapshot = snapshot(domain, theta, 1)
    viewer.tick()
    controls, scene = viewer.controls, viewer.scene
    assert controls is not None and scene is not None
    if isinstance(sent, float):
        choose(controls.kappa, sent)
    else:  # what a raw message can leave there: viser casts only what code assigns
        controls.kappa._impl.value = sent
    viewer.tick()
    assert controls.kappa.value == kept
    assert scene.shaded.sum() == geo.advised_cells(theta, kept, 0.0).sum()
    assert f"kappa = {kept:.2f}" in controls.shading_text.content


def test_viewer_floor_filter_shows_a_building_whole_or_one_floor(
    viewer: Viewer,
    feed: FakeFeed,
    domain: GridDomain,
    theta: np.ndarray,
    tower: Building,
    tower_theta: np.ndarray,
) -> None:
    """A one-floor map has no floor filter; a building's lists its floors, every floor seen
    from the south and above, or one alone, from above (the others hidden)."""
    feed.snapshot = snapshot(domain, theta, 1)
    viewer.tick()
    controls, view = viewer.controls, next(iter(viewer.views.values()))
    assert controls is not None
    assert not controls.floor.visible and controls.picked_floor is None
    assert "Floors" not in controls.legend.content
    feed.snapshot = Snapshot({tower.name: DomainView(tower, tower_theta)}, [
        walk(tower, tower_theta, "t0", 20, np.random.default_rng(3)),
    ])  # fmt: skip
    choose(controls.domain, tower.name)
    viewer.tick()
    scene = viewer.scene
    assert scene is not None and scene.domain is tower
    assert controls.floor.visible and controls.floor.options == (
        ALL_FLOORS,
        "Ground floor",
        "Floor 1",
    )
    assert "**Floors**" in controls.legend.content
    assert scene.shown_floor is None
    cam = view.client.camera
    np.testing.assert_allclose(cam.up_direction, (0.0, 0.0, 1.0), atol=1e-6)
    levels = floor_levels(tower)
    assert cam.position[2] > levels[-1] and cam.position[1] < cam.look_at[1]
    choose(controls.floor, "Floor 1")
    viewer.tick()
    assert scene.shown_floor == 1 == controls.picked_floor
    assert not any(frame.visible for frame in scene.floor_frames[0])
    assert all(frame.visible for frame in scene.floor_frames[1])
    assert cam.look_at[2] == pytest.approx(levels[1])  # from above, on that floor
    np.testing.assert_allclose(cam.up_direction, (0.0, 1.0, 0.0), atol=1e-6)
    choose(controls.floor, "Basement")  # not one of them (a browser may send anything)
    viewer.tick()
    assert controls.floor.value == ALL_FLOORS and scene.shown_floor is None
    choose(controls.floor, "Floor 1")
    viewer.tick()
    feed.snapshot = Snapshot()  # no domain left: no filter
    viewer.tick()
    assert viewer.scene is None and not controls.floor.visible
    feed.snapshot = Snapshot({tower.name: DomainView(tower, tower_theta)})
    choose(controls.floor, "Floor 1")
    viewer.tick()
    assert viewer.scene is not None and viewer.scene.shown_floor == 1
    feed.snapshot = snapshot(domain, theta, 1)  # back to one floor: the filter goes
    choose(controls.domain, domain.name)
    viewer.tick()
    assert viewer.scene is not None and viewer.scene.domain is domain
    assert not controls.floor.visible and controls.picked_floor is None
    assert view.client.camera.look_at[2] == 0.0
