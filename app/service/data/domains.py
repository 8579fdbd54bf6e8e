"""Domains in memory: each map with its action prior and the advice tables sessions read.

The store is the source of truth; this catalog mirrors it. Writers (put, delete, new
trajectories) run in worker threads, hold the domain's lock, commit to the store first and only
then change memory, so memory never holds data the database does not. Readers on the event loop
take :attr:`DomainState.view`, an immutable snapshot replaced in one assignment.

What the strategies need of a domain besides its prior (the goal priors, a guide map) is built
when the domain is made or changed, not when a session asks for it
(:meth:`DomainCatalog.prepare_all`): in the worker thread of an admin's PUT, when a worker reads
another worker's change (:meth:`DomainCatalog.refresh`) and at start (:meth:`DomainCatalog.load`);
what it keeps is bounded per domain (:func:`preparation_bytes`, ``ADVISOR_MAX_DOMAIN_MEMORY``).
Its searches are compiled without the GIL (``kernels.guide_distances``,
``kernels.guide_detours``), so the event loop runs while they do.
"""

from __future__ import annotations

import itertools
import logging
import threading
from collections.abc import Callable, Iterable, Mapping, Sequence
from contextlib import nullcontext
from dataclasses import dataclass, field
from datetime import datetime

import numpy as np

from app import kernels, strategies
from app.advice.guide import MAX_LEAD_CELLS, GuideMap, Leads, marks_for
from app.advice.models import AdviceTables
from app.advice.priors import ActionPrior, GoalPriors
from app.arrays import ByteArray, IntArray
from app.domain.building import Domain, load_map, n_floors
from app.domain.grid import Frame, GridDomain, MapError, NamedCell, name_goals
from app.service.config import SERVICE_LEAD_CELLS
from app.service.data.store import POOLED, DomainRecord, Store, TableCounts, Trajectory
from app.strategies import DomainData, Need, compiled_leads

log = logging.getLogger("app.service")


class DomainNotFound(KeyError):
    """No domain of that name."""


class DomainChanged(RuntimeError):
    """The domain's map was replaced by another while trajectories for it were in flight."""


_versions = itertools.count(1)


@dataclass(frozen=True)
class PriorView:
    """What sessions and readers use of a prior: its tables (pooled ``"*"`` plus every agent
    type with data) and trajectory counts. Replaced whole, never changed; ``version`` goes up
    with every view made, so a reader elsewhere (the viewer) knows when to fetch it again."""

    alpha0: float
    tables: Mapping[str, AdviceTables]
    trajectories: Mapping[str, int]
    version: int = field(default_factory=lambda: next(_versions))

    def resolve(self, agent_type: str | None) -> str:
        """The table serving ``agent_type``: its own if it has data, else the pooled one."""
        return agent_type if agent_type is not None and agent_type in self.tables else POOLED


def restore_prior(alpha0: float, domain: Domain, tables: Mapping[str, TableCounts]) -> ActionPrior:
    """An :class:`ActionPrior` of ``domain``'s states and actions holding the stored counts."""
    stored = {key: (t.n_trajectories, t.counts) for key, t in tables.items()}
    return ActionPrior.from_counts(alpha0, stored, domain.n_states, n_actions=domain.n_actions)


def _view(prior: ActionPrior, old: PriorView | None, changed: set[str]) -> PriorView:
    """A new view: tables of ``changed`` (and new) keys rebuilt, the others reused."""
    tables: dict[str, AdviceTables] = {}
    for key in [POOLED, *(t for t in prior.agent_types if prior.n_trajectories_.get(t, 0) > 0)]:
        reuse = old is not None and key in old.tables and key not in changed
        tables[key] = old.tables[key] if old and reuse else AdviceTables.paper(prior.theta(key))
    return PriorView(float(prior.alpha0), tables, dict(prior.n_trajectories_))  # type: ignore[arg-type]


@dataclass(eq=False)
class DomainState:
    """One live domain: the grid, its prior, the current :class:`PriorView`."""

    name: str
    domain: Domain
    prior: ActionPrior
    created_at: datetime
    updated_at: datetime
    lock: threading.Lock = field(default_factory=threading.Lock)
    # held while the guide map's distances are computed (seconds on a map with many
    # destinations), so that ingestion, which takes ``lock``, does not wait for them
    guide_lock: threading.Lock = field(default_factory=threading.Lock)
    view: PriorView = field(init=False)
    # per-goal counts for goal-aware sessions: built from the stored trajectories when the
    # domain is prepared (DomainCatalog.prepare_all), then kept up to date (replaced whole,
    # never changed)
    goal_priors: GoalPriors | None = None
    # guide sessions: distances to every destination, with the experts' counts of
    # ``goal_priors``; built with them when the domain is prepared
    guide_map: GuideMap | None = None
    version: int = 0  # the store's data version this state holds (store.py)
    # what cannot be built for this domain, and why (its map cannot have it, or it would pass
    # the per-domain memory limit): sessions that need it are refused with the reason
    refused: dict[Need, str] = field(default_factory=dict)
    # :meth:`DomainCatalog.prepare_all` is building what the strategies need, or is about to
    # (a state published by a PUT or a refresh, prepared next by the same thread)
    preparing: bool = False

    def __post_init__(self) -> None:
        self.view = _view(self.prior, None, set())

    @property
    def map_text(self) -> str:
        return self.domain.to_text()

    def data(self, table_key: str) -> DomainData:
        """What an advisor reads of this domain: the tables of ``table_key`` (a key of the
        current view) and what strategies need, as far as it is built."""
        return DomainData(self.view.tables[table_key], self.goal_priors, self.guide_map)


def needed() -> frozenset[Need]:
    """What the registered strategies need of a domain, together (a guide map is made with
    the goal priors)."""
    needs = frozenset(n for e in strategies.STRATEGIES.values() for n in e.needs)
    return needs | {Need.GOAL_PRIORS} if Need.GUIDE_MAP in needs else needs


def preparation_bytes(
    n_goals: int, n_states: int, needs: Iterable[Need], n_actions: int = 4, n_floors: int = 1,
    lead_cells: int = SERVICE_LEAD_CELLS,
) -> int:  # fmt: skip
    """Bytes what ``needs`` keep of a domain of ``n_goals`` destinations, ``n_states`` free
    cells, ``n_actions`` actions (A) and ``n_floors`` floors: the goal priors' counts and
    each goal's log theta (G x S x A float64 each), the counts of unknown goal (S x A) and
    the goal of each state (S); a guide map's distances and detours (G x S int64 each) and
    compass moves (G x S bytes), its landmarks' distances (``marks_for`` x S int64), its open
    moves (S int64, S x A booleans) and the destination of each state (S), on a map of several
    floors each state's floor and nearest stops (3 S int64), and its lead values (G x S x 4
    float32) while G x S is at most ``lead_cells`` (``ADVISOR_LEAD_CELLS``, and MAX_LEAD_CELLS);
    its counts are the goal priors' own."""
    gs, s, a = n_goals * n_states, n_states, n_actions
    most = min(lead_cells, MAX_LEAD_CELLS)
    floors = 24 * s if a != 4 else 0
    marks = marks_for(n_states, n_floors)
    sizes = {
        Need.GOAL_PRIORS: 16 * a * gs + (8 * a + 8) * s,
        Need.GUIDE_MAP: (17 + (16 if gs <= most else 0)) * gs + (16 + a + 8 * marks) * s + floors,
    }
    return sum(sizes[n] for n in set(needs))


def service_leads(domain: Domain, most: int = SERVICE_LEAD_CELLS) -> Leads | None:
    """How the service makes ``domain``'s lead values (``GuideMap.of``'s ``leads``): compiled
    while destinations x cells is at most ``most`` (``ADVISOR_LEAD_CELLS``), else None (none:
    its walkers that keep a heading are led where their next move loses ground)."""
    return compiled_leads if len(domain.goals) * domain.n_states <= most else None


def compiled_searches(
    next_state: IntArray, cells: IntArray, goals: tuple[int, ...], stops: IntArray | None = None
) -> tuple[IntArray, IntArray, ByteArray]:
    """A guide map's searches (``GuideMap.of``'s ``searches``), compiled without the GIL:
    the numbers of ``GridDomain.goal_distances``, ``compass_detours_each`` and
    ``guide.compass_table``; in a building (``stops``: ``Building.nearest_stops``), of
    ``bfs_distances_each`` over every action and ``compass_detours_each`` with the
    building's compass (``Building.compass_takes``)."""
    targets = np.array(goals, dtype=np.int64)
    dist = kernels.guide_distances(next_state, targets)
    on = np.zeros((0, 2), dtype=np.int64) if stops is None else stops
    detour = kernels.guide_detours(next_state, cells, targets, on)
    return dist, detour, kernels.guide_compass_table(next_state, cells, targets, on)


class DomainCatalog:
    """Every domain by name, kept equal to what the store holds. ``max_memory``: the most
    bytes what the strategies need of one domain may keep (:func:`preparation_bytes`; None:
    no limit); ``ready``: what else to make of a domain once prepared, in the same thread
    (the service's: what the event paths read of it, :func:`app.service.wire.warm.warm`);
    ``lead_cells``: guide's lead values for a map of at most that many destinations x cells
    (:func:`service_leads`)."""

    def __init__(
        self, store: Store, max_cells: int, max_memory: int | None = None,
        ready: Callable[[DomainState], None] | None = None,
        lead_cells: int = SERVICE_LEAD_CELLS,
    ):  # fmt: skip
        self.store = store
        self.max_cells = max_cells
        self.max_memory = max_memory
        self.ready = ready
        self.lead_cells = lead_cells
        self._domains: dict[str, DomainState] = {}
        self._lock = threading.Lock()

    def load(self) -> None:
        """Read every domain and its counts from the store, and prepare each
        (:meth:`prepare_all`; at start, before any request)."""
        for rec in self.store.domains():
            domain = load_map(rec.map_text, name=rec.name)
            prior = restore_prior(rec.alpha0, domain, self.store.counts(rec.name))
            self._domains[rec.name] = DomainState(
                rec.name, domain, prior, rec.created_at, rec.updated_at, version=rec.version
            )
        for state in self.states():
            self.prepare_all(state)

    def states(self) -> list[DomainState]:
        """Every domain, by name."""
        return [d for _, d in sorted(self._domains.items())]

    def __len__(self) -> int:
        return len(self._domains)

    def find(self, name: str) -> DomainState | None:
        """The domain ``name``, or None."""
        return self._domains.get(name)

    def get(self, name: str) -> DomainState:
        try:
            return self._domains[name]
        except KeyError:
            raise DomainNotFound(name) from None

    def parse_map(
        self, rows: Sequence[str], name: str, frame: Frame | None = None,
        names: Sequence[NamedCell] = (),
    ) -> GridDomain:  # fmt: skip
        """A validated grid (with its destinations' ``names``); :class:`MapError` names the
        problem (line and column). The map domain ``name`` holds (rows that read as its rows)
        is that grid in ``frame`` with these names (:meth:`GridDomain.with_frame`,
        :meth:`GridDomain.with_names`), not read again."""
        if len(rows) * max((len(r) for r in rows), default=0) > self.max_cells:
            raise MapError(f"the map is larger than {self.max_cells} cells")
        old = self._domains.get(name)
        if old is not None and not isinstance(rows, str):
            cleaned = [str(r).rstrip() for r in rows]
            while cleaned and not cleaned[-1]:
                cleaned.pop()
            if isinstance(old.domain, GridDomain) and tuple(cleaned) == old.domain.rows_text:
                goal_names = name_goals(old.domain.rows_text, names)
                return old.domain.with_frame(frame).with_names(goal_names)
        return GridDomain.from_strings(rows, name=name, frame=frame, names=names)

    def put(
        self, name: str, domain: Domain, alpha0: float, preparing: bool = False
    ) -> tuple[DomainState, bool, bool]:
        """Create or replace ``name`` (store first); returns (state, created, kept_data): the
        same map keeps its trajectories and counts, a new map starts with none. ``preparing``:
        the caller prepares the state next (:meth:`prepare_all`), so it is published as being
        prepared."""
        with self._lock:
            old = self._domains.get(name)
            with old.lock if old else nullcontext():
                rec, created, kept = self.store.put_domain(name, domain.to_text(), alpha0)
                state = self._state(rec, domain, old if old and kept else None)
                state.preparing = preparing
                self._domains[name] = state
        return state, created, kept

    @staticmethod
    def _state(rec: DomainRecord, domain: Domain, keep: DomainState | None) -> DomainState:
        """The state of a put domain; ``keep``: the old state whose counts it keeps."""
        stored = keep.prior.stored_counts() if keep is not None else {}
        prior = ActionPrior.from_counts(
            rec.alpha0, stored, domain.n_states, n_actions=domain.n_actions
        )
        goals = keep.goal_priors if keep is not None else None
        guide = None
        if goals is not None:
            goals = goals.copy(alpha0=rec.alpha0)
            goals.arrays()  # built here, in the worker thread, not at a session's first event
            if keep is not None and keep.guide_map is not None:  # the same map: same distances
                guide = keep.guide_map.replace_counts(goals)
        return DomainState(
            rec.name,
            domain,
            prior,
            rec.created_at,
            rec.updated_at,
            goal_priors=goals,
            guide_map=guide,
            version=rec.version,
        )

    def goal_priors(self, state: DomainState) -> GoalPriors:
        """*Worker thread* the first time (reads every stored trajectory of the domain).

        Counts per goal of the map, from the trajectories whose ``goal`` is that goal's cell;
        trajectories of unknown goal (or of a cell that is not a goal) count for every goal."""
        with state.lock:
            if state.goal_priors is None:
                grid = state.domain
                priors = GoalPriors(grid.n_states, grid.goals, state.view.alpha0, grid.n_actions)
                state.goal_priors = add_goals(priors, self.store.trajectories(state.name))
            return state.goal_priors

    def guide_map(self, state: DomainState) -> GuideMap:
        """*Worker thread* the first time: the goal priors (:meth:`goal_priors`) and a BFS
        from every destination (compiled, without the GIL: :func:`compiled_searches`).
        :class:`GuideError` says why a map cannot be guided."""
        self.goal_priors(state)
        with state.guide_lock:  # one build at a time; ingestion goes on meanwhile
            plain = (
                None
                if state.guide_map is not None
                else GuideMap.of(
                    state.domain,
                    searches=compiled_searches,
                    distances=kernels.guide_distances,
                    leads=service_leads(state.domain, self.lead_cells),
                )
            )
            with state.lock:  # the counts as they are now (ingestion may have added)
                if state.guide_map is None:
                    assert plain is not None and state.goal_priors is not None
                    state.guide_map = plain.replace_counts(state.goal_priors)
                return state.guide_map

    def prepare(self, state: DomainState, needs: Iterable[Need]) -> None:
        """*Worker thread* the first time: build what a strategy ``needs`` of ``state``
        (ValueError, such as :class:`GuideError`, says why a map cannot have it, or why
        :meth:`prepare_all` did not build it: ``state.refused``, the memory limit included).
        A domain is prepared when made or changed (:meth:`prepare_all`): this builds only
        what is still missing, for callers that need it there and then."""
        for need in needs:
            if need in state.refused:
                raise ValueError(state.refused[need])
            self._builders[need](state)

    @property
    def _builders(self) -> dict[Need, Callable[[DomainState], object]]:
        return {Need.GOAL_PRIORS: self.goal_priors, Need.GUIDE_MAP: self.guide_map}

    def over_memory(self, grid: Domain, needs: Iterable[Need]) -> str | None:
        """Why what ``needs`` keep of ``grid`` is more than this catalog allows a domain
        (None: it is not)."""
        needs = set(needs)
        size = preparation_bytes(
            len(grid.goals), grid.n_states, needs, grid.n_actions, n_floors(grid), self.lead_cells
        )
        if not needs or self.max_memory is None or size <= self.max_memory:
            return None
        what = ", ".join(sorted(n.value for n in needs))
        return (
            f"{len(grid.goals)} goals x {grid.n_states} free cells: {what} would take "
            f"{size} bytes, more than this service keeps for a domain ({self.max_memory}, "
            "ADVISOR_MAX_DOMAIN_MEMORY)"
        )

    def prepare_all(self, state: DomainState) -> None:
        """*Worker thread.* Build what every registered strategy needs of ``state``
        (:func:`needed`), when a domain is made or changed (a PUT, another worker's change,
        the start) and not when a session asks for it, then what :attr:`ready` makes; what
        cannot be built (a map that cannot be guided, more than ``max_memory``) is kept in
        ``state.refused`` with why."""
        needs = needed()
        state.preparing = True
        try:
            over = self.over_memory(state.domain, needs)
            for need in sorted(needs, key=lambda n: n.name):
                if over is not None:
                    state.refused[need] = over
                    continue
                try:
                    self._builders[need](state)
                except (ValueError, MemoryError) as exc:  # GuideError: it cannot have it
                    state.refused[need] = str(exc) or type(exc).__name__
                    log.warning("domain %r: %s not built: %s", state.name, need.value, exc)
            if self.ready is not None:
                self.ready(state)
        finally:
            state.preparing = False

    def delete(self, name: str) -> None:
        with self._lock:
            state = self.get(name)
            with state.lock:
                self.store.delete_domain(name)
                del self._domains[name]

    def add_trajectories(self, state: DomainState, items: Sequence[Trajectory]) -> DomainState:
        """Store ``items`` (checked against ``state``'s map) durably, then add them to the
        prior and publish a new view; returns the domain state they went to.

        If ``state`` was replaced meanwhile by a put of the same map (another alpha0 or
        frame), they go to the domain now of that name: its map is theirs. A put of another
        map refuses them (:class:`DomainChanged`), a delete too (:class:`DomainNotFound`).
        If another process (a worker sharing the store) changed the domain since ``state`` was
        read, the state returned is read again from the store (:meth:`refresh`)."""
        while True:
            with state.lock:
                current = self._domains.get(state.name)
                if current is state and self._add(state, items):
                    return state
            if current is state:  # stored after others' changes that this state lacks
                now = self.refresh(state.name)
                if now is None:
                    raise DomainNotFound(state.name)
                return now
            if current is None:
                raise DomainNotFound(state.name)
            if current.domain.rows_text != state.domain.rows_text:
                raise DomainChanged(state.name)
            state = current  # the same map, put again: the trajectories fit it as they are

    def _add(self, state: DomainState, items: Sequence[Trajectory]) -> bool:
        """Under ``state.lock``, ``state`` being the current domain of its name: store ``items``
        and add them to ``state`` (True), or, when the store's data version shows changes by
        another process that ``state`` lacks, only store them (False: read it again)."""
        grid = state.domain
        version = self.store.add_trajectories(state.name, items, grid.n_states, grid.n_actions)
        if version != state.version + 1:
            return False
        state.version = version
        groups: dict[str | None, list[Trajectory]] = {}
        for t in items:
            groups.setdefault(t.agent_type, []).append(t)
        for agent_type, group in groups.items():
            state.prior.partial_fit([t.pairs for t in group], agent_type=agent_type)
        changed = {POOLED, *(t for t in groups if t is not None)}
        state.view = _view(state.prior, state.view, changed)
        if state.goal_priors is not None:
            state.goal_priors = add_goals(state.goal_priors.copy(), items)
            if state.guide_map is not None:
                state.guide_map = state.guide_map.replace_counts(state.goal_priors)
        return True

    def refresh(self, name: str) -> DomainState | None:
        """*Worker thread.* The domain ``name`` as the store holds it now, for a process that
        shares the store with others (workers): the state held if its data version is the
        store's, else a new state read from the store (its counts as of one data version; the
        goal priors and guide map carried over, with the trajectories added since, when the
        map is the same one, else built: :meth:`prepare_all`); None, and dropped, when the
        domain is gone. The caller moves
        the live sessions: to a new state of the same map (``retable``), or ends them."""
        with self._lock:
            old = self._domains.get(name)
            with old.lock if old is not None else nullcontext():
                new = self._reload(name, old)
        if new is not None and new is not old:  # outside the catalog's lock: other domains
            self.prepare_all(new)  # go on; its own sessions wait for this refresh
        return new

    def _reload(self, name: str, old: DomainState | None) -> DomainState | None:
        snap = self.store.snapshot(name, None if old is None else old.version)
        if snap is None:
            self._domains.pop(name, None)
            return None
        rec, counts, added = snap
        if old is not None and old.version == rec.version:
            return old
        if old is not None and old.created_at == rec.created_at and old.map_text == rec.map_text:
            grid = old.domain  # the same map (and frame): not read again
        else:
            grid = load_map(rec.map_text, name=name)
        prior = restore_prior(rec.alpha0, grid, counts)
        goals, guide = None, None
        if old is not None and old.goal_priors is not None and same_map(old, rec, grid):
            goals = add_goals(old.goal_priors.copy(alpha0=rec.alpha0), added)
            if old.guide_map is not None:  # the same map: the same distances
                guide = old.guide_map.replace_counts(goals)
        state = DomainState(
            name, grid, prior, rec.created_at, rec.updated_at, goal_priors=goals,
            guide_map=guide, version=rec.version, preparing=True,  # refresh prepares it next
        )  # fmt: skip
        self._domains[name] = state
        return state

    def sync(self, versions: Mapping[str, int] | None = None) -> list[DomainState]:
        """*Worker thread.* Every domain as the store holds it now (``versions``: their data
        versions by name, if the caller read them): the states that changed (new or read
        again; a deleted one as it was)."""
        versions = self.store.versions() if versions is None else versions
        changed: list[DomainState] = []
        for name in sorted(set(versions) | set(self._domains)):
            old = self._domains.get(name)
            if old is not None and versions.get(name) == old.version:
                continue
            new = self.refresh(name)
            if new is not None and new is not old:
                changed.append(new)
            elif new is None and old is not None:
                changed.append(old)
        return changed


def same_map(state: DomainState, rec: DomainRecord, grid: Domain) -> bool:
    """Whether ``rec`` (read as ``grid``) is the map ``state`` holds, not a new domain of the
    same name (made after a delete) or another map: the states are the same cells."""
    return state.created_at == rec.created_at and state.domain.rows_text == grid.rows_text


def add_goals(priors: GoalPriors, items: Sequence[Trajectory]) -> GoalPriors:
    """``priors`` with ``items`` added under the goals they ended at (if one of the map's),
    and the tables sessions share built (this runs in a worker thread, not on the loop)."""
    goal_index = [priors.goal_index.get(t.goal) if t.goal is not None else None for t in items]
    priors.add([t.pairs for t in items], goal_index)
    priors.arrays()
    return priors
