"""What the routes ask for, one function each: the routes do HTTP, these do the work.

Functions marked *worker thread* touch the database and run through ``run_in_threadpool``;
the others run on the event loop and never block.
"""

from __future__ import annotations

import json

import numpy as np

from app.advice.advisor import Decision
from app.advice.goals import GoalAwareAdvisor
from app.advice.models import AdviceTables
from app.advice.strategies import StrategyParams
from app.domain.grid import ACTIONS, GridDomain, MapError
from app.service.domains import DomainState
from app.service.encode import (
    SMALL,
    encode_binary,
    encode_decisions,
    encode_one,
    fragments,
    packed,
)
from app.service.events import SMALL_EVENTS, BadInput, read_move, read_moves
from app.service.ingest import parse_trajectories, to_trajectories
from app.service.registry import LiveSession, TooManySessions
from app.service.schemas import Cell, DomainPut, SessionCreate, TrajectoriesAccepted
from app.service.state import ServiceState
from app.service.stream_advisor import StreamAdvisor
from app.service.stream_advisor import warm_up as warm_up_advisor


def cell_state(domain: GridDomain, cell: Cell, what: str) -> int:
    try:
        return domain.state(*cell)
    except ValueError as exc:
        raise BadInput(f"{what}: {exc}") from None


def create_session(
    state: ServiceState, domain: DomainState, body: SessionCreate
) -> tuple[LiveSession, Decision]:
    limit = state.settings.max_window
    if body.window > limit:
        raise BadInput(f"window: {body.window} is larger than this service allows ({limit})")
    grid = domain.domain
    start = grid.start if body.start is None else cell_state(grid, body.start, "start")
    params = StrategyParams(**body.params.model_dump()) if body.params else StrategyParams()
    if body.strategy == "goal_aware" and domain.goal_priors is None:
        state.catalog.goal_priors(domain)  # reads the store once; routes call it off the loop
    try:
        return state.registry.create(
            domain, body.kappa, body.window, body.agent_type, start, body.strategy, params
        )
    except TooManySessions:
        raise BadInput(
            f"the service has its maximum of {state.registry.max_sessions} live sessions: "
            "end one (DELETE /sessions/{id}) or retry after idle sessions expire",
            503,
        ) from None


def apply_events(state: ServiceState, session: LiveSession, raw: bytes | str) -> str:
    """Events (JSON text: one or a list) -> decisions (JSON text: one or a list, in order)."""
    move = read_move(session.domain.domain, raw)
    if move is not None:  # one event: plain ints and one decision, no arrays or columns
        d, tables = state.registry.observe_one(session, *move)
        own = isinstance(session.advisor, GoalAwareAdvisor)
        return encode_one(d, fragments(tables, session.domain.cell_json), own)
    moves, single = read_moves(session.domain.domain, raw, state.settings.max_batch_events)
    tables = session.advisor.tables
    cols = state.registry.observe(session, moves)
    cell_json = session.domain.cell_json
    pack = packed(tables, cell_json) if len(cols) > SMALL else None
    return encode_decisions(cols, fragments(tables, cell_json), single, pack)


def apply_events_binary(state: ServiceState, session: LiveSession, raw: bytes | str) -> bytes:
    """Events (JSON text: one or a list) -> decisions as one binary frame
    (:mod:`app.protocol`), the same decisions as :func:`apply_events` gives."""
    moves, _ = read_moves(session.domain.domain, raw, state.settings.max_batch_events)
    return encode_binary(state.registry.observe_arrays(session, moves), session.domain.domain)


def put_domain(state: ServiceState, name: str, body: DomainPut) -> tuple[DomainState, bool, bool]:
    """*Worker thread.* Create or replace a domain: (state, created, kept_data)."""
    try:
        grid = state.catalog.parse_map(body.map, name)
    except MapError as exc:
        raise BadInput(f"map: {exc}") from None
    return state.catalog.put(name, grid, body.alpha0)


def after_put(state: ServiceState, domain: DomainState, kept: bool) -> None:
    """On the loop: sessions follow a domain whose map stayed; others end with their map."""
    if kept:
        state.registry.retable(domain)
    else:
        state.registry.end_domain(domain.name)


def ingest(state: ServiceState, domain: DomainState, raw: bytes) -> TrajectoriesAccepted:
    """*Worker thread.* Parse, check and durably store trajectories; update the prior."""
    body = parse_trajectories(raw)
    items = to_trajectories(domain.domain, body, state.settings.max_trajectory_steps)
    state.catalog.add_trajectories(domain, items)
    prepare_answers(domain)
    return TrajectoriesAccepted(accepted=len(items), pairs=sum(len(t.pairs) for t in items))


def prepare_answers(domain: DomainState) -> None:
    """Build the per-state answer texts of the domain's current tables now (ingestion runs in a
    worker thread) rather than at the first event after the update, on the event loop: about
    1 ms for the default maze, at every ingest."""
    for tables in domain.view.tables.values():
        packed(tables, domain.cell_json)  # builds fragments() too


def warm_up() -> None:
    """Load (or compile, the first time) every compiled loop of :func:`apply_events` (reader,
    checks, advisor, encoder), so that no request waits for it."""
    warm_up_advisor()
    grid = GridDomain.from_strings(["#####", "#S.G#", "#####"])
    tables = AdviceTables.paper(np.full((grid.n_states, 4), 0.25))
    event = {"state": list(grid.cell(grid.start)), "action": ACTIONS[1]}
    moves, _ = read_moves(grid, json.dumps([event] * (SMALL_EVENTS + 1)), SMALL_EVENTS + 1)
    advisor = StreamAdvisor(tables)
    advisor.start(grid.start)
    cols = advisor.observe_many(*moves)
    cells = [f"[{r},{c}]" for r, c in grid.cells.tolist()]
    encode_decisions(cols, fragments(tables, cells), False, packed(tables, cells))
