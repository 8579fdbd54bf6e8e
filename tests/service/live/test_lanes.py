"""A lane to Redis against a server of the test's own: answers matched to calls in order, a
call with no answer fails (LaneError) once it waited the timeout, and the next call connects
again."""

from __future__ import annotations

import asyncio

import pytest

from app.service.live.lanes import Lane, LaneError
from tests.client.test_client import run_async  # off the browser tests' loop


async def _server(answer: bool) -> tuple[asyncio.Server, int, list[bytes]]:
    """A server speaking just enough RESP: each command read is answered ``+OK`` (or never)."""
    seen: list[bytes] = []

    async def handle(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            while data := await reader.read(1 << 16):
                seen.append(data)
                if answer:
                    for _ in range(data.count(b"*")):  # one array header a command
                        writer.write(b"+OK\r\n")
                    await writer.drain()
        finally:
            writer.close()

    server = await asyncio.start_server(handle, "127.0.0.1", 0)
    return server, server.sockets[0].getsockname()[1], seen


def test_a_lane_answers_calls_in_order() -> None:
    async def run() -> list[object]:
        server, port, _ = await _server(answer=True)
        async with server:
            lane = Lane(f"redis://127.0.0.1:{port}/0", timeout=5.0)
            got = await asyncio.gather(*(lane.call("PING") for _ in range(20)))
            await lane.close()
            return list(got)

    assert run_async(run()) == [b"OK"] * 20


def test_a_call_without_an_answer_fails_after_the_timeout_and_the_next_connects_again() -> None:
    async def run() -> None:
        silent, port, seen = await _server(answer=False)
        async with silent:
            lane = Lane(f"redis://127.0.0.1:{port}/0", timeout=0.2)
            with pytest.raises(LaneError, match=r"did not answer within 0\.2 s"):
                await lane.call("PING")
            assert seen  # it was sent; no answer came
            assert not lane.connected and not lane._waiting  # dropped, nothing left waiting
        talking, port2, _ = await _server(answer=True)
        async with talking:
            lane.options["port"] = port2  # the same lane, its server back
            assert await lane.call("PING") == b"OK"
            await lane.close()

    run_async(run())


@pytest.mark.parametrize("reply", [b"", b"?not RESP\r\n"])
def test_a_closed_connection_or_a_garbled_answer_fails_the_calls_at_once(reply: bytes) -> None:
    """A server that closes the connection (or answers what is not RESP) fails every call in
    flight with LaneError then and there, not at the timeout, and drops the connection."""

    async def run() -> None:
        async def handle(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            await reader.read(1 << 16)
            writer.write(reply)
            await writer.drain()
            if not reply:
                writer.close()
            else:
                await reader.read(1 << 16)  # left open: the lane is the one to drop it

        server = await asyncio.start_server(handle, "127.0.0.1", 0)
        async with server:
            port = server.sockets[0].getsockname()[1]
            lane = Lane(f"redis://127.0.0.1:{port}/0", timeout=30.0)
            calls = [asyncio.ensure_future(lane.call("PING")) for _ in range(3)]
            done, _ = await asyncio.wait(calls, timeout=5.0)
            assert len(done) == 3  # long before the 30 s timeout
            for call in calls:
                with pytest.raises(LaneError):
                    call.result()
            assert not lane.connected and not lane._waiting
            await lane.close()

    run_async(run())
