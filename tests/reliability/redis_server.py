"""A Redis of a test's own: ``redis-server`` on a free loopback port in a temporary directory,
which the test pauses (SIGSTOP), kills, restarts (with its data or without) and fills. Never
the machine's shared Redis."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import time
from pathlib import Path

import pytest
import redis

from tests.client.conftest import free_port

REDIS_SERVER = shutil.which("redis-server")
needs_redis_server = pytest.mark.skipif(
    REDIS_SERVER is None, reason="redis-server is not installed (apt-get install redis-server)"
)


class RedisServer:
    """``redis-server`` on 127.0.0.1:``port`` with its files in ``home``. ``aof``: every write
    in an append-only file, fsynced before Redis answers (so what it acknowledged survives a
    SIGKILL); ``args``: more of its options (``--requirepass x``, ``--maxmemory 2mb``)."""

    def __init__(self, home: Path, *args: str, aof: bool = False, tls: bool = False):
        self.home = home
        self.args = list(args)
        self.aof = aof
        self.tls = tls
        self.port = free_port()
        self.process: subprocess.Popen[bytes] | None = None
        home.mkdir(parents=True, exist_ok=True)

    @property
    def url(self) -> str:
        return f"{'rediss' if self.tls else 'redis'}://127.0.0.1:{self.port}/0"

    def command(self) -> list[str]:
        assert REDIS_SERVER is not None
        port = (
            ["--port", "0", "--tls-port", str(self.port)]
            if self.tls
            else ["--port", str(self.port)]
        )
        persistence = ["--appendonly", "yes", "--appendfsync", "always"] if self.aof else [
            "--appendonly", "no",
        ]  # fmt: skip
        return [REDIS_SERVER, *port, "--bind", "127.0.0.1", "--save", "", "--dir", str(self.home),
                "--daemonize", "no", *persistence, *self.args]  # fmt: skip

    def start(self, empty: bool = False) -> RedisServer:
        """Start it (``empty``: its files deleted first: Redis comes back without its data),
        and wait until it answers."""
        if empty:
            for f in self.home.iterdir():
                if f.is_dir():
                    shutil.rmtree(f)
                elif f.suffix != ".log" and f.suffix != ".pem":
                    f.unlink()
        log = (self.home / "redis.log").open("ab")
        self.process = subprocess.Popen(self.command(), stdout=log, stderr=log)
        log.close()
        deadline = time.monotonic() + 30
        while True:
            if self.process.poll() is not None:
                raise RuntimeError(f"redis-server exited: {(self.home / 'redis.log').read_text()}")
            if self.answers():
                return self
            if time.monotonic() > deadline:
                raise RuntimeError("redis-server did not answer within 30 s")
            time.sleep(0.02)

    def answers(self) -> bool:
        if self.tls:  # the test checks it through the service
            return _listening(self.port)
        try:
            return bool(self.client(timeout=1).ping())
        except (redis.exceptions.AuthenticationError, redis.exceptions.ResponseError):
            return True  # it answers: it asks for a password
        except (redis.exceptions.RedisError, OSError):
            return False

    def client(self, timeout: float = 5.0, **kw: object) -> redis.Redis:
        return redis.Redis(
            host="127.0.0.1", port=self.port, socket_timeout=timeout, **kw,  # type: ignore[arg-type]
        )  # fmt: skip

    def pause(self) -> None:
        assert self.process is not None
        os.kill(self.process.pid, signal.SIGSTOP)

    def resume(self) -> None:
        assert self.process is not None
        os.kill(self.process.pid, signal.SIGCONT)

    def kill(self) -> None:
        """SIGKILL: no shutdown, nothing saved but what the append-only file holds."""
        assert self.process is not None
        self.process.kill()
        self.process.wait(30)

    def stop(self) -> None:
        if self.process is not None and self.process.poll() is None:
            self.process.kill()  # also when paused
            self.process.wait(30)


def _listening(port: int) -> bool:
    import socket

    try:
        with socket.create_connection(("127.0.0.1", port), timeout=1.0):
            return True
    except OSError:
        return False
