"""What the routes ask for, one function each: the routes do HTTP, these do the work.

Functions marked *worker thread* touch the database and run through ``run_in_threadpool``;
the others run on the event loop and never block.
"""

from __future__ import annotations

from app.advice.advisor import Decision
from app.domain.grid import GridDomain, MapError
from app.service.domains import DomainState
from app.service.encode import encode_decisions, fragments
from app.service.events import BadInput, parse_events, to_moves
from app.service.ingest import parse_trajectories, to_trajectories
from app.service.registry import LiveSession, TooManySessions
from app.service.schemas import Cell, DomainPut, SessionCreate, TrajectoriesAccepted
from app.service.state import ServiceState


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
    try:
        return state.registry.create(domain, body.kappa, body.window, body.agent_type, start)
    except TooManySessions:
        raise BadInput(
            f"the service has its maximum of {state.registry.max_sessions} live sessions: "
            "end one (DELETE /sessions/{id}) or retry after idle sessions expire",
            503,
        ) from None


def apply_events(state: ServiceState, session: LiveSession, raw: bytes | str) -> str:
    """Events (JSON text: one or a list) -> decisions (JSON text: one or a list, in order)."""
    events, single = parse_events(raw, state.settings.max_batch_events)
    moves = to_moves(session.domain.domain, events)
    tables = session.advisor.tables
    cols = state.registry.observe(session, moves)
    return encode_decisions(cols, fragments(tables, session.domain.cell_json), single)


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
    return TrajectoriesAccepted(accepted=len(items), pairs=sum(len(t.pairs) for t in items))
