"""One client cannot take every slot (the issue: sessions cost about 6 ms to create, and one
anonymous client could hold all 20,000 for the 30-minute idle timeout), and stored counts
cannot wrap round (they are int32: the issue found no overflow check).

Over the real server: a client is the key it sends where the service knows it (the operator
key, ``ADVISOR_CLIENT_KEYS``), else its address (127.0.0.1 and 127.0.0.2 are two clients on
this machine's loopback), also when it sends a key nobody gave it; behind a proxy the operator
trusts, the forwarded address; X-Forwarded-For from anyone else is not believed. With workers,
the same through Redis."""

from __future__ import annotations

import json
from pathlib import Path
from typing import cast

import httpx
import pytest
import sqlalchemy as sa
from fastapi.testclient import TestClient

from app.service.data.store import COUNT_MAX
from app.service.main import create_app
from tests.reliability.conftest import server_errors, start, stop
from tests.service.conftest import (
    REDIS_URL,
    TINY,
    drop_redis_keys,
    make_settings,
    redis_prefix,
    redis_problem,
)

QUOTA = 5
GATEWAY_KEY = "gateway-key-of-this-test-0123456789"


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


def test_trusted_proxies_are_read_by_uvicorns_middleware_networks_included(
    tmp_path: Path,
) -> None:
    """A network given with host bits (``127.0.0.9/8``) is the network, as the settings have
    always taken it; behind it the forwarded address is the client, a port on it dropped."""
    from app.service.clients import trusted_hosts

    assert trusted_hosts(["127.0.0.9/8", "10.0.0.5", "::1", "fd00::/8"]) == [
        "127.0.0.0/8", "10.0.0.5", "::1", "fd00::/8",
    ]  # fmt: skip
    settings = make_settings(tmp_path / "data", trusted_proxies=["127.0.0.9/8"],
                             client_max_sessions=1)  # fmt: skip
    app = create_app(settings)
    with TestClient(app, client=("127.0.0.1", 5000)) as proxy:

        def create(forwarded: str) -> int:
            r = proxy.post("/domains/default/sessions", json={},
                           headers={"X-Forwarded-For": forwarded})  # fmt: skip
            return int(r.status_code)

        assert create("10.0.0.7") == 201
        assert create("10.0.0.7:4321") == 429  # the same client, another port
        assert create("1.2.3.4, 10.0.0.7") == 429  # the client's own entry is not believed
        assert create("10.0.0.8, 127.0.0.2") == 201  # a second proxy of the network: 10.0.0.8
    with TestClient(app, client=("192.0.2.1", 5000)) as direct:  # not a trusted proxy
        codes = [direct.post("/domains/default/sessions", json={},
                             headers={"X-Forwarded-For": f"10.1.0.{i}"}).status_code
                 for i in range(2)]  # fmt: skip
        assert codes == [201, 429]


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


def test_a_cell_count_that_would_pass_int32_is_refused_and_nothing_is_stored(
    tmp_path: Path,
) -> None:
    """Each (state, action) count goes through the same check as the number of trajectories:
    one count at 2^31 - 1 and one more expert through that cell is refused whole, 409."""
    with TestClient(create_app(make_settings(tmp_path / "data"))) as http:
        state = http.app.state.service  # type: ignore[attr-defined]
        admin = {"X-API-Key": state.admin_key}
        assert http.put("/domains/tiny", json={"map": TINY}, headers=admin).status_code == 201
        body = {"trajectories": [{"steps": [{"state": [5, 1], "action": "E"}]}]}
        assert http.post("/domains/tiny/trajectories", json=body, headers=admin).status_code == 201
        grid = state.catalog.get("tiny").domain
        s, east = grid.state(5, 1), 1
        stored = state.store.counts("tiny")["*"]
        assert stored.counts[s, east] == 1 and stored.n_trajectories == 1
        full = stored.counts.copy()
        full[s, east] = COUNT_MAX  # as if 2^31 - 1 experts had gone east there
        with state.store.engine.begin() as conn:
            conn.execute(sa.text("UPDATE prior_counts SET counts = :c"),
                         {"c": full.astype("<i4").tobytes()})  # fmt: skip
        # an expert through another cell is stored; through the full one, refused
        other = {"trajectories": [{"steps": [{"state": [5, 2], "action": "E"}]}]}
        assert http.post("/domains/tiny/trajectories", json=other, headers=admin).status_code == 201
        r = http.post("/domains/tiny/trajectories", json=body, headers=admin)
        assert r.status_code == 409, r.text
        assert "2147483647" in r.json()["detail"] and "nothing was stored" in r.json()["detail"]
        assert len(state.store.trajectories("tiny")) == 2
        after = state.store.counts("tiny")["*"]
        assert after.counts[s, east] == COUNT_MAX and after.n_trajectories == 2
        assert int(after.counts.sum()) == COUNT_MAX + 1  # nothing wrapped round, nothing added


@pytest.mark.parametrize("entry", ["not-an-address", "10.0.0.0/33"])
def test_a_trusted_proxy_that_is_no_address_is_refused_at_start(tmp_path: Path, entry: str) -> None:
    with pytest.raises(ValueError, match="is not an IP address or network"):
        make_settings(tmp_path, trusted_proxies=[entry])


def test_a_known_key_is_one_client_from_any_address_and_an_invented_one_is_its_address(
    tmp_path: Path,
) -> None:
    """A positioning gateway with a key of ADVISOR_CLIENT_KEYS has its quota wherever its
    requests come from; a key the service does not know makes no client of its own (it would
    be a fresh quota for anyone who invents one): it is counted by its address."""
    keys = json.dumps({"gateway": GATEWAY_KEY})
    live = start(tmp_path / "data", log_level="info", ADVISOR_CLIENT_MAX_SESSIONS="3",
                 ADVISOR_CLIENT_KEYS=keys)  # fmt: skip
    gateway = {"X-API-Key": GATEWAY_KEY}
    operator = {"X-API-Key": (live.data_dir / "operator_key").read_text().strip()}
    try:
        with client(live.url) as one, client(live.url, "127.0.0.2") as two:

            def create(http: httpx.Client, headers: dict[str, str]) -> httpx.Response:
                return http.post("/domains/default/sessions", json={}, headers=headers)

            # the same key from two addresses: one quota of 3
            made = [create(http, gateway) for http in (one, two, one)]
            assert [r.status_code for r in made] == [201, 201, 201]
            for http in (one, two):
                refused = create(http, gateway)
                assert refused.status_code == 429, refused.text
                detail = refused.json()["detail"]
                assert "(key gateway)" in detail and "3 live sessions" in detail
                assert GATEWAY_KEY not in refused.text
            # the addresses' own quotas are untouched by the key's sessions
            assert create(two, {}).status_code == 201
            # invented keys: each counted against its address, which they share with no key
            invented = [create(one, {"X-API-Key": f"made-up-key-{i}"}) for i in range(4)]
            assert [r.status_code for r in invented] == [201, 201, 201, 429]
            assert "(address 127.0.0.1)" in invented[-1].json()["detail"]
            assert create(one, {}).status_code == 429  # the same client as the invented keys
            # the operator key is one client too, from either address
            codes = [create(http, operator).status_code for http in (one, two, two, one)]
            assert codes == [201, 201, 201, 429]
            assert len(one.get("/sessions", headers=live.admin).json()["sessions"]) == 10
            # ending one of the key's sessions frees a place for the key, from anywhere
            ended = made[0].json()["session_id"]
            assert one.delete(f"/sessions/{ended}", headers=live.admin).status_code == 200
            assert create(two, gateway).status_code == 201
            assert create(one, gateway).status_code == 429
    finally:
        stop(live)
    assert server_errors(live) == []
    assert GATEWAY_KEY not in live.log.read_text(errors="replace")  # never logged


def test_client_keys_that_cannot_work_are_refused_at_start(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="shorter than 16 characters"):
        make_settings(tmp_path, client_keys={"gw": "short"})
    with pytest.raises(ValueError, match="client name 'a b'"):
        make_settings(tmp_path, client_keys={"a b": GATEWAY_KEY})
    with pytest.raises(ValueError, match="is another client's too"):
        make_settings(tmp_path, client_keys={"a": GATEWAY_KEY, "b": GATEWAY_KEY})
    with pytest.raises(ValueError) as refused:  # the message never holds the key
        make_settings(tmp_path, client_keys={"gw": "short"})
    assert "short'" not in str(refused.value).replace("'**********'", "")
    # a client key that is the admin key would be the admin: refused when the service starts
    settings = make_settings(tmp_path / "data", admin_key=GATEWAY_KEY,
                             client_keys={"gw": GATEWAY_KEY})  # fmt: skip
    refused_at_start = "the key of client 'gw' is the admin or the operator"
    with pytest.raises(ValueError, match=refused_at_start), TestClient(create_app(settings)):
        pass


REDIS_PROBLEM = redis_problem()


@pytest.mark.skipif(REDIS_PROBLEM is not None, reason=f"Redis at {REDIS_URL}: {REDIS_PROBLEM}")
def test_with_workers_a_known_key_is_one_client_across_workers_and_addresses(
    tmp_path: Path,
) -> None:
    """Three workers sharing Redis, reached from two addresses: the key's sessions count
    against one quota whichever worker and address made them; an invented key against its
    address, through any worker; Redis holds the key's name, never the key."""
    import redis

    prefix = redis_prefix()
    url = f"sqlite:///{tmp_path / 'advisor.db'}"
    settings = make_settings(
        tmp_path, database_url=url, redis_url=REDIS_URL, redis_prefix=prefix,
        client_max_sessions=2, client_keys={"gateway": GATEWAY_KEY},
    )  # fmt: skip
    apps = [create_app(settings) for _ in range(3)]
    gateway = {"X-API-Key": GATEWAY_KEY}
    a = TestClient(apps[0], client=("10.0.0.1", 40000))
    b = TestClient(apps[1], client=("10.0.0.2", 40000))
    c = TestClient(apps[2], client=("10.0.0.1", 40001))  # a's address, through a third worker
    try:
        for http in (a, b, c):
            http.__enter__()

        def create(http: TestClient, headers: dict[str, str]) -> int:
            return int(http.post("/domains/default/sessions", json={}, headers=headers).status_code)

        assert [create(a, gateway), create(b, gateway)] == [201, 201]
        for http in (a, b):
            r = http.post("/domains/default/sessions", json={}, headers=gateway)
            assert r.status_code == 429 and "(key gateway)" in r.json()["detail"], r.text
        # an invented key is its address, whichever worker: 10.0.0.1 has two places
        invented = [
            create(a, {"X-API-Key": "x" * 40}),
            create(c, {}),
            create(c, {"X-API-Key": "z" * 40}),
        ]
        assert invented == [201, 201, 429]
        assert create(b, {"X-API-Key": "y" * 40}) == 201  # 10.0.0.2's first
        store = redis.Redis.from_url(REDIS_URL)
        try:
            names = [k.decode() for k in store.scan_iter(f"{prefix}:*", count=1000)]
            assert f"{prefix}:c:key gateway" in names
            assert int(cast(bytes, store.hget(f"{prefix}:c:key gateway", "n"))) == 2
            for name in names:
                assert GATEWAY_KEY not in name
                if store.type(name) == b"hash":
                    values = cast(list[bytes], store.hvals(name))
                    assert all(GATEWAY_KEY.encode() not in v for v in values)
        finally:
            store.close()
    finally:
        for http in (a, b, c):
            http.__exit__(None, None, None)
        drop_redis_keys(prefix)
