"""Ingestion while the same map is PUT again with other alpha0s, over the real server: every
ingest is acknowledged (the issue: 455 of 819 answered 404 "no domain named ..." in a 6-second
run, and a client taking 404 as final dropped expert data), and every one is stored."""

from __future__ import annotations

import threading
from pathlib import Path

import httpx

from app.domain.grid import GridDomain
from tests.reliability.conftest import server_errors, start, stop
from tests.reliability.test_memory import walk

WRITERS, INGESTS, PUTS = 3, 100, 50


def test_no_ingest_is_refused_while_the_same_map_is_put_again(tmp_path: Path) -> None:
    live = start(tmp_path / "data")
    statuses: list[int] = []
    puts: list[int] = []
    try:
        with httpx.Client(base_url=live.url, timeout=60, headers=live.admin) as http:
            rows = http.get("/domains/default").json()["map"]
            before = http.get("/domains/default").json()["trajectories"]
        grid = GridDomain.from_strings(rows)

        def writer(seed: int) -> None:
            with httpx.Client(base_url=live.url, timeout=60, headers=live.admin) as http:
                for i in range(INGESTS):
                    body = {"trajectories": [{"steps": walk(grid, 20, seed * 1000 + i)}]}
                    statuses.append(
                        http.post("/domains/default/trajectories", json=body).status_code
                    )

        def putter() -> None:  # until the writers are done, and at least PUTS times
            with httpx.Client(base_url=live.url, timeout=60, headers=live.admin) as http:
                while not done.is_set() or len(puts) < PUTS:
                    body = {"map": rows, "alpha0": 0.5 + (len(puts) % 7) / 4}
                    puts.append(http.put("/domains/default", json=body).status_code)

        done = threading.Event()
        writers = [threading.Thread(target=writer, args=(k,)) for k in range(WRITERS)]
        put_thread = threading.Thread(target=putter)
        for t in [put_thread, *writers]:
            t.start()
        for t in writers:
            t.join()
        done.set()
        put_thread.join()
        with httpx.Client(base_url=live.url, timeout=60) as http:
            after = http.get("/domains/default").json()["trajectories"]
    finally:
        stop(live)
    refused = [s for s in statuses if s != 201]
    print(f"\n{len(statuses)} ingests during {len(puts)} PUTs: {len(refused)} not acknowledged")
    assert len(statuses) == WRITERS * INGESTS and refused == []
    assert set(puts) == {200}
    assert after - before == WRITERS * INGESTS  # every acknowledged trajectory counted
    assert server_errors(live) == []
