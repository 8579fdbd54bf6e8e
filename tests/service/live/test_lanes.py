"""A lane to Redis against a server of the test's own: answers matched to calls in order, a
call with no answer fails (LaneError) once it waited the timeout, and the next call connects
again."""

from __future__ import annotations

import asyncio

import pytest

from app.service.live.lanes import Lane, LaneError, LaneTimeout, LaneUnreachable
from tests.client.test_client import run_async  # off the browser tests' loop


async def _server(answer: bool) -> tuple[asyncio.Server, int, list[bytes]]:
    """A server speaking just enough RESP: each command read is answered with its number
    (``:1``, ``:2``, ... counted over every connection), or never."""
    seen: list[bytes] = []
    count = 0

    async def handle(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        nonlocal count
        try:
            while data := await reader.read(1 << 16):
                seen.append(data)
                if answer:
                    for _ in range(data.count(b"*")):  # one array header a command
                        count += 1
                        writer.write(b":%d\r\n" % count)
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

    assert run_async(run()) == list(range(1, 21))


def test_the_calls_of_one_step_of_the_loop_go_out_in_one_write_and_are_answered_in_order() -> None:
    """Calls made in the same step of the event loop are packed and written together (one
    write, so that Redis reads them at once); each gets its own answer, in the order made. A
    connection dropped before the write fails what it had packed, and the next call connects
    again."""

    async def run() -> None:
        server, port, _ = await _server(answer=True)
        async with server:
            lane = Lane(f"redis://127.0.0.1:{port}/0", timeout=5.0)
            assert await lane.call("PING") == 1  # connected
            wire = lane._wire
            assert wire is not None and wire.transport is not None
            writes: list[bytes] = []
            write = wire.transport.write

            def counted(data: bytes | bytearray | memoryview) -> None:
                writes.append(bytes(data))
                write(data)

            wire.transport.write = counted  # type: ignore[method-assign]
            got = await asyncio.gather(*(lane.call("PING") for _ in range(20)))
            assert got == list(range(2, 22)) and len(writes) == 1
            packed = [asyncio.ensure_future(lane.call("PING")) for _ in range(3)]
            await asyncio.sleep(0)  # the calls packed, not yet written
            lane._lost(LaneError("dropped"))
            for call in packed:
                with pytest.raises(LaneError, match="dropped"):
                    await call
            assert len(writes) == 1  # nothing went out on the dropped connection
            assert await lane.call("PING") == 22  # a new connection, the same server
            await lane.close()

    run_async(run())


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
            assert await lane.call("PING") == 1
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


def test_a_connection_refused_is_lane_unreachable_and_the_next_call_tries_again() -> None:
    async def run() -> None:
        from tests.client.conftest import free_port

        port = free_port()  # nothing listens there
        lane = Lane(f"redis://127.0.0.1:{port}/0", timeout=5.0)
        with pytest.raises(LaneUnreachable, match="cannot connect to Redis"):
            await lane.call("PING")
        server, port2, _ = await _server(answer=True)
        async with server:
            lane.options["port"] = port2
            assert await lane.call("PING") == 1
            await lane.close()

    run_async(run())


def test_a_call_to_a_server_that_stopped_reading_fails_at_the_timeout_not_at_its_return() -> None:
    """A Redis paused (SIGSTOP) reads nothing: a call larger than what the connection buffers
    waits for the buffer to drain, and still fails at the timeout (the connection aborted,
    what it held dropped), never waiting for the server to read again."""

    async def run() -> None:
        stalled = asyncio.Event()

        async def handle(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            await stalled.wait()  # reads nothing until the test ends
            writer.close()

        server = await asyncio.start_server(handle, "127.0.0.1", 0)
        async with server:
            port = server.sockets[0].getsockname()[1]
            lane = Lane(f"redis://127.0.0.1:{port}/0", timeout=0.2)
            big = b"x" * (8 << 20)  # beyond the socket buffers and the lane's 1 MiB mark
            with pytest.raises(LaneTimeout):
                await asyncio.wait_for(lane.call("SET", "k", big), 30)
            assert not lane.connected and not lane._waiting
            stalled.set()
            await lane.close()

    run_async(run())


def test_rediss_options_make_the_tls_context() -> None:
    """``rediss://`` URLs: the CA file, the certificate checks and a client certificate come
    from the query string, as redis-py reads them (the lanes and redis-py's pool agree)."""
    import ssl

    from app.service.live.lanes import tls_context

    plain = Lane("rediss://:pw@redis.example:6380/1")
    assert plain.tls and plain._tls_context is not None
    assert plain._tls_context.verify_mode == ssl.CERT_REQUIRED
    assert plain._tls_context.check_hostname
    assert plain.options["password"] == "pw" and plain.options["port"] == 6380
    loose = tls_context({"ssl_cert_reqs": "none"})
    assert loose.verify_mode == ssl.CERT_NONE and not loose.check_hostname
    named = tls_context({"ssl_check_hostname": "false"})
    assert not named.check_hostname and named.verify_mode == ssl.CERT_REQUIRED
    assert Lane("redis://127.0.0.1:6379/0")._tls_context is None
