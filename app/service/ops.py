"""What the routes ask for, one function each: the routes do HTTP, these do the work.

Functions marked *worker thread* touch the database and run through ``run_in_threadpool``;
the others run on the event loop and never block.
"""

from __future__ import annotations

import asyncio
from typing import Any

import numpy as np
import orjson
from starlette.concurrency import run_in_threadpool

from app import strategies
from app.advice.advisor import Decision, DecisionBatch
from app.arrays import IntArray
from app.domain.building import Building, Domain
from app.domain.grid import GridDomain, MapError
from app.domain.paths import expert_trajectories, walked_cells
from app.service.data.domains import DomainNotFound, DomainState, needed
from app.service.data.ingest import parse_trajectories, to_trajectories
from app.service.data.store import POOLED, Trajectory
from app.service.live.registry import (
    Aggregate,
    Budget,
    ClientQuotaReached,
    LiveSession,
    SessionMemoryFull,
    SessionSettings,
    SessionSnapshot,
    TooManySessions,
)
from app.service.live.replay import StepConflict
from app.service.mapbody import building_of, map_of
from app.service.metrics import METRICS, ingested
from app.service.problems import BadInput
from app.service.public import (
    decision_leads_to,
    overview_domain,
    overview_session,
    viewer_session,
)
from app.service.schemas import (
    Cell,
    DomainPut,
    ExpertsIn,
    PositionsIn,
    SessionCreate,
    TrajectoriesAccepted,
)
from app.service.state import ServiceState
from app.service.wire.encode import batch_binary, batch_json, decision_json
from app.service.wire.events import cell_words, read_move, read_moves, share_lists
from app.service.wire.warm import warm
from app.strategies import Need

#: an expert walk's longest (``expert_trajectory``'s default ``max_steps``)
EXPERT_MAX_STEPS = 10_000


def cell_state(domain: Domain, cell: Cell, what: str) -> int:
    if len(cell) != domain.width:
        raise BadInput(f"{what}: {list(cell)}: {cell_words(domain)}")
    try:
        return domain.state(*cell)
    except ValueError as exc:
        raise BadInput(f"{what}: {exc}") from None


def session_settings(
    state: ServiceState, domain: DomainState, body: SessionCreate
) -> SessionSettings:
    """A session request's settings, checked against this service's limits before anything
    is built for it: the strategy, the window, the strategy's parameters, for strategies that
    read the experts' goals the per-goal tables (goals x cells), for one that keeps a value
    per goal and pair the goals x window, and the start cell."""
    limits = state.settings
    if body.window > limits.max_window:
        raise BadInput(
            f"window: {body.window} is larger than this service allows ({limits.max_window})"
        )
    given = body.params.model_dump(exclude_unset=True) if body.params else {}
    try:
        entry = strategies.get(body.strategy)
        advisor = entry.settings(body.kappa, body.window, given)
    except ValueError as exc:
        raise BadInput(f"params: {exc}") from None
    goals, cells = len(domain.domain.goals), domain.domain.n_states
    if entry.needs and goals * cells > limits.max_goal_cells:
        raise BadInput(
            f"strategy {entry.name}: domain {domain.name!r} has {goals} goals x {cells} "
            f"free cells = {goals * cells} per-goal entries, more than this service keeps "
            f"({limits.max_goal_cells}, ADVISOR_MAX_GOAL_CELLS)"
        )
    if entry.goal_window(advisor.params) and goals * body.window > limits.max_goal_window:
        raise BadInput(
            f"window: {entry.name} with these parameters keeps a value per goal and pair: "
            f"{goals} goals x window {body.window} = {goals * body.window} is more than this "
            f"service allows ({limits.max_goal_window}, ADVISOR_MAX_GOAL_WINDOW): a smaller "
            "window, or parameters that keep none (goal_aware: beta 0)"
        )
    grid = domain.domain
    start = None if body.start is None else cell_state(grid, body.start, "start")
    budget = None if body.budget is None else Budget(body.budget.total, body.budget.per_minute)
    return SessionSettings(advisor, body.agent_type, start, budget)


#: Seconds a client is told to wait for a domain being prepared (Retry-After)
PREPARING_RETRY = 2


async def open_session(
    state: ServiceState, domain: DomainState, body: SessionCreate, client: str | None = None
) -> tuple[LiveSession, Decision]:
    """A session for ``body`` (checked first, :func:`session_settings`) on a domain prepared
    for its strategy (:func:`unprepared` otherwise: nothing is built on a session's request);
    ``client``: whom its quota counts against (None: no quota)."""
    settings = session_settings(state, domain, body)
    entry = strategies.get(settings.advisor.strategy)
    lacking = entry.missing(domain.data(POOLED))
    if lacking:
        raise unprepared(state, domain, entry.name, lacking)
    return await create_session(state, domain, settings, client)


#: background preparations started by :func:`unprepared`, kept until they end
_preparing: set[asyncio.Future[None]] = set()


def unprepared(
    state: ServiceState, domain: DomainState, strategy: str, lacking: list[Need]
) -> BadInput:
    """Why a session of ``strategy`` cannot open on ``domain`` now: 422 with the reason when
    the domain cannot have what it needs (``domain.refused``), else 503 with Retry-After while
    it is being prepared. What the strategies need is built when the domain is PUT or read
    after another worker changed it (:meth:`DomainCatalog.prepare_all`, the admin's request or
    the refresh waits for it), not on a session's request; if nothing is building it (a
    strategy registered after the domain was prepared), one preparation starts in a worker
    thread, and this request does not wait for it."""
    for need in lacking:
        why = domain.refused.get(need)
        if why is not None:
            return BadInput(f"strategy {strategy}: {why}")
    if not domain.preparing:
        domain.preparing = True  # one at a time: the next request sees it running
        task = asyncio.ensure_future(run_in_threadpool(state.catalog.prepare_all, domain))
        _preparing.add(task)
        task.add_done_callback(_preparing.discard)
    return BadInput(
        f"domain {domain.name!r} is being prepared for strategy {strategy} "
        f"({lacking[0].value}): retry in a few seconds",
        503,
        {"Retry-After": str(PREPARING_RETRY)},
    )


async def create_session(
    state: ServiceState, domain: DomainState, settings: SessionSettings,
    client: str | None = None,
) -> tuple[LiveSession, Decision]:  # fmt: skip
    """A session of checked ``settings`` on ``domain`` (made ready for its strategy); the
    sessions' refusals as 503 and 429 answers."""
    sessions = state.sessions
    try:
        session, decision = await sessions.create(domain, settings, client)
    except TooManySessions:
        raise BadInput(
            f"the service has its maximum of {sessions.max_sessions} live sessions: "
            "end one (DELETE /sessions/{id}) or retry after idle sessions expire",
            503,
        ) from None
    except SessionMemoryFull as exc:
        raise BadInput(
            f"the live sessions hold the {exc.args[0]} bytes this service keeps for sessions "
            "(ADVISOR_MAX_SESSION_MEMORY): end one, ask for a smaller window, or retry after "
            "idle sessions expire",
            503,
        ) from None
    except ClientQuotaReached as exc:
        who, what, limit = exc.args
        held = f"{limit} live sessions" if what == "sessions" else f"{limit} bytes of sessions"
        raise BadInput(
            f"this client ({who}) holds {held}, the most one client may "
            f"(ADVISOR_CLIENT_MAX_{'SESSIONS' if what == 'sessions' else 'SESSION_MEMORY'}): "
            "end some (DELETE /sessions/{id}) or retry after idle ones expire",
            429,
        ) from None
    _count(state, session, 1, int(decision.advise))
    return session, decision


def _count(state: ServiceState, session: LiveSession, made: int, advised: int) -> None:
    if state.settings.metrics_enabled:
        METRICS.decisions(session.domain.name, session.advisor.strategy, made, advised)


def _count_batch(state: ServiceState, session: LiveSession, out: DecisionBatch) -> None:
    if state.settings.metrics_enabled and len(out):
        _count(state, session, len(out), int(np.count_nonzero(out.advise)))


def conflict(exc: StepConflict) -> BadInput:
    return BadInput(str(exc), 409)


async def answer_events(
    state: ServiceState, session: LiveSession, raw: bytes | str, binary: bool = False
) -> bytes:
    """Events (JSON text: one or a list) -> decisions (JSON: one or a list, in order; with
    ``binary``, one binary frame, :mod:`advisor_client.protocol`): a long batch in slices, the
    event loop free for others between them (:meth:`SessionRegistry.observe_sliced`)."""
    grid, sessions = session.domain.domain, state.sessions
    try:
        if not binary:
            move = read_move(grid, raw)
            if move is not None:
                d = await sessions.observe_one(session, *move)
                _count(state, session, 1, int(d.advise))
                leads = decision_leads_to(sessions.current(session), d) if d.advise else None
                return decision_json(d, grid, leads)
        moves, _, first = read_moves(grid, raw, state.settings.max_batch_events)
        out = await sessions.observe(session, moves, first)
    except StepConflict as exc:
        raise conflict(exc) from None
    _count_batch(state, session, out)
    return batch_binary(out, grid) if binary else batch_json(out, grid)


async def apply_positions(state: ServiceState, session: LiveSession, body: PositionsIn) -> bytes:
    """Positions in metres -> decisions (JSON list), one per move. Each reading is snapped to
    the cell holding it; a reading in the cell of the one before adds no move; a reading up to
    ``max_jump`` moves away is walked along a shortest path (one decision per cell of it); a
    reading farther away, in a wall or off the map refuses the whole batch (nothing applied)."""
    moves = position_moves(state, session, body)
    if moves is None:
        return b"[]"
    out = await state.sessions.observe(session, moves)
    _count_batch(state, session, out)
    return batch_json(out, session.domain.domain)


def point_state(grid: Domain, point: list[float]) -> int:
    """The state holding a reading: ``[x, y]`` in metres, on a map of several floors ``[x, y,
    floor]`` (the floor's index); ValueError says why there is none."""
    if isinstance(grid, Building):
        if len(point) != 3 or not float(point[2]).is_integer():
            raise ValueError(
                f"this map has {grid.n_floors} floors: a position is [x, y, floor], floor the "
                "index of its floor (0 the lowest)"
            )
        return grid.state_at(int(point[2]), point[0], point[1])
    if len(point) != 2:
        raise ValueError("this map has one floor: a position is [x, y]")
    return grid.state_at(point[0], point[1])


def position_moves(
    state: ServiceState, session: LiveSession, body: PositionsIn
) -> tuple[IntArray, IntArray, IntArray] | None:
    """The moves ``body``'s readings walk from the session's cell (None: none); BadInput for
    a wall, a point off the map or a jump too far."""
    grid = session.domain.domain
    if grid.frame is None:
        raise BadInput(
            f"domain {session.domain.name!r} has no resolution: send events with cells, or PUT "
            "the domain with resolution (and origin) to send positions in metres"
        )
    limit, most = state.settings.max_jump, state.settings.max_batch_events
    here = session.position
    visited: list[int] = [here]
    for i, point in enumerate(body.positions):
        x, y = point[:2]
        try:
            target = point_state(grid, point)
        except ValueError as exc:
            raise BadInput(f"positions[{i}]: {exc}") from None
        walk = walked_cells(grid, here, target, limit)
        if walk is None:
            raise BadInput(
                f"positions[{i}]: ({x:g}, {y:g}) m is cell {list(grid.cell(target))}, more "
                f"than {limit} moves from the last cell {list(grid.cell(here))}: a jump this "
                "far is refused "
                "(send the readings in between, or start a new session)"
            )
        visited.extend(walk)
        here = target
        if len(visited) - 1 > most:
            raise BadInput(f"too many moves: the positions walk more than {most} in one batch", 413)
    if len(visited) == 1:
        return None
    s = np.array(visited[:-1], dtype=np.int64)
    s2 = np.array(visited[1:], dtype=np.int64)
    a = np.argmax(grid.next_state[s] == s2[:, None], axis=1).astype(np.int64)
    return s, a, s2


def put_domain(state: ServiceState, name: str, body: DomainPut) -> tuple[DomainState, bool, bool]:
    """*Worker thread.* Create or replace a domain: (state, created, kept_data). With
    ``experts``, a domain whose prior is empty after the put learns it from simulated experts
    (made before the put, so a bad request changes nothing). What every strategy needs of it
    is built before the answer (:meth:`DomainCatalog.prepare_all`: a map whose needs would
    pass ``ADVISOR_MAX_DOMAIN_MEMORY`` is refused first), and what the event paths read of it
    (:func:`app.service.wire.warm.warm`), so that no session or event builds them."""
    old = state.catalog.find(name)
    grid: Domain | None = building_of(body, state.settings.max_map_cells, name)
    if grid is None:
        header, rows = map_of(body)  # rows, or a map file's text
        try:
            grid = state.catalog.parse_map(rows, name, header.frame, header.names)
        except MapError as exc:
            raise BadInput(f"map: {exc.below(header.lines)}") from None
        same = old is not None and grid.rows_text is old.domain.rows_text
        if old is not None and isinstance(old.domain, GridDomain) and same:
            share_lists(old.domain, grid)  # the same map in another frame
    goals, most = len(grid.goals), state.settings.max_goal_cells
    if goals * grid.n_states > most:
        raise BadInput(
            f"map: {goals} goals x {grid.n_states} free cells = {goals * grid.n_states}; this "
            f"service keeps per-goal tables (goal_aware, guide) for at most {most} "
            "(ADVISOR_MAX_GOAL_CELLS): fewer goals or a smaller map"
        )
    over = state.catalog.over_memory(grid, needed())
    if over is not None:
        raise BadInput(f"map: {over}: fewer goals or a smaller map")
    experts = None
    if body.experts is not None and not _keeps_data(state, name, grid):
        experts = simulated_experts(grid, body.experts, state.settings.max_expert_pairs)
    domain, created, kept = state.catalog.put(name, grid, body.alpha0, preparing=True)
    try:
        if body.experts is not None and domain.view.trajectories.get(POOLED, 0) == 0:
            if experts is None:  # the data it would have kept went meanwhile
                experts = simulated_experts(grid, body.experts, state.settings.max_expert_pairs)
            domain = state.catalog.add_trajectories(domain, experts)
            ingested(name, len(experts), sum(len(t.pairs) for t in experts))
    finally:  # published as being prepared: prepared whatever happened
        state.catalog.prepare_all(domain)  # with the event paths' texts and lists (wire.warm)
    return domain, created, kept


def _keeps_data(state: ServiceState, name: str, grid: Domain) -> bool:
    """Whether a put of ``grid`` as ``name`` keeps trajectories (the same map, with data)."""
    try:
        old = state.catalog.get(name)
    except DomainNotFound:
        return False
    same = old.domain.rows_text == grid.rows_text
    return same and old.view.trajectories.get(POOLED, 0) > 0


def simulated_experts(grid: Domain, experts: ExpertsIn, max_pairs: int) -> list[Trajectory]:
    """*Worker thread.* The experts' trajectories, each with its goal; BadInput when they
    would be more than ``max_pairs`` pairs (bounded before any is walked)."""
    n = experts.per_goal * len(grid.goals)
    dist = grid.distances_to(grid.start)
    if experts.source == "start":  # exact: each walk is a shortest path from the start
        bound = experts.per_goal * int(dist[list(grid.goals)].sum())
    else:  # from anywhere to a goal: at most twice the start's farthest distance
        bound = n * 2 * int(dist.max())
    bound = min(bound, n * EXPERT_MAX_STEPS)
    if bound > max_pairs:
        raise BadInput(
            f"experts: {n} walks of up to {bound} (state, action) pairs in all; this service "
            f"learns from at most {max_pairs} (fewer per_goal, or post trajectories)"
        )
    rng = np.random.default_rng(experts.seed)
    walks = expert_trajectories(grid, rng, experts.source, experts.per_goal)
    return [Trajectory(None, w.pairs, w.goal) for w in walks]


async def after_put(state: ServiceState, domain: DomainState, created: bool, kept: bool) -> None:
    """Sessions follow a domain whose map stayed; others end with their map. Other workers
    read it again from their next request that uses it."""
    if kept:
        await state.sessions.retable(domain)
    else:
        await state.sessions.end_domain(domain.name)
    await state.sessions.domain_changed(domain.name, domain.version, created or not kept)


async def let_go(held: list[Any]) -> None:
    """Empty ``held`` in a worker thread: what was only held there any more (a replaced or
    deleted domain's state, once its sessions have gone: a large map's tables, lists and
    guide map, hundreds of MB) is freed there, not on the event loop. The caller keeps no
    other reference to it."""
    await run_in_threadpool(held.clear)


async def after_delete(state: ServiceState, name: str, version: int) -> None:
    """A deleted domain's sessions end and its metric series go (``version``: its last data
    version: other workers see one above it, and that it is gone)."""
    await state.sessions.end_domain(name)
    await state.sessions.domain_changed(name, version + 1, True)
    METRICS.forget_domain(name)


def ingest(
    state: ServiceState, domain: DomainState, raw: bytes
) -> tuple[TrajectoriesAccepted, DomainState]:
    """*Worker thread.* Parse, check and durably store trajectories; update the prior. Returns
    the answer and the domain state they went to (``domain``, or the same map put again
    meanwhile)."""
    body = parse_trajectories(raw)
    items = to_trajectories(domain.domain, body, state.settings.max_trajectory_steps)
    domain = state.catalog.add_trajectories(domain, items)  # the same map put again: its state
    warm(domain)  # its new tables' texts
    accepted = TrajectoriesAccepted(accepted=len(items), pairs=sum(len(t.pairs) for t in items))
    ingested(domain.name, accepted.accepted, accepted.pairs)
    return accepted, domain


def overview(
    state: ServiceState, role: str | None, aggregates: dict[str, Aggregate],
    sessions: list[SessionSnapshot],
) -> bytes:  # fmt: skip
    """*Worker thread.* ``GET /overview``: per domain its figures over its live sessions; with
    a ``role`` (the admin or the operator key) also the most recently active sessions, where
    each is and was (``sessions``, read by the route), and the role, which the dashboard reads
    to know what the key may do."""
    return orjson.dumps({
        "detail": role is not None,
        "role": role,
        "domains": [overview_domain(d, aggregates.get(d.name)) for d in state.catalog.states()],
        "total_sessions": sum(a.sessions for a in aggregates.values()),
        "sessions": [overview_session(s) for s in sessions],
    })  # fmt: skip


#: Sessions handed to the viewer per snapshot at most (the most recently active).
VIEWER_SESSIONS = 64


async def viewer_snapshot(state: ServiceState) -> bytes:
    """``GET /viewer/snapshot``: what the viewer draws now, as JSON (``ViewerSnapshot``; the
    sessions' copies made in a worker thread)."""
    domains = [
        {"name": d.name, "updated_at": d.updated_at, "prior_version": d.view.version}
        for d in state.catalog.states()
    ]
    sessions = [viewer_session(s) for s in await state.sessions.snapshot(VIEWER_SESSIONS)]
    highest = [e.kappa_max for e in strategies.STRATEGIES.values() if e.kappa_max is not None]
    return orjson.dumps({"domains": domains, "sessions": sessions, "kappa_max": max(highest)})
