"""Binary answers on the websocket (``?format=binary``, layout in
client/advisor_client/protocol.py): the same decisions as the JSON answers, the same session
afterwards, errors as JSON text frames."""

from __future__ import annotations

import json
import struct
from collections.abc import Iterator
from dataclasses import replace
from typing import Any

import numpy as np
import pytest
from advisor_client.protocol import HEADER, MAGIC, FrameError, pack, unpack
from fastapi.testclient import TestClient
from hypothesis import given, settings
from hypothesis import strategies as st
from starlette.websockets import WebSocketDisconnect

from app.domain.grid import ACTIONS
from app.domain.paths import expert_trajectory
from app.service.main import create_app
from app.service.state import ServiceState
from tests.service.conftest import make_settings, open_session
from tests.service.test_strategies import moves

E = {"state": [28, 0], "action": "E"}


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[TestClient, ServiceState]]:
    with TestClient(create_app(make_settings(tmp_path_factory.mktemp("data")))) as client:
        yield client, client.app.state.service  # type: ignore[attr-defined]


def streams(client: TestClient, body: dict[str, Any]) -> tuple[Any, Any, list[str]]:
    """Two sessions made alike, one streaming JSON answers and one binary ones."""
    urls, ids = [], []
    for fmt in ("json", "binary"):
        sid, _, created = open_session(client, **body)
        urls.append(f"/sessions/{sid}/stream?token={created['token']}&format={fmt}")
        ids.append(sid)
    return client.websocket_connect(urls[0]), client.websocket_connect(urls[1]), ids


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    strategy=st.sampled_from(["paper", "paper", "goal_aware", "random", "early"]),
    kappa=st.sampled_from([0.0, 0.5, 1.0]),
    window=st.sampled_from([1, 40, 300]),
    sizes=st.lists(st.sampled_from([0, 1, 1, 3, 9, 120, 700]), min_size=1, max_size=5),
    single=st.booleans(),
)
def test_binary_frames_carry_the_json_decisions_and_leave_the_same_session(
    live: Any, seed: int, strategy: str, kappa: float, window: int, sizes: list[int], single: bool
) -> None:
    client, service = live
    grid = service.catalog.get("default").domain
    rng = np.random.default_rng(seed)
    params = {"seed": 3} if strategy == "random" else {}
    body = {"kappa": kappa, "window": window, "strategy": strategy, "params": params}
    text_ws, binary_ws, ids = streams(client, body)
    s = grid.start
    with text_ws, binary_ws:
        for n in sizes:
            events = []
            walk = moves(grid, s, rng)[:n] if rng.random() < 0.5 else rng.integers(0, 4, n)
            for a in list(walk):
                events.append({"state": list(grid.cell(s)), "action": ACTIONS[a]})
                s = int(grid.next_state[s, a])
            frame = json.dumps(events[0] if single and len(events) == 1 else events)
            text_ws.send_text(frame)
            binary_ws.send_text(frame)
            want = json.loads(text_ws.receive_text())
            got = unpack(binary_ws.receive_bytes())
            assert got.to_dicts() == (want if isinstance(want, list) else [want])
    # the session's recent path, posterior history, advice log and figures are the same
    a, b = (service.registry.describe(service.registry.get(i)) for i in ids)
    assert replace(a, id="", created_at=b.created_at, idle_seconds=0.0) == replace(
        b, id="", idle_seconds=0.0
    )


def test_goal_aware_advice_of_its_own_goes_in_the_binary_frame(
    tmp_path_factory: pytest.TempPathFactory,
) -> None:
    # a service of its own: which cells' per-goal advice differs from the pooled theta
    # depends on the data, and other tests add some
    with TestClient(create_app(make_settings(tmp_path_factory.mktemp("goal")))) as client:
        grid = client.app.state.service.catalog.get("default").domain  # type: ignore[attr-defined]
        body = {"kappa": 0.0, "strategy": "goal_aware", "params": {"beta": 1.0}}
        path = expert_trajectory(grid, grid.start, grid.goals[-1], np.random.default_rng(5))
        events = [{"state": grid.cell(s), "action": ACTIONS[a]} for s, a in path.tolist()]
        text_ws, binary_ws, _ = streams(client, body)
        with text_ws, binary_ws:
            text_ws.send_text(json.dumps(events))
            binary_ws.send_text(json.dumps(events))
            want = json.loads(text_ws.receive_text())
            got = unpack(binary_ws.receive_bytes())
        assert got.to_dicts() == want
        theta = client.get("/domains/default/prior").json()["theta"]  # rows of cells
        pooled = np.array([theta[r][c] for r, c in got.cell.tolist()])
        assert (got.advise & (got.advice != pooled).any(axis=1)).any()


def test_binary_stream_errors_are_json_text_frames(live: Any) -> None:
    client, _ = live
    sid, _, created = open_session(client)
    url = f"/sessions/{sid}/stream?token={created['token']}&format=binary"
    with client.websocket_connect(url) as ws:
        ws.send_text('{"state": [27, 0], "action": "N"}')
        error = json.loads(ws.receive_text())
        assert error["status"] == 422 and "is a wall" in error["detail"]
        ws.send_text(json.dumps(E))
        one = unpack(ws.receive_bytes())
        assert one.step.tolist() == [1] and one.cell.tolist() == [[28, 1]]


def test_an_unknown_format_closes_the_stream_with_4422(live: Any) -> None:
    client, _ = live
    sid, _, created = open_session(client)
    url = f"/sessions/{sid}/stream?token={created['token']}&format=xml"
    with client.websocket_connect(url) as ws, pytest.raises(WebSocketDisconnect) as closed:
        ws.receive_text()
    assert closed.value.code == 4422 and "binary" in closed.value.reason


@given(
    n=st.integers(0, 40),
    seed=st.integers(0, 2**32 - 1),
    first=st.integers(0, 2**40),
    kappa=st.floats(0, 10),
    count0=st.integers(0, 10**6),
    benefit0=st.floats(0, 1e6),
)
def test_unpack_inverts_pack_and_adds_up_as_the_service_does(
    n: int, seed: int, first: int, kappa: float, count0: int, benefit0: float
) -> None:
    rng = np.random.default_rng(seed)
    advise = rng.random(n) < 0.5
    kl, p = rng.random(n) * 3, rng.random(n)
    advice = rng.dirichlet(np.ones(4), int(advise.sum()))
    cells = rng.integers(0, 2**31 - 1, (n, 2)).astype(np.int32)
    frame = unpack(pack(first, kappa, count0, benefit0, kl, p, advice, cells, advise))
    assert frame.step.tolist() == list(range(first, first + n))
    assert frame.cell.tolist() == cells.tolist() and frame.advise.tolist() == advise.tolist()
    assert frame.kl.tolist() == kl.tolist() and frame.p_normal.tolist() == p.tolist()
    assert frame.advice[advise].tolist() == advice.tolist()
    assert np.isnan(frame.advice[~advise]).all()
    # the running figures, added one decision at a time as the advisor does
    count, benefit = count0, benefit0
    for i in range(n):
        if advise[i]:
            count += 1
            benefit += float(kl[i])
        assert frame.advice_count[i] == count and frame.benefit[i] == benefit
        assert frame.total[i] == kappa * count


@pytest.mark.parametrize(
    ("frame", "says"),
    [
        (b"", "shorter than"),
        (b"HGA2" + bytes(HEADER.size - 4), "magic"),
        (HEADER.pack(MAGIC, 1, 0, 0, 0, 0.0, 0, 0.0), "bytes for 1 decisions"),
        (HEADER.pack(MAGIC, 1, 2, 0, 0, 0.0, 0, 0.0) + bytes(25 + 64), "bytes for 1 decisions"),
        (HEADER.pack(MAGIC, 1, 0, 0, 0, 0.0, 0, 0.0) + bytes(24) + b"\x01", "advising flags"),
        (struct.pack("<4s", MAGIC), "shorter than"),
    ],
)
def test_unpack_refuses_what_is_not_a_frame(frame: bytes, says: str) -> None:
    with pytest.raises(FrameError, match=says):
        unpack(frame)
