"""AdvisorClient and AsyncAdvisorClient against a real uvicorn server, REST and websocket."""

from __future__ import annotations

import asyncio
import contextlib
import socket
import threading
from collections.abc import Coroutine
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, TypeVar
from urllib.parse import urlsplit

import numpy as np
import pytest
from advisor_client import AdvisorClient, AdvisorError, AsyncAdvisorClient, DecisionFrame, api
from advisor_client.types import DomainInfo

from app.advice.advisor import Advisor
from app.advice.models import AdviceTables
from tests.client.conftest import Server

TINY = ["#######", "#G..#G#", "#.#.#.#", "#...#.#", "###...#", "#S....#", "#######"]
E = {"state": [28, 0], "action": "E"}
W = {"state": [28, 1], "action": "W"}
T = TypeVar("T")


def run_async(coro: Coroutine[Any, Any, T]) -> T:
    """Run a coroutine on a loop of its own in a worker thread.

    The browser tests' session-scoped Playwright keeps an event loop in the main thread, where
    ``asyncio.run`` would refuse to start; a fresh thread has none.
    """
    with ThreadPoolExecutor(1) as pool:
        return pool.submit(asyncio.run, coro).result()


def test_client_names_destinations_and_reads_what_guide_believes(server: Server) -> None:
    with AdvisorClient(server.url, admin_key=server.admin_key) as client:
        info = client.put_domain("tiny-named", TINY, destinations={(1, 5): "Exit"})
        assert info["goals"] == [[1, 1], [1, 5]] and info.get("goal_names") == [None, "Exit"]
        session = client.create_session("tiny-named", strategy="guide", kappa=0.0)
        decision = client.step(session, {"state": [5, 1], "action": "S"})  # into a wall
        assert decision["advise"]
        leads = decision.get("leads_to")
        assert leads is not None and leads["cell"] in info["goals"]
        assert leads["name"] == ("Exit" if leads["cell"] == [1, 5] else None)
        beliefs = client.session(session).get("beliefs")
        assert beliefs is not None and beliefs["leads_to"] == leads
        assert [f["name"] for f in beliefs["figures"]] == [
            "looks lost", "on its way", "takes the advice",
        ]  # fmt: skip
        with pytest.raises(AdvisorError, match="cell \\[2, 1\\] is a free cell"):
            client.put_domain("tiny-named", TINY, destinations={(2, 1): "Hall"})


def test_client_rest_calls(server: Server) -> None:
    with AdvisorClient(server.url, admin_key=server.admin_key) as client:
        assert client.health()["status"] == "ok"
        assert "default" in {d["name"] for d in client.domains()}
        assert client.put_domain("tiny-rest", TINY)["start"] == [5, 1]
        steps = [{"state": [5, 1], "action": "E"}, {"state": [5, 2], "action": "E"}]
        assert client.add_trajectories("tiny-rest", [{"steps": steps}]) == {
            "accepted": 1,
            "pairs": 2,
        }
        assert client.prior("tiny-rest")["trajectories"] == 1
        session = client.create_session("tiny-rest", kappa=0.0, window=10, start=(5, 1))
        assert session.decision["state"] == [5, 1] and session.kappa == 0.0
        one = client.step(session, {"state": [5, 1], "action": "E"})
        assert one["step"] == 1 and one["advise"]
        many = client.events(
            session, [{"state": [5, 2], "action": "W"}, {"state": [5, 1], "action": "E"}]
        )
        assert [d["step"] for d in many] == [2, 3]
        assert client.session(session)["steps"] == 3
        assert client.sessions()["total"] >= 1
        assert any(s["session_id"] == session.session_id for s in client.overview()["sessions"])
        assert client.end_session(session)["steps"] == 3
        aware = client.create_session("tiny-rest", strategy="goal_aware", params={"beta": 0.5})
        assert client.session(aware)["strategy"] == "goal_aware"
        goals = client.session(aware)["goals"]
        assert goals is not None and len(goals) == 2
        budgeted = client.create_session("tiny-rest", kappa=0.0, budget={"total": 1})
        assert client.session(budgeted)["budget"] == {
            "total": 1, "per_minute": None, "left": 0, "left_this_minute": None,
        }  # fmt: skip
        assert not client.step(budgeted, {"state": [5, 1], "action": "E"})["advise"]
        assert client.mute(aware)["muted"] and not client.mute(aware, False)["muted"]
        client.delete_domain("tiny-rest")


def test_client_raises_the_services_reason(server: Server) -> None:
    with AdvisorClient(server.url) as client:
        with pytest.raises(AdvisorError) as err:
            client.domain("nowhere")
        assert err.value.status == 404 and "nowhere" in err.value.detail
        with pytest.raises(AdvisorError) as err:
            client.put_domain("x", TINY)  # no admin key given to the client
        assert err.value.status == 401
        session = client.create_session()
        with pytest.raises(AdvisorError) as err:
            client.events(session, {"state": [27, 0], "action": "N"})
        assert err.value.status == 422 and err.value.detail == "event 0: state [27, 0] is a wall"
    with AdvisorClient(server.url, admin_key="wrong") as client, pytest.raises(AdvisorError) as err:
        client.sessions()
    assert err.value.status == 403


def test_client_stream_decides_in_order_and_survives_bad_frames(server: Server) -> None:
    with AdvisorClient(server.url) as client:
        session = client.create_session(window=20)
        with client.stream(session) as stream:
            assert stream.send(E)["step"] == 1
            assert [d["step"] for d in stream.send([W, E] * 250)] == list(range(2, 502))
            with pytest.raises(AdvisorError) as err:
                stream.send({"state": [28, 0], "action": "up"})
            assert err.value.status == 422
            assert stream.send(W)["step"] == 502
        assert client.session(session)["steps"] == 502


def test_client_stream_with_a_wrong_token_is_refused(server: Server) -> None:
    with AdvisorClient(server.url) as client:
        session = client.create_session()
        other = client.create_session()
        forged = type(session)(
            session.session_id, other.token, "default", 0.5, 300, session.decision
        )
        with client.stream(forged) as stream, pytest.raises(AdvisorError) as err:
            stream.send(E)
        assert err.value.status == 403 and "does not belong" in err.value.detail


def test_decisions_over_the_wire_equal_the_core(server: Server) -> None:
    """A random walk through real uvicorn: each decision equals a core Advisor's."""
    from app.domain.grid import GridDomain

    with AdvisorClient(server.url) as client:
        theta = client.prior("default")["theta"]
        grid = GridDomain.from_strings(client.domain("default")["map"])
        table = np.array([theta[r][c] for r, c in grid.cells.tolist()])
        core = Advisor(AdviceTables.paper(table), kappa=0.5, window=50)
        session = client.create_session(window=50)
        core.start(grid.start)
        rng = np.random.default_rng(7)
        s, events, expected = grid.start, [], []
        for a in rng.integers(0, 4, 400).tolist():
            s2 = grid.step(s, a)
            events.append({"state": grid.cell(s), "action": "NESW"[a]})
            expected.append(core.observe(s, a, s2))
            s = s2
        with client.stream(session) as stream:
            got = stream.send(events[:150]) + stream.send(events[150:])
    assert [d["kl"] for d in got] == [d.kl for d in expected]
    assert [d["p_normal"] for d in got] == [d.p_normal for d in expected]
    assert [d["advise"] for d in got] == [d.advise for d in expected]


def test_binary_stream_gives_the_json_streams_decisions(server: Server) -> None:
    """Two sessions alike, one streaming JSON answers, one binary (``DecisionFrame``)."""
    with AdvisorClient(server.url) as client:
        a, b = client.create_session(window=30), client.create_session(window=30)
        with client.stream(a) as text, client.stream(b, binary=True) as binary:
            for batch in ([W, E] * 200, [E], E, []):
                want = text.send(batch)
                got = binary.send(batch)
                assert isinstance(got, DecisionFrame)
                assert got.to_dicts() == (want if isinstance(want, list) else [want])
            with pytest.raises(AdvisorError) as err:  # errors: JSON text frames
                binary.send({"state": [28, 0], "action": "up"})
            assert err.value.status == 422
        assert client.session(b)["steps"] == client.session(a)["steps"] == 402

    async def scenario() -> list[int]:
        async with AsyncAdvisorClient(server.url) as client:
            session = await client.create_session()
            async with await client.stream(session, binary=True) as stream:
                frame = await stream.send([E, W])
            return [int(x) for x in frame.step]

    assert run_async(scenario()) == [1, 2]


def test_async_client_rest_and_stream(server: Server) -> None:
    async def scenario() -> tuple[int, list[int], int]:
        async with AsyncAdvisorClient(server.url, admin_key=server.admin_key) as client:
            session = await client.create_session("default", kappa=0.5)
            assert (await client.mute(session))["muted"]
            assert not (await client.mute(session, muted=False))["muted"]
            one = await client.events(session, E)
            async with await client.stream(session) as stream:
                many = await stream.send([W, E] * 10)
                with pytest.raises(AdvisorError):
                    await stream.send({"state": [28, 0]})
            summary = await client.end_session(session)
            return one["step"], [d["step"] for d in many], summary["steps"]

    one, many, steps = run_async(scenario())
    assert one == 1 and many == list(range(2, 22)) and steps == 21


def test_async_clients_in_parallel(server: Server) -> None:
    async def explorer(client: AsyncAdvisorClient) -> int:
        session = await client.create_session()
        async with await client.stream(session) as stream:
            for _ in range(20):
                await stream.send([E, W])
        return int((await client.session(session))["steps"])

    async def scenario() -> list[int]:
        async with AsyncAdvisorClient(server.url) as client:
            return list(await asyncio.gather(*(explorer(client) for _ in range(8))))

    assert run_async(scenario()) == [40] * 8


def test_client_domains_in_metres_with_experts(server: Server) -> None:
    with AdvisorClient(server.url, admin_key=server.admin_key) as client:
        made = client.put_domain(
            "tiny-m", TINY, resolution=1.0, origin=(0.0, 0.0), experts={"per_goal": 2}
        )
        assert made["resolution"] == 1.0 and made["trajectories"] == 4
        session = client.create_session("tiny-m", kappa=0.0)
        # the start is [5, 1]: x 1.5, y 1.5 (row 5 of 7 is the second from the bottom)
        walked = client.positions(session, [(1.5, 1.5), (3.4, 1.2)])
        assert [d["state"] for d in walked] == [[5, 2], [5, 3]]
        with pytest.raises(AdvisorError, match="is a wall"):
            client.positions(session, [(0.5, 0.5)])

        async def scenario() -> list[Any]:
            async with AsyncAdvisorClient(server.url, admin_key=server.admin_key) as aclient:
                s = await aclient.create_session("tiny-m")
                return await aclient.positions(s, [(2.5, 1.5)])

        assert [d["state"] for d in run_async(scenario())] == [[5, 2]]
        client.delete_domain("tiny-m")


def test_client_puts_a_map_file_as_the_project_writes_it(server: Server, tmp_path: Path) -> None:
    """put_domain_file sends the file as it is: the header a ROS map's import writes gives the
    domain its metres; a bad file is refused naming the file's line and column."""
    from app.domain.grid import Frame, GridDomain

    path = tmp_path / "lobby.txt"
    path.write_text(GridDomain.from_strings(TINY, frame=Frame(0.5, (-2.0, 1.0, 0.0))).to_text())
    with AdvisorClient(server.url, admin_key=server.admin_key) as client:
        made = client.put_domain_file("lobby-file", path, experts="anywhere")
        assert made["resolution"] == 0.5 and made["origin"] == [-2.0, 1.0, 0.0]
        assert made["map"] == TINY and made["trajectories"] == 10 * 2
        again = client.put_domain_file("lobby-file", path, 2.0, experts={"per_goal": 1})
        assert again["alpha0"] == 2.0 and again["trajectories"] == 10 * 2  # the same map: kept
        bad = tmp_path / "bad.txt"
        bad.write_text(path.read_text().replace("#G..#G#", "#G..?G#"))
        with pytest.raises(AdvisorError, match=r"^422: map: line 4, column 5: unknown character"):
            client.put_domain_file("lobby-file", bad)

        async def scenario() -> DomainInfo:
            async with AsyncAdvisorClient(server.url, admin_key=server.admin_key) as aclient:
                return await aclient.put_domain_file("lobby-file-async", path, experts="start")

        assert run_async(scenario())["resolution"] == 0.5
        client.delete_domain("lobby-file")
        client.delete_domain("lobby-file-async")


def test_the_stream_url_carries_no_token_the_header_does() -> None:
    """Proxies and servers log URLs: the websocket's token goes in its Authorization header."""
    decision: Any = {}
    session = api.Session("ab12", "t0k3n", "default", 0.5, 300, decision)
    url = api.stream_url("https://example.org/base/", session, binary=True)
    assert url == "wss://example.org/base/sessions/ab12/stream?format=binary"
    assert "t0k3n" not in url
    assert api.stream_headers(session) == {"Authorization": "Bearer t0k3n"}


class CuttingProxy:
    """A TCP proxy to the service that, once told (``cut``), drops the connection instead of
    passing on the next bytes the service sends: the answer to a frame, lost after the service
    applied the frame."""

    def __init__(self, upstream: str):
        self.upstream = (urlsplit(upstream).hostname or "", urlsplit(upstream).port or 80)
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.url = f"http://127.0.0.1:{self.listener.getsockname()[1]}"
        self.cut = threading.Event()
        self.cuts = 0
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while True:
            try:
                near, _ = self.listener.accept()
            except OSError:  # closed
                return
            far = socket.create_connection(self.upstream)
            threading.Thread(target=self._pump, args=(near, far, False), daemon=True).start()
            threading.Thread(target=self._pump, args=(far, near, True), daemon=True).start()

    def _pump(self, src: socket.socket, dst: socket.socket, answers: bool) -> None:
        try:
            while data := src.recv(65536):
                if answers and self.cut.is_set():
                    self.cut.clear()
                    self.cuts += 1
                    return
                dst.sendall(data)
        except OSError:
            pass
        finally:
            for sock in (src, dst):
                with contextlib.suppress(OSError):
                    sock.shutdown(socket.SHUT_RDWR)
                sock.close()

    def close(self) -> None:
        self.listener.close()


def test_a_stream_sends_a_frame_whose_answer_was_lost_again_on_a_new_stream(
    server: Server,
) -> None:
    """The connection drops after the service applied a frame, before its answer arrived: the
    stream opens a new one and sends the frame again with its steps; the service answers it
    without applying it twice (sync and async)."""
    proxy = CuttingProxy(server.url)
    try:
        with AdvisorClient(proxy.url, retries=3, backoff=0.05) as client:
            session = client.create_session(window=20)
            with client.stream(session) as stream:
                first = stream.send([W, E] * 5)
                proxy.cut.set()
                again = stream.send([W, E] * 5)  # applied; its answer lost; sent again
                assert proxy.cuts == 1 and stream.reconnects == 1
                assert [d["step"] for d in again] == list(range(11, 21))
                assert stream.send(W)["step"] == 21
            assert client.session(session)["steps"] == 21  # each event applied once

        async def scenario() -> tuple[list[int], int, int]:
            async with AsyncAdvisorClient(proxy.url, retries=3, backoff=0.05) as client:
                session = await client.create_session(window=20)
                async with await client.stream(session) as stream:
                    await stream.send([W, E] * 5)
                    proxy.cut.set()
                    again = await stream.send([W, E] * 5)
                    reconnects = stream.reconnects
                steps = (await client.session(session))["steps"]
                return [d["step"] for d in again], reconnects, steps

        assert run_async(scenario()) == (list(range(11, 21)), 1, 20)
        assert proxy.cuts == 2
    finally:
        proxy.close()
    with AdvisorClient(server.url) as client:  # the decisions of a stream that lost nothing
        reference = client.create_session(window=20)
        with client.stream(reference) as stream:
            assert stream.send([W, E] * 5) == first
            assert stream.send([W, E] * 5) == again


def test_a_stream_the_service_closed_to_refuse_it_is_not_opened_again(server: Server) -> None:
    with AdvisorClient(server.url, retries=3, backoff=0.05) as client:
        session = client.create_session()
        with client.stream(session) as stream:
            assert stream.send(E)["step"] == 1
            client.end_session(session)
            with pytest.raises(AdvisorError) as err:
                stream.send(W)
            assert err.value.status == 404 and stream.reconnects == 0


def test_the_client_serves_a_building_of_floors(server: Server, tmp_path: Path) -> None:
    """A map file of two floors put as the project writes it; cells [floor, row, col], U and D
    in the advice, and the binary stream's wide frames equal the JSON stream's decisions."""
    from tests.service.test_strategies import TOWER

    path = tmp_path / "tower.txt"
    path.write_text(TOWER.to_text())
    stop = int(TOWER.rides[0, 0])
    walk = [{"state": list(TOWER.cell(stop)), "action": "U"}, {"state": list(TOWER.cell(
        int(TOWER.rides[0, 1]))), "action": "D"}] * 20  # fmt: skip
    with AdvisorClient(server.url, admin_key=server.admin_key) as client:
        made = client.put_domain_file("tower-file", path, experts={"per_goal": 1})
        assert made["actions"] == ["N", "E", "S", "W", "U", "D"] and len(made["floors"]) == 2
        start = list(TOWER.cell(stop))
        a = client.create_session("tower-file", kappa=0.0, start=start)
        b = client.create_session("tower-file", kappa=0.0, start=start)
        with client.stream(a) as text, client.stream(b, binary=True) as binary:
            want = text.send(walk)
            got = binary.send(walk)
            assert isinstance(got, DecisionFrame) and got.cell.shape == (40, 3)
            assert got.to_dicts() == want
        assert want[0]["state"] == list(TOWER.cell(int(TOWER.rides[0, 1])))  # rode up
        assert set(want[0]["advice"] or {}) == set("NESWUD")
        client.delete_domain("tower-file")
