"""/docs (Swagger UI) and /redoc (ReDoc) render offline: their assets come from the service."""

from __future__ import annotations

from urllib.parse import urlsplit

import pytest
from playwright.sync_api import Page, Route, expect

from tests.browser.conftest import Service, screenshot

pytestmark = pytest.mark.browser


def offline(page: Page) -> list[str]:
    """Refuse (and list) every request that would leave this machine, as it is offline."""
    outside: list[str] = []

    def handle(route: Route) -> None:
        url = route.request.url
        if urlsplit(url).hostname not in ("127.0.0.1", "localhost") and not url.startswith("data:"):
            outside.append(url)
            route.abort()
        else:
            route.continue_()

    page.route("**/*", handle)
    return outside


def test_swagger_ui_renders_the_api_offline(service: Service, page: Page) -> None:
    outside = offline(page)
    page.goto(service.base + "/docs")
    expect(page.locator(".swagger-ui .info .title")).to_contain_text("Hidden-goal advisor")
    expect(page.locator(".opblock-summary-path").first).to_be_visible()
    assert page.locator(".opblock-summary-path", has_text="/sessions/{session_id}/events").count()
    screenshot(page, "docs")
    assert outside == []


def test_redoc_renders_the_api_offline(service: Service, page: Page) -> None:
    outside = offline(page)
    page.goto(service.base + "/redoc")
    expect(page.locator("h1").first).to_contain_text("Hidden-goal advisor")
    expect(page.get_by_text("/sessions/{session_id}/events").first).to_be_attached()
    screenshot(page, "redoc")
    assert outside == []


def test_the_dashboards_api_link_opens_the_docs(service: Service, page: Page) -> None:
    outside = offline(page)
    page.goto(service.base + "/")
    page.get_by_role("link", name="API").click()
    expect(page).to_have_url(service.base + "/docs")
    expect(page.locator(".swagger-ui .info .title")).to_contain_text("Hidden-goal advisor")
    assert outside == []
