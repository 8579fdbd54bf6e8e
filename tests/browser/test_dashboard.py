"""The dashboard at / lists live sessions and keeps their figures up to date."""

from __future__ import annotations

import re

import pytest
from playwright.sync_api import Page, expect

from tests.browser.conftest import Service, screenshot

pytestmark = pytest.mark.browser


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
    screenshot(page, "dashboard")
