"""What a browser can do to the viewer (the issue: any page could open its websocket and set
the kappa slider to -5, NaN or 1e308 for every viewer, pick values no dropdown offers, make the
server buffer file-upload parts without limit; a 500 x 500 domain sent 55 MB to a browser).

A browser here is a program speaking viser's protocol (tests/viewer/conftest.py: Browser), so
that it can send what a page's script could forge."""

from __future__ import annotations

import time
import uuid
from collections.abc import Iterator

import numpy as np
import pytest
from viser import _messages
from websockets.exceptions import ConnectionClosed, InvalidStatus

from app.domain.grid import GridDomain
from app.service.config import Settings
from app.viewer.controls import NONE
from app.viewer.guard import MAX_CLIENTS, MAX_MESSAGE, origins
from app.viewer.scene import DETAIL_CELLS
from app.viewer.state import DomainView, Snapshot
from app.viewer.viewer import ClientView, Viewer
from tests.viewer.conftest import Browser, FakeFeed, free_port, wait_until, walk
from tests.viewer.test_viewer import snapshot


@pytest.fixture
def bare(feed: FakeFeed) -> Iterator[Viewer]:
    """A viewer with no browser yet (its pump off: tests tick it)."""
    v = Viewer(feed, port=free_port())
    v.start(pump=False)
    yield v
    v.stop()


def view_of(viewer: Viewer, before: set[int]) -> ClientView:
    """The view of the browser that connected after ``before``."""
    wait_until(lambda: set(viewer.views) - before)
    return viewer.views[next(iter(set(viewer.views) - before))]


def settled(browser: Browser) -> int:
    """The bytes the browser has received once nothing more arrives for half a second."""
    seen = -1
    while browser.received != seen:
        seen = browser.received
        time.sleep(0.5)
    return seen


def update(browser: Browser, handle: object, value: object) -> None:
    """A GUI change as a page would send it, with any value in it."""
    browser.send_raw({"type": "GuiUpdateMessage", "uuid": handle._impl.uuid,  # type: ignore[attr-defined]
                      "updates": {"value": value}})  # fmt: skip


def test_each_browser_has_its_own_controls_and_a_forged_value_is_put_back(
    bare: Viewer, feed: FakeFeed, domain: GridDomain, theta: np.ndarray
) -> None:
    feed.snapshot = snapshot(domain, theta, 2)
    one = Browser(bare.port)
    a = view_of(bare, set())
    two = Browser(bare.port)
    b = view_of(bare, {a.client.client_id})
    bare.tick()
    update(one, a.controls.kappa, 1e308)  # beyond the slider
    update(one, a.controls.session, "not-a-session")  # no option of the dropdown
    update(one, a.controls.lost, 7)  # not even text (viser makes it "7": no option either)
    wait_until(lambda: a.controls.kappa.value == 1e308 and a.controls.lost.value == "7")
    bare.tick()
    assert a.controls.picked_kappa == 1.4 and a.controls.kappa.value == 1.4
    assert a.controls.picked_session is None and a.controls.session.value == NONE
    assert a.controls.lost.value == a.controls.lost.options[0]
    # the other browser saw none of it
    assert b.controls.kappa.value == 0.5 and b.scene is not None
    update(two, b.controls.kappa, 0.2)
    wait_until(lambda: b.controls.kappa.value == 0.2)
    bare.tick()
    assert a.controls.picked_kappa == 1.4 and b.controls.picked_kappa == 0.2
    assert a.scene is not None and not np.array_equal(a.scene.shaded, b.scene.shaded)
    one.close()
    two.close()


def test_uploads_are_dropped_and_big_messages_close_the_connection(bare: Viewer) -> None:
    browser = Browser(bare.port, max_size=None)
    view = view_of(bare, set())
    transfer = str(uuid.uuid4())
    browser.send(_messages.FileTransferStartUpload(
        source_component_uuid=view.controls.kappa._impl.uuid, transfer_uuid=transfer,
        filename="x", mime_type="application/octet-stream", part_count=100,
        size_bytes=100 * 1024 * 1024,
    ))  # fmt: skip
    for i in range(3):  # parts under the message limit: dropped, not buffered
        browser.send(_messages.FileTransferPart(
            source_component_uuid=None, transfer_uuid=transfer, part_index=i,
            content=b"x" * (MAX_MESSAGE // 2),
        ))  # fmt: skip
    assert not view.client.gui._current_file_upload_states
    assert not bare.server.gui._current_file_upload_states  # type: ignore[union-attr]
    with pytest.raises(ConnectionClosed):  # one over the limit: closed (1009), never read
        browser.send_raw({"type": "FileTransferPart", "content": b"x" * (MAX_MESSAGE + 1)})
        for _ in range(50):
            browser.socket.ping().wait(1)
    wait_until(lambda: not bare.views)
    browser.close()


def test_a_page_of_another_origin_is_refused(bare: Viewer) -> None:
    with pytest.raises(InvalidStatus) as refused:
        Browser(bare.port, origin="https://evil.example")
    assert refused.value.response.status_code == 403
    ok = Browser(bare.port, origin=f"http://127.0.0.1:{bare.port}")  # its own page
    view_of(bare, set())
    ok.close()


def test_more_browsers_than_the_cap_are_refused(bare: Viewer) -> None:
    browsers = [Browser(bare.port) for _ in range(MAX_CLIENTS)]
    wait_until(lambda: len(bare.views) == MAX_CLIENTS)
    with pytest.raises(InvalidStatus) as refused:
        Browser(bare.port)
    assert refused.value.response.status_code == 503
    for b in browsers:
        b.close()


def test_a_500_by_500_domain_is_sent_in_a_bounded_form(bare: Viewer, feed: FakeFeed) -> None:
    rows = ["S" + "." * 498 + "G"] + ["." * 500] * 498 + ["#" * 499 + "G"]
    big = GridDomain.from_strings(rows, name="big")
    assert big.n_states > DETAIL_CELLS
    theta = np.random.default_rng(0).dirichlet(np.ones(4), size=big.n_states)
    rng = np.random.default_rng(1)
    sessions = [walk(big, theta, f"w{i}", 100, rng) for i in range(3)]
    feed.snapshot = Snapshot({"big": DomainView(big, theta)}, sessions)
    browser = Browser(bare.port)
    view = view_of(bare, set())
    start = browser.received
    bare.tick()
    assert view.scene is not None and view.scene.prior_arrows is None
    sent = settled(browser) - start
    print(f"\na 500 x 500 domain: {sent / 1e6:.2f} MB sent to a browser")
    assert sent < 3_000_000  # 55 MB before: four arrows and a tile per cell
    browser.close()


def test_with_the_docker_settings_loopback_pages_are_let_in_and_others_refused(
    feed: FakeFeed,
) -> None:
    """The Docker recipe: the viewer on 0.0.0.0 in the container, published on the host's
    127.0.0.1 (the issue: it allowed only pages of http://0.0.0.0:<port>, so the browser's page
    at http://127.0.0.1:8080 was refused). Origins of ADVISOR_VIEWER_ORIGINS are let in too;
    any other page is still refused."""
    assert {"http://127.0.0.1:8080", "http://localhost:8080"} <= set(origins("0.0.0.0", 8080))
    assert "http://localhost:8080" in origins("::", 8080)
    assert "http://127.0.0.1:8080" not in origins("192.0.2.7", 8080)  # a host of its own
    assert origins("192.0.2.7", 8080, ("http://viewer.example",))[:2] == [
        "http://192.0.2.7:8080", "http://viewer.example",
    ]  # fmt: skip
    v = Viewer(feed, host="0.0.0.0", port=free_port(), origins=("http://127.0.0.1:9090",))
    v.start(pump=False)
    try:
        for page in (f"http://127.0.0.1:{v.port}", f"http://localhost:{v.port}",
                     "http://127.0.0.1:9090"):  # fmt: skip
            before = set(v.views)
            browser = Browser(v.port, origin=page)
            view_of(v, before)
            browser.close()
        for page in ("https://evil.example", f"http://0.0.0.0.evil.example:{v.port}",
                     f"http://192.0.2.7:{v.port}", "http://127.0.0.1:9091"):  # fmt: skip
            with pytest.raises(InvalidStatus) as refused:
                Browser(v.port, origin=page)
            assert refused.value.response.status_code == 403, page
    finally:
        v.stop()


@pytest.mark.parametrize("bad", ["http://x.example/viewer", "ftp://x.example", "*", "x.example"])
def test_a_viewer_origin_that_is_no_origin_is_refused_in_the_settings(bad: str) -> None:
    with pytest.raises(ValueError, match="is not the origin of a page"):
        Settings(viewer_origins=[bad])
    assert Settings(viewer_origins=["HTTP://Viewer.Example:9090/"]).viewer_origins == [
        "http://viewer.example:9090"
    ]
