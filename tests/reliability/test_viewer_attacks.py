"""A browser's attacks on the viewer, fed by the real service (the issue: any page could open
the viewer's websocket and set the kappa slider to -5, NaN or 1e308 for every viewer, pick
values no dropdown offers, and picking a 500 x 500 domain sent 55 MB to a browser).

The service is ``python -m app serve`` holding a 500 x 500 domain with explorers walking on
it; the viewer reads it over HTTP with the operator key (:class:`RemoteFeed`, as ``python -m app
viewer`` does) in this process, so that the test can see what each browser's controls and
scene hold. The attacker is a program speaking viser's protocol (tests/viewer/conftest.py:
Browser), sending what a page's script could forge."""

from __future__ import annotations

import math
from pathlib import Path

import httpx
import numpy as np

from app.domain.grid import ACTIONS, GridDomain
from app.strategies import STRATEGIES
from app.viewer.controls import NONE, SLIDER_KAPPA_HIGH
from app.viewer.remote import RemoteFeed
from app.viewer.scene import DETAIL_CELLS
from app.viewer.viewer import Viewer
from tests.reliability.conftest import server_errors, start, stop
from tests.viewer.conftest import Browser, free_port, wait_until
from tests.viewer.test_guard import settled, update, view_of

BIG = ["S" + "." * 498 + "G"] + ["." * 500] * 498 + ["#" * 499 + "G"]


def test_forged_values_and_a_500_by_500_domain_against_the_viewer_of_a_live_service(
    tmp_path: Path,
) -> None:
    live = start(tmp_path / "data")
    key = (live.data_dir / "operator_key").read_text().strip()
    http = httpx.Client(base_url=live.url, timeout=120)
    viewer = Viewer(RemoteFeed(http, key), port=free_port())
    try:
        r = http.put("/domains/zbig", json={"map": BIG}, headers=live.admin)
        assert r.status_code == 201, r.text
        big = GridDomain.from_strings(BIG, name="zbig")
        assert big.n_states > DETAIL_CELLS
        rng = np.random.default_rng(3)
        for _ in range(3):  # explorers walking on it, so that paths are drawn too
            made = http.post("/domains/zbig/sessions", json={}).json()
            auth = {"Authorization": f"Bearer {made['token']}"}
            s, moves = big.start, []
            for a in rng.integers(0, 4, 100).tolist():
                moves.append({"state": list(big.cell(s)), "action": ACTIONS[a]})
                s = big.step(s, a)
            r = http.post(f"/sessions/{made['session_id']}/events", json=moves, headers=auth)
            assert r.status_code == 200, r.text

        viewer.start(pump=False)
        attacker = Browser(viewer.port)
        mine = view_of(viewer, set())
        bystander = Browser(viewer.port)
        theirs = view_of(viewer, {mine.client.client_id})
        viewer.tick()
        controls = mine.controls
        assert controls.domain.options == ("default", "zbig")
        assert controls.picked_domain == "default"

        # values no dropdown offers: put back to an option, for this browser only
        update(attacker, controls.domain, "no-such-domain")
        update(attacker, controls.session, "not-a-session")
        update(attacker, controls.lost, 7)
        wait_until(lambda: controls.domain.value == "no-such-domain" and controls.lost.value == "7")
        viewer.tick()
        assert controls.picked_domain == "default" and controls.domain.value == "default"
        assert controls.picked_session is None and controls.session.value == NONE
        assert controls.lost.value == controls.lost.options[0]

        # kappa out of the slider's range, or not a number: put back in [0, the slider's top],
        # every strategy's range as the service says it (above the paper's, log 4)
        high = controls.kappa_high
        assert high == max(e.kappa_max or 0.0 for e in STRATEGIES.values()) > SLIDER_KAPPA_HIGH
        for sent, kept in (
            (math.nan, 0.5),
            (math.inf, 0.5),
            (-5.0, 0.0),
            (1e308, high),
        ):
            update(attacker, controls.kappa, sent)

            def arrived(value: float = sent) -> bool:
                return _same(controls.kappa.value, value)

            wait_until(arrived)
            viewer.tick()
            assert controls.picked_kappa == kept and controls.kappa.value == kept, sent
            assert f"kappa = {kept:.2f}" in controls.shading_text.content
        update(attacker, controls.kappa, "x")  # viser cannot make a float of it: unchanged
        viewer.tick()
        assert controls.picked_kappa == high

        # the 500 x 500 domain, picked by the attacker: the map as an image, no prior arrows
        before = settled(attacker)
        update(attacker, controls.domain, "zbig")
        wait_until(lambda: controls.domain.value == "zbig")
        viewer.tick()
        assert mine.scene is not None and mine.scene.domain.n_states == big.n_states
        assert mine.scene.prior_arrows is None and len(mine.scene.session_ids) == 3
        sent_bytes = settled(attacker) - before
        print(f"\n500 x 500 domain of a live service: {sent_bytes / 1e6:.2f} MB to a browser")
        assert sent_bytes < 3_000_000  # 55 MB before: four arrows and a tile per cell

        # the other browser saw none of it
        viewer.tick()
        assert theirs.controls.picked_domain == "default" and theirs.controls.kappa.value == 0.5
        assert theirs.scene is not None and theirs.scene.domain.name == "default"
        attacker.close()
        bystander.close()
    finally:
        viewer.stop()
        http.close()
        stop(live)
    assert server_errors(live) == []


def _same(value: object, sent: float) -> bool:
    return isinstance(value, float) and (value == sent or (math.isnan(sent) and math.isnan(value)))
