"""An upgrade keeps what the version before floors wrote: its database (domains, trajectories,
counts four actions wide, the sessions a graceful stop kept) and its sessions as Redis keeps
them (packed session, packed decision records), read with no migration step.

``fixtures/previous`` was written by that version (commit aae9804) with
``fixtures/make_previous.py``, which says how; its ``expected.json`` holds what that version
answered next on the same data, and this version must answer the same, byte for byte once
parsed (timestamps of the session aside), but for sessions of a strategy whose decisions
changed since (:data:`CHANGED`): theirs are what this version's core advisor answers going on
from the session as that version kept it (its Redis form, written from the same live session
at the same moment as the database's)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from app.advice.advisor import Advisor
from app.service.live import codec
from app.service.main import create_app
from app.service.state import ServiceState
from app.service.wire.encode import batch_dicts, decision_dict
from tests.service.conftest import make_settings

PREVIOUS = Path(__file__).parent / "fixtures" / "previous"
EXPECTED: dict[str, Any] = json.loads((PREVIOUS / "expected.json").read_text())
#: what a session's summary holds that does not depend on when it is read
STEADY = ("advice_count", "benefit", "goals", "kappa", "p_normal", "params", "position",
          "prior_table", "steps", "strategy", "total_cost", "window", "beliefs")  # fmt: skip
#: ... nor on the decisions, for a strategy whose decisions changed since
KEPT = ("kappa", "params", "position", "steps", "strategy", "window")
#: strategies whose decisions changed since the fixture was written, and why
CHANGED = {"guide": "980442c: L4, the lost model of any action, takes the advice"}


def strategy(s: dict[str, Any]) -> str:
    name: str = s["summary"]["strategy"]
    return name


def continued(service: ServiceState, i: int, s: dict[str, Any]) -> list[dict[str, Any]]:
    """Session ``i``'s answers to its further events by this version's core advisor, going on
    from the session as the previous version kept it in Redis."""
    return going_on(service, i, s)[0]


def going_on(
    service: ServiceState, i: int, s: dict[str, Any]
) -> tuple[list[dict[str, Any]], Advisor]:
    """:func:`continued`, and the core advisor after those events."""
    domain = service.catalog.get(s["domain"])
    raw = (PREVIOUS / "redis" / f"{i}.session").read_bytes()
    session = codec.load(codec.unpacked(raw), domain, 8)
    grid, out = domain.domain, []
    for event in s["more"]:
        here = grid.state(*event["state"])
        a = "NESW".index(event["action"])
        d = session.advisor.observe(here, a, int(grid.next_state[here, a]))
        out.append(json.loads(json.dumps(decision_dict(d, grid))))
    return out, session.advisor


@pytest.fixture
def upgraded(tmp_path: Path) -> Any:
    data = tmp_path / "data"
    shutil.copytree(PREVIOUS / "data", data)
    # the sessions were kept when the fixture was made: idle since, so only a long idle limit
    # keeps them live (ten years), whenever the test runs
    settings = make_settings(
        data, bootstrap_per_goal=1, replay_steps=8, session_idle_seconds=10 * 365 * 86400.0
    )
    with TestClient(create_app(settings)) as client:
        yield client


def test_the_previous_version_s_database_and_kept_sessions_go_on_as_they_would_have(
    upgraded: TestClient,
) -> None:
    client = upgraded
    for name in ("default", "tiny"):
        assert client.get(f"/domains/{name}").json() == EXPECTED[name]
    prior = client.get("/domains/tiny/prior", params={"agent_type": "guest"})
    assert prior.json() == EXPECTED["tiny_prior"]
    service: ServiceState = client.app.state.service  # type: ignore[attr-defined]
    assert {strategy(s) for s in EXPECTED["sessions"]} - set(CHANGED)  # some did not change
    for i, s in enumerate(EXPECTED["sessions"]):
        changed = strategy(s) in CHANGED
        want, core = going_on(service, i, s) if changed else (s["answers"], None)
        auth = {"Authorization": f"Bearer {s['token']}"}
        r = client.post(f"/sessions/{s['id']}/events", json=s["more"], headers=auth)
        assert r.status_code == 200, r.text
        assert r.json() == want
        again = client.post(f"/sessions/{s['id']}/events", json=s["retry"], headers=auth)
        assert again.json() == s["retried"]  # kept steps: answered as that version did
        summary = client.get(f"/sessions/{s['id']}", headers=auth).json()
        keys = KEPT if changed else STEADY
        assert {k: summary[k] for k in keys} == {k: s["summary"][k] for k in keys}
        if core is not None:  # the rest of a changed one's summary: the core advisor's
            cost = want[-1]["cost"]
            assert summary["advice_count"] == core.advice_count == cost["advice_count"]
            assert summary["benefit"] == core.benefit == cost["benefit"]
            assert summary["total_cost"] == cost["total"]
            assert summary["p_normal"] == want[-1]["p_normal"]


def test_sessions_the_previous_version_kept_in_redis_read_as_they_were(
    upgraded: TestClient,
) -> None:
    """The Redis form (read by ``codec``, as every worker reads it): the session goes on with
    the answers that version gave, and its decision records read back as it answered them."""
    service: ServiceState = upgraded.app.state.service  # type: ignore[attr-defined]
    for i, s in enumerate(EXPECTED["sessions"]):
        domain = service.catalog.get(s["domain"])
        raw = (PREVIOUS / "redis" / f"{i}.session").read_bytes()
        session = codec.load(codec.unpacked(raw), domain, 8)
        records = codec.read_packed_records((PREVIOUS / "redis" / f"{i}.records").read_bytes())
        kept = [d for batch in records for d in batch_dicts(batch, domain.domain)]
        assert kept == s["first_answers"][-len(kept) :] and len(kept) == 8
        assert session.advisor.steps == len(s["sent"])
        if strategy(s) not in CHANGED:  # a changed one's: the database's test, against this
            assert continued(service, i, s) == s["answers"]
