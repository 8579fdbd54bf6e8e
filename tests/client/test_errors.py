"""Connection failures raise AdvisorError (AdvisorUnreachable) with the URL and a hint; calls
are tried again with a backoff when that is safe (no server needed: httpx's MockTransport)."""

from __future__ import annotations

import socket
import time

import httpx
import pytest
from advisor_client import AdvisorClient, AdvisorError, AdvisorUnreachable, AsyncAdvisorClient, api
from advisor_client.api import Session
from advisor_client.gym import NoCell, cell_of_observation

from tests.client.test_client import run_async

SESSION = Session("ab12", "tok", "default", 0.5, 300, {})  # type: ignore[typeddict-item]


def closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
    return port  # nothing listens there once the socket is closed


def test_a_refused_connection_is_an_advisor_error_with_the_url_and_a_hint() -> None:
    url = f"http://127.0.0.1:{closed_port()}"
    with AdvisorClient(url, retries=1, backoff=0.0) as client, pytest.raises(AdvisorError) as err:
        client.health()
    assert isinstance(err.value, AdvisorUnreachable) and err.value.status == 0
    assert err.value.url == url + "/health"
    assert f"cannot reach the advisor at {url}/health (2 attempts)" in err.value.detail
    assert "advisor serve" in err.value.detail


def test_a_refused_websocket_is_an_advisor_error_too() -> None:
    url = f"http://127.0.0.1:{closed_port()}"
    with AdvisorClient(url, retries=0) as client, pytest.raises(AdvisorUnreachable) as err:
        client.stream(SESSION)
    assert f"ws://127.0.0.1:{url.rsplit(':', 1)[1]}/sessions/ab12/stream" in err.value.detail


class Script:
    """A transport answering from a script: an int is a status, an exception is raised."""

    def __init__(self, *steps: int | Exception):
        self.steps = list(steps)
        self.calls: list[str] = []
        self.bodies: list[bytes] = []

    def __call__(self, request: httpx.Request) -> httpx.Response:
        self.calls.append(request.method)
        self.bodies.append(request.content)
        step = self.steps.pop(0)
        if isinstance(step, Exception):
            raise step
        body = {"detail": "busy"} if step >= 400 else {"status": "ok", "step": 1}
        return httpx.Response(step, json=body)


def client_for(script: Script, retries: int = 3) -> AdvisorClient:
    transport = httpx.MockTransport(script)
    return AdvisorClient("http://advisor.test", transport=transport, retries=retries, backoff=0)


def test_idempotent_calls_are_retried_after_503_and_lost_answers() -> None:
    script = Script(503, httpx.ReadTimeout("slow"), 200)
    with client_for(script) as client:
        assert client.health()["status"] == "ok"
    assert script.calls == ["GET"] * 3


def test_retries_stop_after_the_last_one_with_the_services_answer() -> None:
    script = Script(503, 503, 503)
    with client_for(script, retries=2) as client, pytest.raises(AdvisorError) as err:
        client.health()
    assert err.value.status == 503 and len(script.calls) == 3


def test_a_post_is_sent_again_only_when_nothing_was_sent() -> None:
    refused = Script(httpx.ConnectError("refused"), 201)
    with client_for(refused) as client:
        client.call(api.create_session("default"))
    assert refused.calls == ["POST", "POST"]
    lost = Script(httpx.ReadTimeout("slow"), 201)  # creating it may have happened: not again
    with client_for(lost) as client, pytest.raises(AdvisorUnreachable):
        client.call(api.create_session("default"))
    assert lost.calls == ["POST"]


def test_events_are_sent_again_with_their_steps_after_a_lost_answer() -> None:
    """Events carry their steps: the service answers a step it applied again instead of
    applying it twice, so an event call is sent again after any failure to get an answer,
    the same text each time; the session then counts the steps answered."""
    session = Session("ab12", "tok", "default", 0.5, 300, {})  # type: ignore[typeddict-item]
    lost = Script(httpx.ReadTimeout("slow"), 503, 200)
    with client_for(lost) as client:
        client.events(session, {"state": [28, 0], "action": "E"})
    assert lost.calls == ["POST"] * 3
    assert lost.bodies[0] == lost.bodies[1] == lost.bodies[2]
    assert b'"step":1' in lost.bodies[0].replace(b" ", b"") and session.steps == 1
    explicit = Script(200)
    with client_for(explicit) as client:
        client.events(session, [{"state": [28, 0], "action": "E", "step": 1}])
    assert b'"step":1' in explicit.bodies[0].replace(b" ", b"")  # a step given is kept


def test_retries_wait_the_backoff_doubling_up_to_4_s(monkeypatch: pytest.MonkeyPatch) -> None:
    waits: list[float] = []
    monkeypatch.setattr(time, "sleep", waits.append)  # tenacity sleeps with time.sleep
    script = Script(503, 503, 503, 503, 503, 200)
    transport = httpx.MockTransport(script)
    with AdvisorClient(
        "http://advisor.test", transport=transport, retries=5, backoff=1.0
    ) as client:
        assert client.health()["status"] == "ok"
    assert waits == [1.0, 2.0, 4.0, 4.0, 4.0] and len(script.calls) == 6
    assert [client._delay(n) for n in range(5)] == waits  # the streams' waits too


def test_a_refusal_is_not_retried_and_an_error_of_another_kind_goes_through() -> None:
    refused = Script(404)
    with client_for(refused) as client, pytest.raises(AdvisorError) as err:
        client.health()
    assert err.value.status == 404 and refused.calls == ["GET"]
    broken = Script(ValueError("not a transport error"))
    with client_for(broken) as client, pytest.raises(ValueError):
        client.health()
    assert broken.calls == ["GET"]


def test_the_async_client_retries_alike() -> None:
    script = Script(httpx.ConnectError("refused"), 502, 200)

    async def scenario() -> str:
        transport = httpx.MockTransport(script)
        async with AsyncAdvisorClient(
            "http://advisor.test", transport=transport, backoff=0
        ) as client:
            return (await client.health())["status"]

    assert run_async(scenario()) == "ok" and script.calls == ["GET"] * 3


def test_advised_env_says_what_it_needs_when_the_observation_names_no_cell() -> None:
    assert cell_of_observation({"cell": (3, 4), "image": None}) == (3, 4)
    assert cell_of_observation([5, 6]) == (5, 6)
    with pytest.raises(NoCell, match=r"observation \(a dict with keys \['direction', 'image'"):
        cell_of_observation({"image": 0, "direction": 1})
    with pytest.raises(NoCell, match="cell_of="):
        cell_of_observation(7)
