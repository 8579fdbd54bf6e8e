"""/walk: a person walks with the arrow keys; moves reach the service; advice shows when given;
what the advisor believes shows in plain words (the paper's symbol second, the strategy's
tone), with the destination its advice leads to, by name; the panel stays in view on any map
(the map scrolls and zooms in its own box) and the destinations' labels stay readable."""

from __future__ import annotations

import json
import random
import re

import pytest
from playwright.sync_api import Page, expect

from app.domain.generate import generate_building_domain
from app.domain.grid import GridDomain, NamedCell
from tests.browser.conftest import ADMIN, Service, screenshot

KEY = {"N": "ArrowUp", "E": "ArrowRight", "S": "ArrowDown", "W": "ArrowLeft"}

pytestmark = pytest.mark.browser


def summary(service: Service, sid: str) -> dict[str, object]:
    answer = service.http.get(f"/sessions/{sid}", headers={"X-API-Key": ADMIN})
    assert answer.status_code == 200, answer.text
    body: dict[str, object] = answer.json()
    return body


def test_walk_keys_move_the_explorer_and_advice_appears_when_lost(
    service: Service, page: Page
) -> None:
    with page.expect_response(
        lambda r: r.url.endswith("/domains/default/sessions") and r.request.method == "POST"
    ) as created_info:
        page.goto(service.base + "/walk")
    created = created_info.value.json()
    sid = created["session_id"]
    assert created["decision"]["state"] == [28, 0]
    expect(page.locator("#status")).to_contain_text("Connected")

    # walking like the experts (east along the bottom corridor): recorded, no advice
    for _ in range(3):
        page.keyboard.press("ArrowRight")
    expect(page.locator("#steps")).to_have_text("3")
    expect(page.locator("#position")).to_have_text("[28, 3]")
    seen = summary(service, sid)
    assert seen["steps"] == 3 and seen["position"] == [28, 3]
    # what the advisor believes, as the paper's rule says it: plain words, then the symbol
    expect(page.locator("body")).to_have_attribute("data-beliefs-step", "3")
    names = page.locator("#beliefs dt")
    expect(names).to_have_text(["moves like someone who knows the building", "looks lost"])
    p = seen["p_normal"]
    assert isinstance(p, float) and p > 0.5
    values = page.locator("#beliefs dd")
    expect(values).to_have_text(
        [f"{round(100 * p)}% (P(M1|H))", f"{round(100 * (1 - p))}% (P(M2|H))"]
    )
    expect(page.locator("#beliefs dt.headline")).to_have_text(
        "moves like someone who knows the building"
    )
    expect(page.locator("#beliefs dd.headline")).to_have_class(re.compile("tone-good"))
    expect(page.locator("#p-chart-name")).to_have_text("Moves like someone who knows the building")
    expect(page.locator("#advice")).to_be_hidden()
    # the advice's worth beside its price, and why no advice; P(M1|H) after each decision
    kl = page.locator("#kl").inner_text()
    assert re.fullmatch(r"\d+\.\d{3} nats", kl)
    rule = page.locator("#kl-rule")
    expect(rule).to_have_text(f"worth {kl.split()[0]} < price 0.5 → not advised (KL < κ)")
    chart = page.locator("#p-chart")
    expect(chart).to_have_attribute("data-points", "4")
    assert float(chart.get_attribute("data-last") or "nan") == pytest.approx(p, abs=6e-4)
    # the legend names what the maze shows, each with a swatch drawn as the maze draws it (the
    # stairs and lifts on a building only)
    legend = page.locator("#maze-legend li:visible")
    expect(legend).to_have_count(7)
    expect(page.locator("#maze-legend li:visible canvas.swatch")).to_have_count(7)
    for item in ("wall", "start", "goal", "walker", "path", "advised", "advice"):
        expect(page.locator(f'#maze-legend li[data-item="{item}"]')).to_be_visible()
    expect(page.locator('#maze-legend li[data-item="stop"]')).to_be_hidden()

    # a lost-looking walk: bumping into the walls and going back and forth
    for key in ["ArrowDown", "ArrowDown", "ArrowLeft", "ArrowRight", "ArrowLeft", "ArrowRight"]:
        page.keyboard.press(key)
    expect(page.locator("#steps")).to_have_text("9")
    expect(page.locator("#advice")).to_be_visible()
    expect(rule).to_have_text(re.compile(r"^worth \d+\.\d{3} ≥ price 0\.5 → advised \(KL ≥ κ\)$"))
    expect(rule).to_have_class(re.compile("advised"))
    expect(chart).to_have_attribute("data-points", "10")
    items = page.locator("#advice-list li")
    expect(items).to_have_count(4)
    expect(items.first).to_contain_text("%")
    seen = summary(service, sid)
    assert seen["steps"] == 9 and seen["position"] == [28, 3]
    advice_count = seen["advice_count"]
    assert isinstance(advice_count, int) and advice_count >= 1
    expect(page.locator("#advice-count")).to_have_text(str(advice_count))
    # it looks lost now: the paper's rule reads that red, "looks lost" (P(M2|H)) in bold
    expect(page.locator("body")).to_have_attribute("data-beliefs-step", "9")
    lost = 1 - seen["p_normal"]  # type: ignore[operator]
    assert lost > 0.5
    expect(page.locator("#beliefs dt.headline")).to_have_text("looks lost")
    expect(page.locator("#beliefs dd.headline")).to_have_text(f"{round(100 * lost)}% (P(M2|H))")
    expect(page.locator("#beliefs dd.headline")).to_have_class(re.compile("tone-bad"))
    expect(page.locator("#leads-to")).to_be_hidden()  # the paper's advice leads nowhere
    # the most likely direction, as advised on the page, is the prior's at that cell
    prior = service.http.get("/domains/default/prior").json()["theta"][28][3]
    best = "NESW"[max(range(4), key=lambda a: prior[a])]
    shown = {li.get_attribute("data-action"): li.inner_text() for li in items.all()}
    assert f"{100 * max(prior):.1f}%" in shown[best]
    screenshot(page, "walk-advised", full_page=True)


def test_a_walker_in_a_128_building_is_led_to_a_destination_by_guide(
    service: Service, page: Page
) -> None:
    """A generated 128 x 128 building, its prior learned from simulated experts at PUT; the
    walker does not know the way: it follows the advice when it is given and otherwise takes
    a random open way. guide leads it to a destination (the nearest is 80 moves away)."""
    grid = generate_building_domain(128, 128, 5)
    body = {"map": grid.to_text().splitlines(), "experts": {"per_goal": 3, "seed": 1}}
    r = service.http.put("/domains/hall128", json=body, headers={"X-API-Key": ADMIN})
    assert r.status_code in (200, 201), r.text
    page.goto(service.base + "/walk?domain=hall128&strategy=guide")
    expect(page.locator("#status")).to_contain_text("Connected")
    expect(page.locator("#session")).to_contain_text("guide")
    rng = random.Random(5)
    advised, checked = 0, 0
    for i in range(3000):
        page.wait_for_function("document.body.dataset.pending === '0'")
        seen = page.evaluate("() => ({...document.body.dataset})")
        if seen["goal"]:
            break
        state = grid.state(*json.loads(seen["position"]))
        if seen["advice"]:
            advice = json.loads(seen["advice"])
            heading = max("NESW", key=lambda a: advice[a])
            advised += 1
            if i % 25 == 0:  # a walker that follows the advice is led, never shown red
                page.wait_for_function(f"document.body.dataset.beliefsStep === '{seen['step']}'")
                assert page.locator("#beliefs .tone-bad").count() == 0
                expect(page.locator("#beliefs dt").first).to_have_text("looks lost")
                expect(page.locator("#leads-to")).to_contain_text("Advice leads to G")
                expect(page.locator("#destinations li.target")).to_have_count(1)
                checked += 1
        else:
            heading = rng.choice([a for i, a in enumerate("NESW") if grid.open_moves[state, i]])
        page.keyboard.press(KEY[heading])
    else:
        pytest.fail("the walker did not reach a destination in 3,000 moves")
    assert advised > 0 and checked > 0
    # P(M1|H) of every decision of the walk is on the chart, the start's included
    expect(page.locator("#p-chart")).to_have_attribute("data-points", str(int(seen["step"]) + 1))
    cell = json.loads(seen["position"])
    assert grid.state(*cell) in grid.goals
    sid = page.evaluate("document.body.dataset.sessionId")
    summary_ = summary(service, sid)
    assert summary_["strategy"] == "guide" and summary_["position"] == cell
    advice_count = summary_["advice_count"]
    assert isinstance(advice_count, int) and advice_count >= advised
    screenshot(page, "walk-guide-128", full_page=True)


def test_walk_draws_a_256_map_and_answers_moves(service: Service, page: Page) -> None:
    """A 256 x 256 building: the page draws it (scrolling), and a move comes back decided."""
    grid = generate_building_domain(256, 256, 2)
    body = {"map": grid.to_text().splitlines()}
    r = service.http.put("/domains/hall256", json=body, headers={"X-API-Key": ADMIN})
    assert r.status_code in (200, 201), r.text
    page.goto(service.base + "/walk?domain=hall256&strategy=guide")
    expect(page.locator("#status")).to_contain_text("Connected")
    size = page.evaluate("() => [document.getElementById('maze').clientWidth, "
                         "document.getElementById('maze').clientHeight]")  # fmt: skip
    assert size == [256 * 6, 256 * 6]  # six pixels a cell, in a scrolling board
    expect(page.locator("#panel")).to_be_in_viewport()
    start = json.loads(page.evaluate("document.body.dataset.position"))
    open_way = next(i for i in range(4) if grid.open_moves[grid.state(*start), i])
    page.keyboard.press(KEY["NESW"[open_way]])
    expect(page.locator("#steps")).to_have_text("1")
    page.wait_for_function("document.body.dataset.pending === '0'")
    moved = json.loads(page.evaluate("document.body.dataset.position"))
    assert grid.state(*moved) == grid.next_state[grid.state(*start), open_way]


def test_walk_lists_the_service_s_strategies_and_says_what_their_advice_is(
    service: Service, page: Page
) -> None:
    """The strategy picker is the service's table (GET /strategies), each with its summary;
    the advice note is the picked strategy's own."""
    listed = service.http.get("/strategies").json()
    page.goto(service.base + "/walk?strategy=goal_aware")
    options = page.locator("#strategy option")
    expect(options).to_have_count(len(listed))
    assert [o.get_attribute("value") for o in options.all()] == [s["name"] for s in listed]
    expect(page.locator("#strategy")).to_have_value("goal_aware")
    picked = next(s for s in listed if s["name"] == "goal_aware")
    expect(page.locator("#strategy option[value=goal_aware]")).to_have_attribute(
        "title", picked["summary"]
    )
    expect(page.locator("#advice-note")).to_have_text(picked["advice"])


def board_scrolls(page: Page) -> list[bool]:
    """Whether the map's box scrolls across and down (the map is larger than the box)."""
    out: list[bool] = page.evaluate(
        "(() => { const b = document.getElementById('board'); return "
        "[b.scrollWidth > b.clientWidth, b.scrollHeight > b.clientHeight]; })()"
    )
    return out


def in_view(page: Page, selector: str) -> bool:
    """Whether the element's whole box lies inside the window."""
    box = page.locator(selector).bounding_box()
    view = page.viewport_size
    assert box is not None and view is not None
    return (
        box["x"] >= 0 and box["y"] >= 0 and box["x"] + box["width"] <= view["width"]
        and box["y"] + box["height"] <= view["height"]
    )  # fmt: skip


def test_walk_keeps_its_panel_in_view_and_names_readable_on_a_141_by_162_map(
    service: Service, page: Page
) -> None:
    """A generated 141 x 162 building whose destinations have names: the page does not grow
    past the window (the map scrolls in its own box), the panel's figures and advice stay in
    view as the walker goes, the destinations are listed by name and labelled on the map at a
    readable size, the walker is kept in the map's view, and the map zooms."""
    grid = generate_building_domain(141, 162, 3)
    names = [NamedCell(r, c, f"Room {i} ({r},{c})") for i, (r, c) in enumerate(grid.goal_cells)]
    named = GridDomain.from_strings(list(grid.rows_text), names=names)
    put = service.http.put("/domains/big141?experts=start&per_goal=2", content=named.to_text(),
                           headers={"X-API-Key": ADMIN, "Content-Type": "text/plain"})  # fmt: skip
    assert put.status_code in (200, 201), put.text
    page.goto(service.base + "/walk?domain=big141&strategy=guide")
    expect(page.locator("#status")).to_contain_text("Connected")
    # the window does not scroll: the page is its height, the map's box scrolls
    assert page.evaluate("document.scrollingElement.scrollHeight <= window.innerHeight + 1")
    assert board_scrolls(page) == [True, True]
    assert in_view(page, "#panel")
    # the destinations by name, in a font as large as the page's own text
    listed = page.locator("#destinations li")
    expect(listed).to_have_count(len(grid.goals))
    expect(listed.first).to_contain_text("Room 0")
    px = float(listed.first.evaluate("e => parseFloat(getComputedStyle(e).fontSize)"))
    assert px >= 12
    # on the map, labels at no less than 11 pixels although a cell is 6
    canvas = page.locator("#maze")
    expect(canvas).to_have_attribute("data-cell", "6")
    assert float(canvas.get_attribute("data-label-px") or "0") >= 11
    # a walk at a low price of advice: into walls, then on, following the advice when given;
    # the panel stays in view, the advice with it
    page.fill("#kappa", "0.1")
    page.click("#restart")
    expect(page.locator("#steps")).to_have_text("0")
    expect(page.locator("#status")).to_contain_text("Connected")
    advised = 0
    for i in range(40):
        seen = page.evaluate("() => ({...document.body.dataset})")
        if seen["advice"]:
            assert in_view(page, "#advice")
            advised += 1
        if seen["advice"] and i > 4:
            advice = json.loads(seen["advice"])
            heading = max("NESW", key=lambda a: advice[a])
        else:
            s = grid.state(*json.loads(seen["position"]))
            shut = [a for k, a in enumerate("NESW") if not grid.open_moves[s, k]]
            heading = shut[0] if shut else "N"
        page.keyboard.press(KEY[heading])
        page.wait_for_function("document.body.dataset.pending === '0'")
    expect(page.locator("#steps")).to_have_text("40")
    assert advised > 0
    step = page.evaluate("document.body.dataset.step")
    page.wait_for_function(f"document.body.dataset.beliefsStep === '{step}'")
    for part in ("#panel", "#beliefs", "#kl-rule"):
        assert in_view(page, part), part
    expect(page.locator("#beliefs dt")).to_have_text(
        ["looks lost", "on its way", "takes the advice"]
    )
    expect(page.locator("#leads-to")).to_contain_text("Advice leads to Room ")
    assert in_view(page, "#leads-to")
    target = page.locator("#destinations li.target")  # the panel's list marks it too
    expect(target).to_have_count(1)
    expect(target).to_contain_text("Room ")
    # the walker is within the map's visible part
    shown = page.evaluate("""(() => {
        const b = document.getElementById('board'), c = document.getElementById('maze');
        const [r, col] = JSON.parse(document.body.dataset.position), cell = Number(c.dataset.cell);
        const x = c.offsetLeft + (col + 0.5) * cell - b.scrollLeft;
        const y = c.offsetTop + (r + 0.5) * cell - b.scrollTop;
        return x >= 0 && y >= 0 && x <= b.clientWidth && y <= b.clientHeight;
    })()""")
    assert shown
    screenshot(page, "walk-big-map")
    # zoom: larger cells, then the whole map in its box
    page.click("#zoom-in")
    expect(canvas).to_have_attribute("data-cell", "8")
    page.click("#zoom-fit")
    assert board_scrolls(page) == [False, False]
    assert float(canvas.get_attribute("data-label-px") or "0") >= 11
    assert in_view(page, "#panel")


#: Two floors joined by a lift; the one destination is upstairs, so the experts ride it
LIFTS = """destination: 1 5 3 Radiology
connection: lift 4 0:3,7 1:3,7 Lift 1
floor: 0 Ground floor elevation: 0.0
###########
#.........#
#.........#
#S........#
#.....#...#
#.........#
#.........#
###########
floor: 1 First floor elevation: 4.0
###########
#.........#
#.........#
#.........#
#.....#...#
#..G......#
#.........#
###########
"""


def test_walk_follows_the_walker_upstairs_and_says_take_the_lift_up(
    service: Service, page: Page
) -> None:
    """A building of two floors: the map is the walker's floor; at the lift the advice says
    "take the lift up" (every expert rode it) and PageUp rides it; the map follows to the
    first floor, where the destination is named."""
    body = {"text": LIFTS, "experts": {"per_goal": 3, "seed": 1}}
    r = service.http.put("/domains/lifts", json=body, headers={"X-API-Key": ADMIN})
    assert r.status_code in (200, 201), r.text
    page.goto(service.base + "/walk?domain=lifts&strategy=paper")
    expect(page.locator("#status")).to_contain_text("Connected")
    page.fill("#kappa", "0")  # every step advised: the advice at each cell shows
    page.click("#restart")
    expect(page.locator("#status")).to_contain_text("Connected")
    expect(page.locator("#floor-keys")).to_be_visible()
    expect(page.locator("#floor")).to_have_text("Ground floor (ordinal 0)")
    expect(page.locator("#position")).to_have_text("[0, 3, 1]")

    def press(key: str, times: int = 1) -> None:
        for _ in range(times):
            page.keyboard.press(key)
            page.wait_for_function("document.body.dataset.pending === '0'")

    press("ArrowRight", 6)
    expect(page.locator("#position")).to_have_text("[0, 3, 7]")
    expect(page.locator("#ride-note")).to_have_text("Here: Lift 1 (lift), up (PageUp or R).")
    expect(page.locator("#advice-words")).to_contain_text("Take the lift up")
    expect(page.locator("#advice-list li[data-action='U']")).to_have_count(1)
    expect(page.locator('#maze-legend li[data-item="stop"]')).to_be_visible()
    screenshot(page, "walk-floors-lift", full_page=True)
    press("PageUp")
    expect(page.locator("#position")).to_have_text("[1, 3, 7]")
    assert page.evaluate("document.body.dataset.floor") == "1"
    expect(page.locator("#floor")).to_have_text("First floor (ordinal 1)")
    expect(page.locator("#ride-note")).to_have_text("Here: Lift 1 (lift), down (PageDown or F).")
    press("ArrowDown", 2)
    press("ArrowLeft", 4)
    expect(page.locator("#position")).to_have_text("[1, 5, 3]")
    expect(page.locator("#goal-note")).to_have_text("You are at Radiology.")
    expect(page.locator("#destinations li")).to_have_text(["Radiology · G0 [1, 5, 3]"])
    screenshot(page, "walk-floors", full_page=True)
