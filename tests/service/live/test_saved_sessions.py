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
    # guide now holds advice back from a visitor who ignores it (these moves ignore every
    # piece): the same decisions, bit for bit, until the first piece it holds back (after
    # several ignored ones); from there on its evidence differs (a move after no advice is
    # read as the visitor's own)
    first, state, advise, kl, p_normal, _, _, rows = now
    assert (first, state) == (then[0], then[1])
    held = next(i for i, (a, b) in enumerate(zip(advise, then[2], strict=True)) if a != b)
    assert then[2][held] and not advise[held] and sum(then[2][:held]) >= 5
    assert kl[: held + 1] == then[3][: held + 1] and p_normal[: held + 1] == then[4][: held + 1]
    given = sum(then[2][:held])  # the advice rows are the advised decisions'
    assert rows[:given] == then[7][:given]


#: strategies whose decisions changed on purpose since the sessions were saved: guide holds
#: advice back from a visitor who ignores it (app/advice/guide.py, "compliance")
HOLDS_BACK = frozenset({"guide"})
