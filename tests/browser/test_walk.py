"""/walk: a person walks with the arrow keys; moves reach the service; advice shows when given."""

from __future__ import annotations

import json
import random
import re

import pytest
from playwright.sync_api import Page, expect

from app.domain.generate import generate_building_domain
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
    assert float(page.locator("#p-normal").inner_text()) > 0.5
    expect(page.locator("#advice")).to_be_hidden()
    # the KL beside kappa, and why no advice; P(M1|H) after each decision (the start's too)
    kl = page.locator("#kl").inner_text()
    assert re.fullmatch(r"\d+\.\d{3} nats", kl)
    rule = page.locator("#kl-rule")
    expect(rule).to_have_text(f"KL {kl.split()[0]} < κ 0.5 → not advised")
    chart = page.locator("#p-chart")
    expect(chart).to_have_attribute("data-points", "4")
    assert float(chart.get_attribute("data-last") or "nan") == pytest.approx(
        float(page.locator("#p-normal").inner_text()), abs=6e-4
    )
    # the legend names what the maze shows, each with a swatch drawn as the maze draws it
    legend = page.locator("#maze-legend li")
    expect(legend).to_have_count(7)
    expect(page.locator("#maze-legend li canvas.swatch")).to_have_count(7)
    for item in ("wall", "start", "goal", "walker", "path", "advised", "advice"):
        expect(page.locator(f'#maze-legend li[data-item="{item}"]')).to_be_visible()

    # a lost-looking walk: bumping into the walls and going back and forth
    for key in ["ArrowDown", "ArrowDown", "ArrowLeft", "ArrowRight", "ArrowLeft", "ArrowRight"]:
        page.keyboard.press(key)
    expect(page.locator("#steps")).to_have_text("9")
    expect(page.locator("#advice")).to_be_visible()
    expect(rule).to_have_text(re.compile(r"^KL \d+\.\d{3} ≥ κ 0\.5 → advised$"))
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
    shown_p = float(page.locator("#p-normal").inner_text())
    assert shown_p == pytest.approx(seen["p_normal"], abs=6e-4)
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
    advised = 0
    for _ in range(3000):
        page.wait_for_function("document.body.dataset.pending === '0'")
        seen = page.evaluate("() => ({...document.body.dataset})")
        if seen["goal"]:
            break
        state = grid.state(*json.loads(seen["position"]))
        if seen["advice"]:
            advice = json.loads(seen["advice"])
            heading = max("NESW", key=lambda a: advice[a])
            advised += 1
        else:
            heading = rng.choice([a for i, a in enumerate("NESW") if grid.open_moves[state, i]])
        page.keyboard.press(KEY[heading])
    else:
        pytest.fail("the walker did not reach a destination in 3,000 moves")
    assert advised > 0
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
