"""The dashboard at / lists live sessions and keeps their figures up to date; its figures have
a legend and units, its sessions sort by any column and end with the admin key."""

from __future__ import annotations

import re

import pytest
from playwright.sync_api import Page, Route, expect

from tests.browser.conftest import ADMIN, Problems, Service, screenshot

pytestmark = pytest.mark.browser


def show_sessions(service: Service, page: Page, key: str) -> None:
    page.goto(service.base + "/")
    page.fill("#key", key)
    page.click("#key-form button[type=submit]")


def order_of(page: Page, ids: list[str]) -> list[str]:
    """The rows of these sessions, top to bottom."""
    shown = page.locator("#sessions tbody tr").evaluate_all(
        "rows => rows.map(r => r.dataset.sessionId)"
    )
    return [sid for sid in shown if sid in ids]


def test_dashboard_lists_a_session_and_refreshes_its_figures(service: Service, page: Page) -> None:
    sid, auth = service.new_session("EEE")
    page.goto(service.base + "/")
    # without a key: the figures per domain, no session's
    expect(page.locator('tr[data-domain="default"]')).to_be_visible()
    expect(page.locator("#sessions")).to_contain_text("shown with the operator key")
    expect(page.locator(f'tr[data-session-id="{sid}"]')).to_have_count(0)
    page.fill("#key", service.operator_key)
    page.click("#key-form button[type=submit]")
    row = page.locator(f'tr[data-session-id="{sid}"]')
    expect(row).to_be_visible()
    expect(row.locator("td").nth(3)).to_have_text("paper")  # strategy
    expect(row.locator("td").nth(5)).to_have_text("3")  # steps
    expect(page.locator('tr[data-domain="default"]')).to_contain_text("30×30")
    # the page polls: more moves show up without a reload
    service.move(sid, auth, [28, 3], "WW")
    expect(row.locator("td").nth(5)).to_have_text("5")
    expect(row.locator("td").nth(6)).to_have_text("[28, 1]")
    link = page.locator("#viewer-link")
    expect(link).to_be_visible()
    expect(link).to_have_attribute("href", re.compile(rf":{service.viewer.port}/$"))


def test_dashboard_hides_the_viewer_link_while_the_viewer_is_down(
    service: Service, page: Page
) -> None:
    """The page asks GET /viewer again every few seconds: a viewer that died hides the link,
    one that runs again shows it (the answer is the service's, with ``running`` set here)."""
    running = {"now": True}

    def viewer(route: Route) -> None:
        answer = service.http.get("/viewer").json() | {"running": running["now"]}
        route.fulfill(json=answer)

    page.route("**/viewer", viewer)
    page.goto(service.base + "/")
    link = page.locator("#viewer-link")
    expect(link).to_be_visible()
    running["now"] = False
    expect(link).to_be_hidden(timeout=15_000)
    running["now"] = True
    expect(link).to_be_visible(timeout=15_000)
    expect(link).to_have_attribute("href", re.compile(rf":{service.viewer.port}/$"))


def test_dashboard_figures_have_a_legend_and_units(service: Service, page: Page) -> None:
    sid, _ = service.new_session("EEEWW")
    show_sessions(service, page, service.operator_key)
    row = page.locator(f'tr[data-session-id="{sid}"]')
    expect(row).to_be_visible()
    legend = page.locator("#legend")
    expect(legend).to_be_visible()
    # the legend's samples are drawn as the table's cells are: a bar of each colour, a line
    expect(legend.locator(".bar:not(.lost)")).to_have_count(1)
    expect(legend.locator(".bar.lost")).to_have_count(1)
    expect(legend.locator("svg.spark polyline")).to_have_count(1)
    expect(legend).to_contain_text("blue at 0.5 or more")
    expect(legend).to_contain_text("cost = κ × advice given")
    # the row draws the same things, with the 0.5 line of the sparkline
    expect(row.locator(".bar")).to_have_count(1)
    expect(row.locator("svg.spark line.half")).to_have_count(1)
    units = {
        "kappa": "nats", "steps": "moves", "position": "[row, col]", "p": "0 to 1",
        "cost": "nats", "per100": "decisions",
    }  # fmt: skip
    for column, unit in units.items():
        expect(page.locator(f'#sessions th[data-column="{column}"] .unit')).to_have_text(unit)
    expect(page.locator("#domains th .unit").first).to_be_visible()
    screenshot(page, "dashboard")


def test_dashboard_sorts_sessions_by_the_column_clicked(service: Service, page: Page) -> None:
    mine = {service.new_session(moves)[0]: len(moves) for moves in ("E", "EEEE", "EE")}
    ids = list(mine)
    show_sessions(service, page, service.operator_key)
    for sid in ids:
        expect(page.locator(f'tr[data-session-id="{sid}"]')).to_be_visible()
    # at first, the service's order: the most recently active first
    assert order_of(page, ids) == ids[::-1]
    steps = page.locator('#sessions th[data-column="steps"]')
    steps.get_by_role("button").click()
    expect(steps).to_have_attribute("aria-sort", "ascending")
    expect(steps).to_contain_text("▲")
    expect(page.locator("#sort-note")).to_contain_text("sorted by Steps, ascending")
    assert order_of(page, ids) == sorted(ids, key=mine.__getitem__)
    steps.get_by_role("button").click()
    expect(steps).to_have_attribute("aria-sort", "descending")
    expect(steps).to_contain_text("▼")
    assert order_of(page, ids) == sorted(ids, key=mine.__getitem__, reverse=True)
    # the order holds across the page's polls (the table is redrawn each second)
    page.evaluate("document.querySelector('#sessions tbody tr').dataset.stale = 'yes'")
    page.wait_for_function("!document.querySelector('#sessions tbody tr[data-stale]')")
    assert order_of(page, ids) == sorted(ids, key=mine.__getitem__, reverse=True)
    session = page.locator('#sessions th[data-column="session"]')
    session.get_by_role("button").click()
    expect(session).to_have_attribute("aria-sort", "ascending")
    expect(steps).to_have_attribute("aria-sort", "none")
    assert order_of(page, ids) == sorted(ids)


def test_dashboard_ends_a_session_with_the_admin_key(service: Service, page: Page) -> None:
    sid, _ = service.new_session("EE")
    show_sessions(service, page, ADMIN)
    row = page.locator(f'tr[data-session-id="{sid}"]')
    row.get_by_role("button", name="End").click()
    expect(page.locator("#session-message")).to_have_text(re.compile(rf"Session {sid} ended"))
    expect(row).to_have_count(0)
    answer = service.http.get(f"/sessions/{sid}", headers={"X-API-Key": ADMIN})
    assert answer.status_code == 404, answer.text


def test_dashboard_shows_why_the_operator_key_cannot_end_a_session(
    service: Service, page: Page, problems: Problems
) -> None:
    problems.expect(r"the server responded with a status of 403")  # the browser's own line
    sid, _ = service.new_session("EE")
    refusal = service.http.delete(f"/sessions/{sid}", headers={"X-API-Key": service.operator_key})
    assert refusal.status_code == 403
    detail = refusal.json()["detail"]
    show_sessions(service, page, service.operator_key)
    row = page.locator(f'tr[data-session-id="{sid}"]')
    row.get_by_role("button", name="End").click()
    message = page.locator("#session-message")
    expect(message).to_contain_text(f"Could not end session {sid}: 403: {detail}")
    expect(message).to_have_class(re.compile("error"))
    expect(row).to_be_visible()  # still live
    answer = service.http.get(f"/sessions/{sid}", headers={"X-API-Key": ADMIN})
    assert answer.status_code == 200, answer.text
    assert problems.seen_expected  # the refusal really was the service's 403
    screenshot(page, "dashboard-refused")


def test_dashboard_shows_each_session_s_advice_left(service: Service, page: Page) -> None:
    """A session's budget (pieces left in all, this minute) and a muted visitor's mute."""
    made = service.http.post(
        "/domains/default/sessions", json={"kappa": 0.0, "budget": {"total": 5, "per_minute": 4}}
    ).json()
    budgeted = made["session_id"]
    muted, auth = service.new_session("E")
    assert service.http.post(f"/sessions/{muted}/mute", headers=auth).status_code == 200
    show_sessions(service, page, service.operator_key)
    expect(page.locator('#sessions th[data-column="left"] .unit')).to_have_text("budget")
    left = page.locator(f'tr[data-session-id="{budgeted}"] td').nth(12)
    expect(left).to_have_text("4 of 5, 3/min of 4")  # the start decision took one
    expect(page.locator(f'tr[data-session-id="{muted}"] td').nth(12)).to_have_text("muted")


def test_dashboard_shows_what_the_service_relies_on(service: Service, page: Page) -> None:
    """Each dependency of GET /health, by name and state: the database up, Redis not used
    (sessions in this process), the MQTT bridge off, the viewer as the service sees it."""
    health = service.http.get("/health").json()["dependencies"]
    page.goto(service.base + "/")
    strip = page.locator("#dependencies")
    expect(strip.locator('[data-dependency="database"]')).to_have_text("Database: up")
    expect(strip.locator('[data-dependency="redis"]')).to_have_text("Redis: not used")
    expect(strip.locator('[data-dependency="mqtt"]')).to_have_text("MQTT bridge: off")
    viewer = strip.locator('[data-dependency="viewer"]')
    expect(viewer).to_have_text(f"3D viewer: {health['viewer']['state']}")
    expect(strip.locator(".dependency.down.required")).to_have_count(0)
