"""What the routes ask for, one function each: the routes do HTTP, these do the work.

Functions marked *worker thread* touch the database and run through ``run_in_threadpool``;
the others run on the event loop and never block.
"""

from __future__ import annotations

import json

import numpy as np

from app.advice.advisor import Decision
from app.advice.models import AdviceTables
from app.advice.strategies import strategy_params
from app.domain.grid import ACTIONS, GridDomain, MapError
from app.service.data.domains import DomainState
from app.service.data.ingest import parse_trajectories, to_trajectories
from app.service.live.registry import LiveSession, TooManySessions
from app.service.live.stream import StreamAdvisor
from app.service.problems import BadInput
from app.service.schemas import Cell, DomainPut, SessionCreate, TrajectoriesAccepted
from app.service.state import ServiceState
from app.service.wire.encode import batch_binary, batch_json, decision_json, theta_text
from app.service.wire.events import read_move, read_moves


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
    given = body.params.model_dump(exclude_unset=True) if body.params else {}
    try:
        params = strategy_params(body.strategy, given)
    except ValueError as exc:
        raise BadInput(f"params: {exc}") from None
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


def apply_events(state: ServiceState, session: LiveSession, raw: bytes | str) -> bytes:
    """Events (JSON text: one or a list) -> decisions (JSON: one or a list, in order)."""
    grid = session.domain.domain
    move = read_move(grid, raw)
    if move is not None:  # one event object: plain ints and one decision
        return decision_json(state.registry.observe_one(session, *move), grid)
    moves, _ = read_moves(grid, raw, state.settings.max_batch_events)  # a list (or not JSON)
    return batch_json(state.registry.observe_batch(session, moves), grid)


def apply_events_binary(state: ServiceState, session: LiveSession, raw: bytes | str) -> bytes:
    """Events (JSON text: one or a list) -> decisions as one binary frame
    (:mod:`app.protocol`), the same decisions as :func:`apply_events` gives."""
    grid = session.domain.domain
    moves, _ = read_moves(grid, raw, state.settings.max_batch_events)
    return batch_binary(state.registry.observe_batch(session, moves), grid)


def put_domain(state: ServiceState, name: str, body: DomainPut) -> tuple[DomainState, bool, bool]:
    """*Worker thread.* Create or replace a domain: (state, created, kept_data)."""
    try:
        grid = state.catalog.parse_map(body.map, name)
    except MapError as exc:
        raise BadInput(f"map: {exc}") from None
    domain, created, kept = state.catalog.put(name, grid, body.alpha0)
    prepare_answers(domain)
    return domain, created, kept


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
    """*Worker thread.* The text of theta that batch answers copy their advice from, for each
    table of the domain's current prior, made here rather than at the first batch after the
    prior changed (on the event loop)."""
    for tables in domain.view.tables.values():
        theta_text(tables)


def warm_up() -> None:
    """Load (or compile, the first time) every compiled loop of the event paths (reader,
    checks, advisor, writers), so that no request waits for it."""
    grid = GridDomain.from_strings(["#####", "#S.G#", "#####"])
    tables = AdviceTables.paper(np.full((grid.n_states, 4), 0.25))
    event = {"state": list(grid.cell(grid.start)), "action": ACTIONS[1]}
    moves, _ = read_moves(grid, json.dumps([event] * 3), 3)
    advisor = StreamAdvisor(tables, kappa=0.0, window=2)
    advisor.start(grid.start)
    out = advisor.observe_batch(*moves)
    advisor.tables = AdviceTables.paper(np.full((grid.n_states, 4), 0.25))  # a prior update
    advisor.observe_batch(*moves)
    batch_json(out, grid)
    batch_binary(out, grid)
