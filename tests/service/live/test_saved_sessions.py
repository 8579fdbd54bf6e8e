"""Sessions written by the version before the strategy registry (tests/service/live/data/,
made by that version: each strategy's session after 25 moves, in the form the database keeps at
a shutdown and in the packed form Redis keeps) load in this one and go on with the decisions
that version made, bit for bit (guide's until it holds advice back from a visitor who ignores
it, which that version did not)."""

from __future__ import annotations

import base64
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from app.domain.grid import GridDomain
from app.service.data.domains import DomainState
from app.service.data.store import Trajectory
from app.service.live.codec import load, unpacked
from app.service.live.registry import Limits, SessionRegistry
from app.service.state import ServiceState
from tests.service.live.test_codec import columns

SAVED = json.loads(
    (Path(__file__).parent / "data" / "sessions-before-registry.json").read_text("utf-8")
)


@pytest.fixture
def tiny(service: ServiceState) -> DomainState:
    """The domain the sessions were made on, made again: its map and expert trajectories."""
    grid = GridDomain.from_strings(SAVED["map"])
    domain, _, _ = service.catalog.put("tiny", grid, SAVED["alpha0"])
    trajectories = [
        Trajectory(None, np.array(t["pairs"]), t["goal"]) for t in SAVED["trajectories"]
    ]
    domain = service.catalog.add_trajectories(domain, trajectories)
    service.catalog.guide_map(domain)
    return service.catalog.get("tiny")


@pytest.mark.parametrize("form", ["store", "redis"])
@pytest.mark.parametrize("strategy", sorted(SAVED["sessions"]))
def test_a_session_saved_before_the_registry_goes_on_as_it_would_have(
    tiny: DomainState, strategy: str, form: str
) -> None:
    saved: dict[str, Any] = SAVED["sessions"][strategy]
    raw = base64.b64decode(saved[form])
    session = load(unpacked(raw) if form == "redis" else raw, tiny, 32)
    assert session.advisor.strategy == strategy
    reg = SessionRegistry(Limits(10), 3600.0, replay_steps=32)
    reg.put(session)
    after = tuple(np.array(m, dtype=np.int64) for m in saved["after"])
    got = reg.observe_batch(session, after)  # type: ignore[arg-type]
    now, then = columns(got), saved["decisions"]
    if strategy not in HOLDS_BACK:
        assert now == then
        return
    # guide's decisions changed on purpose since (it holds advice back from a visitor who
    # ignores it, spends an advice budget, has a fifth lost model): the session loads, goes
    # on from the same step, and decides as the readable advisor does from the same state,
    # one move at a time
    first, state, advise, kl, *_ = now
    assert (first, state) == (then[0], then[1])
    again = load(unpacked(raw) if form == "redis" else raw, tiny, 32)
    readable = [again.advisor.observe(*(int(m[i]) for m in after)) for i in range(len(after[0]))]
    assert advise == [d.advise for d in readable]
    assert kl == np.array([d.kl for d in readable]).view(np.int64).tolist()


#: strategies whose decisions changed on purpose since the sessions were saved: guide holds
#: advice back from a visitor who ignores it (app/advice/guide.py, "compliance"), spends an
#: advice budget and has a fifth lost model (LA)
HOLDS_BACK = frozenset({"guide"})
