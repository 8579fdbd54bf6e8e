"""Redis failing, without Redis: every kind of failure is one exception (RedisDown) and says
what it is; the breaker opens for what means Redis is down (not for its quick refusals),
refuses at once while open, probes at once and then no more often than its pace, and closes
at the first probe answered, handing the answer on."""

from __future__ import annotations

import asyncio
from typing import Any

import hiredis
import pytest
import redis.exceptions as rx

from app.service.live.faults import Breaker, RedisDown, classify
from app.service.live.lanes import LaneError, LaneTimeout, LaneUnreachable
from tests.client.test_client import run_async

DOWN = [  # (exception, words its reason holds); each opens the breaker
    (LaneTimeout("Redis did not answer within 1 s"), "did not answer"),
    (LaneUnreachable("cannot connect to Redis: [Errno 111] Connection refused"), "refused"),
    (rx.TimeoutError("Timeout reading from socket"), "did not answer in time"),
    (rx.ConnectionError("Error 111 connecting to 127.0.0.1:1. Connection refused."), "refused"),
    (rx.BusyLoadingError("Redis is loading the dataset in memory"), "loading"),
    (rx.AuthenticationError("invalid username-password pair"), "password"),
    (hiredis.ReplyError("LOADING Redis is loading the dataset in memory"), "loading"),
    (hiredis.ReplyError("BUSY Redis is busy running a script."), "busy"),
    (hiredis.ReplyError("NOAUTH Authentication required."), "password"),
    (hiredis.ReplyError("WRONGPASS invalid username-password pair"), "password"),
    (hiredis.ProtocolError("Protocol error, got 'x'"), "not RESP"),
    (ConnectionRefusedError(111, "Connection refused"), "refused"),
    (TimeoutError(), "did not answer"),
]
QUICK = [  # Redis answered at once, refusing: 503, the breaker stays closed
    (hiredis.ReplyError("OOM command not allowed when used memory > 'maxmemory'."), "memory"),
    (rx.OutOfMemoryError("command not allowed when used memory > 'maxmemory'."), "memory"),
    (hiredis.ReplyError("MISCONF Redis is configured to save RDB snapshots"), "cannot save"),
    (rx.ReadOnlyError("You can't write against a read only replica."), "read-only"),
    (LaneError("Redis closed the connection"), "closed"),
]
NOT_REDIS = [
    hiredis.ReplyError("ERR user_script:1: Script attempted to access nonexistent global"),
    rx.ResponseError("ERR unknown command"),
    rx.NoScriptError("No matching script. Please use EVAL."),
    ValueError("a bug"),
    KeyError("x"),
]


@pytest.mark.parametrize(("exc", "words"), DOWN + QUICK)
def test_every_redis_failure_is_named(exc: BaseException, words: str) -> None:
    got = classify(exc)
    assert got is not None and words.lower() in got[0].lower(), got
    assert got[1] is any(exc is e for e, _ in DOWN)


@pytest.mark.parametrize("exc", NOT_REDIS)
def test_what_is_not_redis_failing_is_left_as_it_is(exc: BaseException) -> None:
    assert classify(exc) is None


def test_the_breaker_refuses_at_once_while_open_and_closes_at_the_first_probe_answered() -> None:
    async def run() -> dict[str, Any]:
        answers: list[object] = [rx.TimeoutError("Timeout"), ConnectionRefusedError(), b"gen"]
        handed: list[object] = []
        probed = asyncio.Event()

        async def probe() -> object:
            probed.set()
            answer = answers.pop(0)
            if isinstance(answer, BaseException):
                raise answer
            return answer

        async def on_up(answer: object) -> None:
            handed.append(answer)

        breaker = Breaker(probe, on_up, every=0.01)
        breaker.check()  # closed: nothing happens
        assert breaker.failed(ValueError("a bug")) is None and breaker.up
        quick = breaker.failed(hiredis.ReplyError("OOM command not allowed"))
        assert isinstance(quick, RedisDown) and breaker.up  # Redis answered: not down
        down = breaker.failed(LaneTimeout("Redis did not answer within 0.3 s"))
        assert isinstance(down, RedisDown) and not breaker.up
        refused = 0
        for _ in range(100):  # while open, every call is refused without reaching Redis
            with pytest.raises(RedisDown):
                breaker.check()
            refused += 1
        await asyncio.wait_for(probed.wait(), 5)
        for _ in range(500):
            if breaker.up:
                break
            await asyncio.sleep(0.01)
        return {"up": breaker.up, "handed": handed, "refused": breaker.refused,
                "probes": breaker.probes, "opened": breaker.opened, "counted": refused}  # fmt: skip

    got = run_async(run())
    assert got["up"] and got["handed"] == [b"gen"]
    assert got["refused"] == got["counted"] == 100
    assert got["probes"] == 3 and got["opened"] == 1


def test_one_probe_at_a_time_however_many_failures_come() -> None:
    async def run() -> tuple[int, int]:
        gate = asyncio.Event()
        running = 0
        most = 0

        async def probe() -> object:
            nonlocal running, most
            running += 1
            most = max(most, running)
            await gate.wait()
            running -= 1
            return b"gen"

        breaker = Breaker(probe, every=0.01)
        for _ in range(200):  # 200 calls failing at once (explorers whose Redis paused)
            breaker.failed(LaneTimeout("no answer"))
            await asyncio.sleep(0)
        gate.set()
        for _ in range(500):
            if breaker.up:
                break
            await asyncio.sleep(0.01)
        await breaker.close()
        return most, breaker.opened

    most, opened = run_async(run())
    assert most == 1 and opened == 1
