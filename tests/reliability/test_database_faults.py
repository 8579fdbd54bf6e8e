"""PostgreSQL failing under the service, through a TCP proxy the test controls (the machine's
PostgreSQL is shared: it is never stopped): paused (every byte held, connections open: a
database that stopped answering) and dropped (connections reset, new ones refused). Ingestion
and a domain's PUT meanwhile answer 503 with Retry-After and a body naming the database,
within ``ADVISOR_DATABASE_TIMEOUT`` (1 s here) and the connection time limit, never a 500 or a
logged traceback; readiness is 503 naming the database and liveness stays 200; once it
answers again, everything acknowledged is stored, nothing else, and counts = recount."""

from __future__ import annotations

import logging
import secrets
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import sqlalchemy as sa
from fastapi.testclient import TestClient
from sqlalchemy.engine import make_url

from app.service.data.store import Store
from app.service.main import create_app
from tests.reliability.tcp_proxy import Proxy
from tests.service.conftest import PG_URL, TINY, _postgres_problem, make_settings

PROBLEM = _postgres_problem()
pytestmark = pytest.mark.skipif(
    PROBLEM is not None, reason=f"PostgreSQL not reachable at {PG_URL}: {PROBLEM}"
)
STEPS = {"trajectories": [{"steps": [{"state": [28, c], "action": "E"} for c in range(4)]}]}


@pytest.fixture
def proxied() -> Iterator[tuple[str, str, Proxy]]:
    """(the database's URL through the proxy, its URL straight, the proxy): a schema of the
    test's own, dropped afterwards."""
    schema = f"advisor_test_{secrets.token_hex(6)}"
    engine = sa.create_engine(PG_URL)
    with engine.begin() as conn:
        conn.execute(sa.text(f'CREATE SCHEMA "{schema}"'))
    base = make_url(PG_URL)
    proxy = Proxy((base.host or "127.0.0.1", base.port or 5432))
    options = f"?options=-csearch_path%3D{schema}"
    through = base.set(host="127.0.0.1", port=proxy.port).render_as_string(hide_password=False)
    try:
        yield through + options, PG_URL + options, proxy
    finally:
        proxy.close()
        with engine.begin() as conn:
            conn.execute(sa.text(f'DROP SCHEMA "{schema}" CASCADE'))
        engine.dispose()


def assert_database_503(r: Any) -> None:
    assert r.status_code == 503, r.text
    assert r.headers["retry-after"] == "2"
    assert "database" in r.json()["detail"], r.text


def test_postgresql_stopping_or_going_away_during_put_and_ingestion_is_503_and_loses_nothing(
    tmp_path: Path, proxied: tuple[str, str, Proxy], caplog: pytest.LogCaptureFixture
) -> None:
    through, direct, proxy = proxied
    settings = make_settings(tmp_path / "data", database_url=through, database_timeout=1.0)
    acked = 0
    with TestClient(create_app(settings)) as c, caplog.at_level(logging.WARNING):
        admin = {"X-API-Key": c.app.state.service.admin_key}  # type: ignore[attr-defined]
        before = c.get("/domains/default").json()["trajectories"]

        def ingest() -> Any:
            return c.post("/domains/default/trajectories", json=STEPS, headers=admin)

        for _ in range(3):
            assert ingest().status_code == 201
            acked += 1
        for how in ("paused", "dropped"):
            if how == "paused":
                proxy.pause()
            else:
                proxy.drop()
            try:
                assert_database_503(ingest())
                assert_database_503(c.put("/domains/hall", json={"map": TINY}, headers=admin))
                r = c.get("/health/ready")
                assert r.status_code == 503 and r.headers["retry-after"], r.text
                deps = r.json()["dependencies"]
                assert deps["database"]["state"] == "down" and "database" in r.json()["detail"]
                assert c.get("/health/live").status_code == 200
            finally:
                if how == "paused":
                    proxy.resume()
                else:
                    proxy.allow()
            deadline = time.monotonic() + 60
            while c.get("/health/ready").status_code != 200:
                assert time.monotonic() < deadline, f"the database {how}: never ready again"
                time.sleep(0.1)
            r = ingest()
            assert r.status_code == 201, r.text
            acked += 1
        assert c.get("/domains/hall").status_code == 404  # its PUT was never acknowledged
        assert c.get("/domains/default").json()["trajectories"] == before + acked
    logged = [r for r in caplog.records if r.levelno >= logging.ERROR or r.exc_info]
    assert logged == [], [r.getMessage() for r in logged]
    store = Store(direct)
    try:
        grid_states = len(store.counts("default")["*"].counts)
        assert len(store.trajectories("default")) == before + acked  # every one acknowledged
        recount = store.recount("default", grid_states)
        for table, counts in store.counts("default").items():
            assert counts.n_trajectories == recount[table].n_trajectories
            assert (counts.counts == recount[table].counts).all()
    finally:
        store.close()
