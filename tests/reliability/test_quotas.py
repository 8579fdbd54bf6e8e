"""One client cannot take every slot (the issue: sessions cost about 6 ms to create, and one
anonymous client could hold all 20,000 for the 30-minute idle timeout), and stored counts
cannot wrap round (they are int32: the issue found no overflow check).

Over the real server: a client is its address (127.0.0.1 and 127.0.0.2 are two clients on
this machine's loopback), or the key it sends; behind a proxy the operator trusts, the
forwarded address; X-Forwarded-For from anyone else is not believed."""

from __future__ import annotations

from pathlib import Path

import httpx
import pytest
import sqlalchemy as sa
from fastapi.testclient import TestClient

from app.service.data.store import COUNT_MAX
from app.service.main import create_app
from tests.reliability.conftest import server_errors, start, stop
from tests.service.conftest import TINY, make_settings

QUOTA = 5


def client(url: str, address: str = "127.0.0.1") -> httpx.Client:
    """A client whose connections come from ``address`` (a loopback address)."""
    transport = httpx.HTTPTransport(local_address=address)
    return httpx.Client(base_url=url, timeout=30, transport=transport)


def test_one_client_gets_429_at_its_quota_and_others_are_served(tmp_path: Path) -> None:
    live = start(tmp_path / "data", ADVISOR_CLIENT_MAX_SESSIONS=str(QUOTA))
    try:
        with client(live.url) as one, client(live.url, "127.0.0.2") as two:
            made = [one.post("/domains/default/sessions", json={}) for _ in range(QUOTA)]
            assert [r.status_code for r in made] == [201] * QUOTA
            refused = one.post("/domains/default/sessions", json={})
            assert refused.status_code == 429, refused.text
            detail = refused.json()["detail"]
            assert "address 127.0.0.1" in detail and f"{QUOTA} live sessions" in detail
            assert "ADVISOR_CLIENT_MAX_SESSIONS" in detail
            # a forwarded address from a proxy nobody trusts changes nothing
            spoofed = one.post("/domains/default/sessions", json={},
                               headers={"X-Forwarded-For": "10.9.8.7"})  # fmt: skip
            assert spoofed.status_code == 429
            # another client is served; the admin's sessions count against no client's quota
            assert two.post("/domains/default/sessions", json={}).status_code == 201
            assert one.post("/domains/default/sessions", json={},
                            headers=live.admin).status_code == 201  # fmt: skip
            # the quota's sessions still answer, and ending one frees a place
            first = made[0].json()
            auth = {"Authorization": f"Bearer {first['token']}"}
            e = {"state": first["decision"]["state"], "action": "E"}
            assert one.post(f"/sessions/{first['session_id']}/events", json=e,
                            headers=auth).status_code == 200  # fmt: skip
            assert one.delete(f"/sessions/{first['session_id']}", headers=auth).status_code == 200
            assert one.post("/domains/default/sessions", json={}).status_code == 201
    finally:
        stop(live)
    assert server_errors(live) == []


def test_a_client_s_session_memory_is_bounded_too(tmp_path: Path) -> None:
    live = start(tmp_path / "data", ADVISOR_CLIENT_MAX_SESSION_MEMORY=str(1024 * 1024))
    try:
        with client(live.url) as one:
            codes = [
                one.post("/domains/default/sessions", json={"window": 10_000}).status_code
                for _ in range(6)
            ]
            r = one.post("/domains/default/sessions", json={"window": 10_000})
    finally:
        stop(live)
    assert codes[:4] == [201] * 4 and 429 in codes  # 226 kB reserved each: 4 in 1 MiB
    assert r.status_code == 429 and "ADVISOR_CLIENT_MAX_SESSION_MEMORY" in r.json()["detail"]


def test_behind_a_trusted_proxy_the_forwarded_address_is_the_client(tmp_path: Path) -> None:
    live = start(tmp_path / "data", ADVISOR_CLIENT_MAX_SESSIONS="2",
                 ADVISOR_TRUSTED_PROXIES='["127.0.0.1"]')  # fmt: skip
    try:
        with client(live.url) as proxy, client(live.url, "127.0.0.2") as direct:

            def create(forwarded: str | None) -> int:
                headers = {} if forwarded is None else {"X-Forwarded-For": forwarded}
                r = proxy.post("/domains/default/sessions", json={}, headers=headers)
                return r.status_code

            assert [create("10.0.0.7") for _ in range(3)] == [201, 201, 429]
            assert create("10.0.0.8") == 201  # another client behind the proxy
            # what a client writes left of the proxy's entry is not believed: the proxy
            # appends the address it saw (10.0.0.7), which is the one counted
            assert create("1.2.3.4, 10.0.0.7") == 429
            # from an untrusted peer the header is ignored: the peer is the client
            codes = [direct.post("/domains/default/sessions", json={},
                                 headers={"X-Forwarded-For": f"10.1.0.{i}"}).status_code
                     for i in range(3)]  # fmt: skip
            assert codes == [201, 201, 429]
    finally:
        stop(live)


def test_counts_that_would_pass_int32_are_refused_and_nothing_is_stored(
    tmp_path: Path,
) -> None:
    with TestClient(create_app(make_settings(tmp_path / "data"))) as http:
        state = http.app.state.service  # type: ignore[attr-defined]
        admin = {"X-API-Key": state.admin_key}
        assert http.put("/domains/tiny", json={"map": TINY}, headers=admin).status_code == 201
        body = {"trajectories": [{"steps": [{"state": [5, 1], "action": "E"}]}]}
        r = http.post("/domains/tiny/trajectories", json=body, headers=admin)
        assert r.status_code == 201, r.text
        with state.store.engine.begin() as conn:  # as if 2^31 - 1 had been stored
            conn.execute(sa.text("UPDATE prior_counts SET n_trajectories = :n"), {"n": COUNT_MAX})
        r = http.post("/domains/tiny/trajectories", json=body, headers=admin)
        assert r.status_code == 409, r.text
        assert "2147483647" in r.json()["detail"] and "nothing was stored" in r.json()["detail"]
        assert len(state.store.trajectories("tiny")) == 1
        assert state.store.counts("tiny")["*"].n_trajectories == COUNT_MAX


@pytest.mark.parametrize("entry", ["not-an-address", "10.0.0.0/33"])
def test_a_trusted_proxy_that_is_no_address_is_refused_at_start(tmp_path: Path, entry: str) -> None:
    with pytest.raises(ValueError, match="is not an IP address or network"):
        make_settings(tmp_path, trusted_proxies=[entry])
