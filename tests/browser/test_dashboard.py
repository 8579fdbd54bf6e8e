"""The dashboard at / lists live sessions and keeps their figures up to date; its figures have
a legend and units, plain words first and the paper's symbol second, coloured as each
strategy reads them; its sessions sort by any column and end with the admin key (the
read-only key's End buttons are disabled, saying why)."""

from __future__ import annotations

import re

import pytest
from playwright.sync_api import Page, Route, expect

from tests.browser.conftest import ADMIN, Service, screenshot
from tests.browser.test_walk import LIFTS

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
    expect(row.locator('td[data-column="strategy"]')).to_have_text("paper")
    expect(row.locator('td[data-column="steps"]')).to_have_text("3")
    expect(page.locator('tr[data-domain="default"]')).to_contain_text("30×30")
    # the page polls: more moves show up without a reload
    service.move(sid, auth, [28, 3], "WW")
    expect(row.locator('td[data-column="steps"]')).to_have_text("5")
    expect(row.locator('td[data-column="position"]')).to_have_text("[28, 1]")
    expect(row.locator('td[data-column="floor"]')).to_have_text("–")  # one floor
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


def test_the_key_form_stays_put_while_the_health_line_fills_in(
    service: Service, page: Page
) -> None:
    """The line of what the service relies on is a line high before ``/health`` answers: when
    it fills in, the key form below it does not move (it did, and a click on "Show live
    sessions" made at that moment landed elsewhere)."""
    page.goto(service.base + "/")
    strip = page.locator("#dependencies")
    expect(strip.locator(".dependency").first).to_be_visible()
    filled = page.locator("#key-form").bounding_box()
    strip.evaluate("p => p.replaceChildren()")  # as the page is before /health answers
    empty = page.locator("#key-form").bounding_box()
    assert filled is not None and empty is not None
    assert abs(filled["y"] - empty["y"]) < 0.5, (filled, empty)


def test_dashboard_figures_have_a_legend_and_units(service: Service, page: Page) -> None:
    sid, _ = service.new_session("EEEWW")
    show_sessions(service, page, service.operator_key)
    row = page.locator(f'tr[data-session-id="{sid}"]')
    expect(row).to_be_visible()
    legend = page.locator("#legend")
    expect(legend).to_be_visible()
    # the legend's samples are drawn as the table's cells are: a bar of each tone, a line
    for tone in ("good", "neutral", "bad"):
        expect(legend.locator(f".bar.tone-{tone}")).to_have_count(1)
    expect(legend.locator("svg.spark polyline")).to_have_count(1)
    expect(legend).to_contain_text("blue, nothing to do; amber, the advisor is handling it")
    expect(legend).to_contain_text("cost = κ × advice given")
    # the row draws the same things, with the 0.5 line of the sparkline
    expect(row.locator(".bar")).to_have_count(1)
    expect(row.locator("svg.spark line.half")).to_have_count(1)
    units = {
        "kappa": "κ, nats", "steps": "moves", "position": "[row, col] ([floor, row, col])",
        "floor": "buildings of floors",
        "p": "plain words (the paper's symbol)", "leads": "destination",
        "cost": "κ × advice, nats", "per100": "decisions",
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


def test_dashboard_disables_end_for_the_read_only_key_saying_why(
    service: Service, page: Page
) -> None:
    """The service refuses the operator key's DELETE (403); the page, told the key's role by
    GET /overview, offers no button it would refuse: End is disabled, its tooltip says why,
    and a click sends nothing."""
    sid, _ = service.new_session("EE")
    refusal = service.http.delete(f"/sessions/{sid}", headers={"X-API-Key": service.operator_key})
    assert refusal.status_code == 403
    deletes: list[str] = []
    page.on("request", lambda r: deletes.append(r.url) if r.method == "DELETE" else None)
    show_sessions(service, page, service.operator_key)
    row = page.locator(f'tr[data-session-id="{sid}"]')
    end = row.get_by_role("button", name="End")
    expect(end).to_be_disabled()
    expect(end).to_have_attribute("title", re.compile(r"^This key can only read: .*admin key"))
    expect(page.locator("#role-note")).to_have_text(re.compile(r"^This key can only read: .*"))
    end.click(force=True)  # a disabled button: nothing happens
    page.evaluate("document.querySelector('#sessions tbody tr').dataset.stale = 'yes'")
    page.wait_for_function("!document.querySelector('#sessions tbody tr[data-stale]')")
    expect(page.locator("#session-message")).to_be_hidden()
    assert deletes == []
    expect(row).to_be_visible()
    answer = service.http.get(f"/sessions/{sid}", headers={"X-API-Key": ADMIN})
    assert answer.status_code == 200, answer.text
    # the admin key's End is live again
    page.click("#forget-key")
    show_sessions(service, page, ADMIN)
    expect(row.get_by_role("button", name="End")).to_be_enabled()
    expect(page.locator("#role-note")).to_be_hidden()
    page.click("#forget-key")
    show_sessions(service, page, service.operator_key)
    expect(end).to_be_disabled()
    end.hover()
    screenshot(page, "dashboard-read-only")


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
    left = page.locator(f'tr[data-session-id="{budgeted}"] td[data-column="left"]')
    expect(left).to_have_text("4 of 5, 3/min of 4")  # the start decision took one
    expect(page.locator(f'tr[data-session-id="{muted}"] td[data-column="left"]')).to_have_text(
        "muted"
    )


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


#: a small building with its two destinations named
NAMED = "destination: 1 1 Lobby\ndestination: 1 5 Café (east)\n" + "\n".join(
    ["#######", "#G..#G#", "#.#.#.#", "#...#.#", "###...#", "#S....#", "#######"]
)


def test_dashboard_says_what_each_strategy_believes_plain_words_first(
    service: Service, page: Page
) -> None:
    """A paper session that looks lost reads red, "looks lost" (P(M2|H)); a guide session
    whose walker looks lost and follows the advice reads amber (guide is leading it, not red),
    with the destination its advice leads to, by name."""
    put = service.http.put("/domains/named-dash?experts=start&per_goal=3", content=NAMED,
                           headers={"X-API-Key": ADMIN, "Content-Type": "text/plain"})  # fmt: skip
    assert put.status_code in (200, 201), put.text
    lost, _ = service.new_session("SSWWSSWWSSWW")  # into the walls of the start's corner
    made = service.http.post("/domains/named-dash/sessions", json={"strategy": "guide", "kappa": 0})
    led, auth = made.json()["session_id"], {"Authorization": f"Bearer {made.json()['token']}"}
    decision = made.json()["decision"]
    for i in range(14):  # bumps into the walls, then follows the advice
        a = "SW"[i % 2] if i < 12 or not decision["advise"] else max(
            "NESW", key=lambda k: decision["advice"][k])  # fmt: skip
        r = service.http.post(f"/sessions/{led}/events", headers=auth,
                              json={"state": decision["state"], "action": a})  # fmt: skip
        decision = r.json()
    seen = service.http.get(f"/sessions/{led}", headers=auth).json()["beliefs"]
    assert seen["figures"][seen["headline"]]["tone"] == "neutral", seen
    to = seen["leads_to"]
    show_sessions(service, page, service.operator_key)

    paper = page.locator(f'tr[data-session-id="{lost}"] td[data-column="p"]')
    expect(paper).to_have_text(re.compile(r"^looks lost: \d+% \(P\(M2\|H\)\)$"))
    expect(paper).to_have_attribute("data-tone", "bad")
    expect(paper.locator(".bar")).to_have_class(re.compile("tone-bad"))
    expect(paper).to_have_attribute("title", re.compile(r"moves like someone who knows"))
    guided = page.locator(f'tr[data-session-id="{led}"] td[data-column="p"]')
    expect(guided).to_have_text(re.compile(r"^looks lost: \d+% \(P\(lost\|H\)\)$"))
    expect(guided).to_have_attribute("data-tone", "neutral")
    expect(guided.locator(".bar")).to_have_class(re.compile("tone-neutral"))
    assert "rgb(214, 69, 69)" not in guided.locator("span.tone-neutral:not(.bar)").evaluate(
        "e => getComputedStyle(e).color"
    )  # not the red of "bad"
    leads = page.locator(f'tr[data-session-id="{led}"] td[data-column="leads"]')
    expect(leads).to_have_text(f"{to['name']} (G{to['goal']})")
    assert to["name"] in ("Lobby", "Café (east)")
    expect(page.locator('#sessions th[data-column="p"]')).to_contain_text("Advisor believes")
    screenshot(page, "dashboard-beliefs")


def test_dashboard_shows_the_floor_of_a_session_in_a_building(service: Service, page: Page) -> None:
    """A session on a map of several floors: its position [floor, row, col] and its floor by
    name, followed as it rides the lift up."""
    r = service.http.put("/domains/lifts", json={"text": LIFTS}, headers={"X-API-Key": ADMIN})
    assert r.status_code in (200, 201), r.text
    created = service.http.post("/domains/lifts/sessions", json={}).json()
    sid, auth = created["session_id"], {"Authorization": f"Bearer {created['token']}"}
    events = [{"state": [0, 3, c], "action": "E"} for c in range(1, 7)]
    events.append({"state": [0, 3, 7], "action": "U"})
    r = service.http.post(f"/sessions/{sid}/events", json=events[:6], headers=auth)
    assert r.status_code == 200, r.text
    page.goto(service.base + "/")
    page.fill("#key", service.operator_key)
    page.click("#key-form button[type=submit]")
    row = page.locator(f'tr[data-session-id="{sid}"]')
    expect(row.locator('td[data-column="position"]')).to_have_text("[0, 3, 7]")
    expect(row.locator('td[data-column="floor"]')).to_have_text("Ground floor")
    r = service.http.post(f"/sessions/{sid}/events", json=events[6], headers=auth)
    assert r.status_code == 200 and r.json()["state"] == [1, 3, 7], r.text
    expect(row.locator('td[data-column="floor"]')).to_have_text("First floor")
    expect(row.locator('td[data-column="position"]')).to_have_text("[1, 3, 7]")
