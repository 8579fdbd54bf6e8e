"""Fixtures: an app on a temporary data dir (SQLite), its TestClient, the admin key."""

from __future__ import annotations

import os
import secrets
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import sqlalchemy as sa
from fastapi.testclient import TestClient

from app.service.config import Settings
from app.service.main import create_app
from app.service.state import ServiceState

#: A small maze: start lower-left, two goals, one loop, a dead end.
TINY = [
    "#######",
    "#G..#G#",
    "#.#.#.#",
    "#...#.#",
    "###...#",
    "#S....#",
    "#######",
]


def make_settings(data_dir: Path, **overrides: Any) -> Settings:
    values: dict[str, Any] = {
        "data_dir": data_dir,
        "viewer_enabled": False,
        "bootstrap_per_goal": 2,
        "static_dir": data_dir / "no-static",
        "overview_seconds": 0.0,  # every read sees the events before it
    }
    return Settings(**(values | overrides))


@pytest.fixture
def settings(tmp_path: Path) -> Settings:
    return make_settings(tmp_path / "data")


@pytest.fixture
def client(settings: Settings) -> Iterator[TestClient]:
    with TestClient(create_app(settings)) as c:
        yield c


@pytest.fixture
def service(client: TestClient) -> ServiceState:
    state: ServiceState = client.app.state.service  # type: ignore[attr-defined]
    return state


@pytest.fixture
def admin(service: ServiceState) -> dict[str, str]:
    return {"X-API-Key": service.admin_key}


def open_session(
    client: TestClient, domain: str = "default", **body: Any
) -> tuple[str, dict[str, str], dict[str, Any]]:
    """(session id, auth headers, creation answer)."""
    r = client.post(f"/domains/{domain}/sessions", json=body)
    assert r.status_code == 201, r.text
    created = r.json()
    return created["session_id"], {"Authorization": f"Bearer {created['token']}"}, created


def put_tiny(client: TestClient, admin: dict[str, str], name: str = "tiny") -> dict[str, Any]:
    r = client.put(f"/domains/{name}", json={"map": TINY}, headers=admin)
    assert r.status_code in (200, 201), r.text
    body: dict[str, Any] = r.json()
    return body


PG_URL = os.environ.get(
    "ADVISOR_TEST_POSTGRES", "postgresql+psycopg://postgres@127.0.0.1:5432/test"
)


def _postgres_problem() -> str | None:
    try:
        engine = sa.create_engine(PG_URL, connect_args={"connect_timeout": 3})
        with engine.connect() as conn:
            conn.execute(sa.text("SELECT 1"))
        engine.dispose()
    except Exception as exc:  # any failure to connect means: skip, saying why
        return f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
    return None


@pytest.fixture(params=["sqlite", "postgresql"])
def db_url(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[str]:
    """A database URL of each kind: a SQLite file, or a fresh PostgreSQL schema (dropped
    afterwards, with everything in it)."""
    if request.param == "sqlite":
        yield f"sqlite:///{tmp_path / 'advisor.db'}"
        return
    problem = _postgres_problem()
    if problem:
        pytest.skip(f"PostgreSQL not reachable at {PG_URL}: {problem}")
    schema = f"advisor_test_{secrets.token_hex(6)}"
    engine = sa.create_engine(PG_URL)
    with engine.begin() as conn:
        conn.execute(sa.text(f'CREATE SCHEMA "{schema}"'))
    try:
        yield f"{PG_URL}?options=-csearch_path%3D{schema}"
    finally:
        with engine.begin() as conn:
            conn.execute(sa.text(f'DROP SCHEMA "{schema}" CASCADE'))
        engine.dispose()


REDIS_URL = os.environ.get("ADVISOR_TEST_REDIS", "redis://127.0.0.1:6379/0")


def redis_problem() -> str | None:
    """Why Redis cannot be used for the tests (None: it answers)."""
    import redis

    try:
        redis.Redis.from_url(REDIS_URL, socket_connect_timeout=3).ping()
    except Exception as exc:  # any failure to connect means: skip, saying why
        return f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
    return None


def redis_prefix() -> str:
    """A prefix of Redis keys of one test's own, its keys deleted when it ends."""
    return f"t{secrets.token_hex(6)}"


def drop_redis_keys(prefix: str) -> None:
    import redis

    r = redis.Redis.from_url(REDIS_URL)
    keys = list(r.scan_iter(f"{prefix}:*", count=1000))
    if keys:
        r.delete(*keys)
    r.close()
