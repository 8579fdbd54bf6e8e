"""Buildings of several floors: a domain whose cells are ``[floor, row, col]``.

A :class:`Building` is made of floors of the same rows and columns (:class:`~app.domain.floors.
Floor`: an ordinal, a name, maybe an elevation, a one-floor map's rows), the connections
between them (:class:`~app.domain.floors.Connection`: stairs, lifts, escalators, ramps), the
destinations' names and the grid's frame; its text is :mod:`app.domain.floors`'. A map of one
floor stays a :class:`~app.domain.grid.GridDomain`; :func:`load_map` reads either.

States are the free cells of every floor, floor by floor in the floors' order, row-major within
a floor; ``cells[s]`` is ``(floor, row, col)`` with ``floor`` the floor's index (0 the lowest
floor of the map, whatever its ordinal). Actions are six (0..5)::

    N E S W   the compass moves within the floor, as on a one-floor map (a move into a wall or
              off the map leaves the explorer in place)
    U         at a stop of a connection: to that connection's next stop above (its stop on the
              nearest floor above that it serves); anywhere else, or at its top stop, the
              explorer stays in place, as a wall leaves it
    D         the same downwards

so the dynamics is one precomputed table ``next_state[s, a]`` (S x 6), deterministic.

Time. A step is one action; every action takes one move of time but a ride: a U or D that
changes floor takes ``COST x k`` moves, ``COST`` the connection's cost (moves of time per floor
travelled, from the map) and ``k`` the floors travelled, the difference of the two floors'
ordinals (the storeys climbed, any the map leaves out included). So an explorer riding a lift of
cost 5 from ordinal 0 to ordinal 3, stopping at each floor, takes 3 actions and spends 15 moves
of time. ``durations[s, a]`` holds every action's time (S x 6; a U or D that stays takes 1, as a
bump into a wall does); ``rides`` lists every ride up (its lower and upper state, its time, its
connection: each ride down is one of them reversed, at the same time). What an advisor makes of
a ride, and how an experiment's budget counts it, is for them to say; the map carries the time.

Limits (a file cannot make the domain large): :data:`~app.domain.floors.MAX_FLOORS` floors,
:data:`MAX_CELLS` cells (floors x rows x columns, checked before any array is made),
:data:`~app.domain.floors.MAX_CONNECTIONS` connections, each with at most one stop a floor.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property
from itertools import pairwise
from pathlib import Path
from typing import Any

import numpy as np

from app.arrays import BoolArray, IntArray
from app.domain.floors import (
    KINDS,
    MAX_CONNECTIONS,
    MAX_ELEVATION,
    MAX_FLOORS,
    MAX_ORDINAL,
    MAX_RIDE_COST,
    Connection,
    Floor,
    FloorName,
    floors_text,
    is_floors_text,
    order_problem,
    read_floors,
)
from app.domain.grid import (
    GOAL,
    START,
    UNREACHABLE,
    WALL,
    Frame,
    GridDomain,
    MapError,
    NamedCell,
    Placed,
    bfs_distances,
    check_rows,
    compass_takes,
    moves_table,
    name_problem,
    names_in_order,
    read_map_text,
)

ACTIONS: tuple[str, ...] = ("N", "E", "S", "W", "U", "D")
N_ACTIONS = 6
U, D = 4, 5
#: the most cells (floors x rows x columns) a building has: its tables cost about 150 bytes
#: a free cell (next_state, durations, cells, distances), 300 MiB at most
MAX_CELLS = 1 << 21


@dataclass(frozen=True, eq=False)
class Building:
    """A building D = (S, A, T): floors, the connections between them, the destinations.

    Build it with :meth:`from_parts`, :meth:`from_text` or :meth:`from_file`, which check it
    (the constructor takes parts already checked). Frozen; its arrays are read-only."""

    floors: tuple[Floor, ...]
    connections: tuple[Connection, ...] = ()
    name: str = "building"
    frame: Frame | None = None
    #: each goal's name (in the order of ``goals``; None: unnamed), None when none has one
    goal_names: tuple[str | None, ...] | None = None
    walls: BoolArray = field(init=False, repr=False)  # (floors, rows, cols)
    state_of: IntArray = field(init=False, repr=False)  # (floors, rows, cols), -1 walls
    cells: IntArray = field(init=False, repr=False)  # (S, 3): floor, row, col
    next_state: IntArray = field(init=False, repr=False)  # (S, 6)
    #: (K, 4): each ride up between two stops next to each other on a connection: the lower
    #: state, the upper state, its moves of time, the connection's index
    rides: IntArray = field(init=False, repr=False)
    #: the index of the connection each state is a stop of (-1: none)
    connection_of: IntArray = field(init=False, repr=False)
    start: int = field(init=False)
    goals: tuple[int, ...] = field(init=False)

    def __post_init__(self) -> None:
        n, (rows, cols) = len(self.floors), (len(self.floors[0].rows), len(self.floors[0].rows[0]))
        text = "".join(r for f in self.floors for r in f.rows).encode("ascii")
        grid = np.frombuffer(text, dtype=np.uint8).reshape(n, rows, cols)
        walls = grid == ord(WALL)
        state_of = np.full(walls.shape, -1, dtype=np.int64)
        cells, moves = [], []
        offset = 0
        for f in range(n):
            s_of, c2, ns = moves_table(walls[f])
            state_of[f] = np.where(s_of >= 0, s_of + offset, -1)
            cells.append(np.column_stack((np.full(len(c2), f, dtype=np.int64), c2)))
            moves.append(ns + offset)
            offset += len(c2)
        stay = np.arange(offset, dtype=np.int64)[:, None]
        next_state = np.hstack([np.concatenate(moves), stay, stay])
        rides, connection_of = _rides(self.floors, self.connections, state_of, offset)
        next_state[rides[:, 0], U] = rides[:, 1]
        next_state[rides[:, 1], D] = rides[:, 0]
        for name, value in (
            ("walls", walls),
            ("state_of", state_of),
            ("cells", np.concatenate(cells)),
            ("next_state", next_state),
            ("rides", rides),
            ("connection_of", connection_of),
        ):
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        object.__setattr__(self, "start", int(state_of[grid == ord(START)][0]))
        object.__setattr__(self, "goals", tuple(int(s) for s in state_of[grid == ord(GOAL)]))
        if self.goal_names is not None and len(self.goal_names) != len(self.goals):
            raise ValueError(f"{len(self.goal_names)} goal names for {len(self.goals)} goals")

    # ---- construction -------------------------------------------------------------------
    @classmethod
    def from_parts(
        cls,
        floors: Sequence[Floor],
        connections: Sequence[Connection] = (),
        names: Sequence[FloorName] = (),
        frame: Frame | None = None,
        name: str = "building",
    ) -> Building:
        """Check the parts (every rule of :mod:`app.domain.floors`; :class:`MapError` names the
        floor, line and column where the parts say where they were written) and build it."""
        checked = _check_floors(floors)
        joined = _check_connections(checked, connections)
        goal_names = _name_goals(checked, names)
        building = cls(checked, joined, name=name, frame=frame, goal_names=goal_names)
        building._check_reachable()
        return building

    @classmethod
    def from_text(cls, text: str, name: str = "building") -> Building:
        """A map file's text of several floors (:mod:`app.domain.floors`)."""
        parts = read_floors(text)
        return cls.from_parts(parts.floors, parts.connections, parts.names, parts.frame, name)

    @classmethod
    def from_file(cls, path: str | Path, name: str | None = None) -> Building:
        p = Path(path)
        return cls.from_text(read_map_text(p), name=name or p.stem)

    def to_text(self) -> str:
        """The map file's text; :meth:`from_text` reads it back."""
        named = [
            (self.cell(g), goal_name)
            for g, goal_name in zip(self.goals, self.goal_names or (), strict=False)
            if goal_name is not None
        ]
        return floors_text(self.floors, self.connections, named, self.frame)

    # ---- shape --------------------------------------------------------------------------
    @property
    def actions(self) -> tuple[str, ...]:
        return ACTIONS

    @property
    def n_actions(self) -> int:
        return N_ACTIONS

    @property
    def n_floors(self) -> int:
        return len(self.floors)

    @property
    def shape(self) -> tuple[int, int, int]:
        """(floors, rows, cols)."""
        return (len(self.floors), len(self.floors[0].rows), len(self.floors[0].rows[0]))

    @property
    def n_states(self) -> int:
        return int(self.cells.shape[0])

    def state(self, floor: int, row: int, col: int) -> int:
        """State index of a free cell (``floor``: the floor's index); ``ValueError`` for walls
        or cells off the map."""
        floors, rows, cols = self.shape
        if not (0 <= floor < floors and 0 <= row < rows and 0 <= col < cols):
            raise ValueError(f"cell [{floor}, {row}, {col}] is off the {floors}x{rows}x{cols} map")
        s = int(self.state_of[floor, row, col])
        if s < 0:
            raise ValueError(f"cell [{floor}, {row}, {col}] is a wall")
        return s

    @cached_property
    def rows_text(self) -> tuple[str, ...]:
        """Which map this is, as a one-floor map's rows say it: each floor's index and rows,
        then each connection's kind, cost and stops (not the floors' names and elevations, the
        destinations' names or the frame: the same states and moves, however they are named).
        A service keeps a domain's data over a PUT of the map of the same ``rows_text``."""
        out: list[str] = []
        for f, floor in enumerate(self.floors):
            out += [f"floor {f}", *floor.rows]
        for c in self.connections:
            stops = " ".join(f"{f}:{r},{col}" for f, r, col in c.stops)
            out.append(f"{c.kind} {c.cost} {stops}")
        return tuple(out)

    @property
    def width(self) -> int:
        """A cell's coordinates: 3, ``[floor, row, col]``."""
        return 3

    def cell(self, state: int) -> tuple[int, int, int]:
        """(floor, row, col) of ``state``."""
        f, r, c = self.cells[state]
        return int(f), int(r), int(c)

    def state_at(self, floor: int, x: float, y: float) -> int:
        """The state holding the point (x, y) in metres on floor ``floor`` (its index);
        ``ValueError`` if the map has no frame or the point is in a wall or off the map."""
        if self.frame is None:
            raise ValueError(f"domain {self.name!r} has no resolution and origin: send cells")
        row, col = self.frame.cell_at(x, y, self.shape[1])
        try:
            return self.state(floor, row, col)
        except ValueError as exc:
            raise ValueError(f"position ({x:g}, {y:g}) m: {exc}") from None

    def step(self, state: int, action: int) -> int:
        return int(self.next_state[state, action])

    @property
    def goal_cells(self) -> list[tuple[int, int, int]]:
        """Each goal's (floor, row, col), in the order of ``goals``."""
        return [self.cell(g) for g in self.goals]

    def goal_label(self, index: int) -> str:
        """Goal ``index``'s name, else ``G<index>``."""
        named = self.goal_names[index] if self.goal_names is not None else None
        return named if named is not None else f"G{index}"

    @cached_property
    def open_moves(self) -> BoolArray:
        """``open_moves[s, a]``: action ``a`` leaves ``s`` (a compass move not into a wall, a
        ride from a stop with a stop above or below)."""
        out: BoolArray = self.next_state != np.arange(self.n_states)[:, None]
        out.setflags(write=False)
        return out

    # ---- time and distance --------------------------------------------------------------
    @cached_property
    def durations(self) -> IntArray:
        """``durations[s, a]``: the moves of time action ``a`` takes at ``s`` (1, or a ride's
        ``COST x k``: the module docstring)."""
        out = np.ones((self.n_states, N_ACTIONS), dtype=np.int64)
        out[self.rides[:, 0], U] = self.rides[:, 2]
        out[self.rides[:, 1], D] = self.rides[:, 2]
        out.setflags(write=False)
        return out

    @cached_property
    def nearest_stops(self) -> IntArray:
        """``nearest_stops[s, k]``: the stop on ``s``'s floor nearest to it by row plus column
        difference (walls aside: as the crow flies on a grid, the way a sign to the lifts
        points) from which ``U`` (k = 0) or ``D`` (k = 1) leaves the floor; the lowest state
        on a tie, -1 where the floor has none. The bug's way to another floor
        (:mod:`app.agents.explorers`)."""
        out = np.full((self.n_states, 2), -1, dtype=np.int64)
        floor, rc = self.cells[:, 0], self.cells[:, 1:]
        for k, action in enumerate((U, D)):
            leaves = self.next_state[:, action] != np.arange(self.n_states)
            for f in range(self.n_floors):
                here = np.flatnonzero(floor == f)
                stops = here[leaves[here]]  # in state order: argmin keeps the lowest
                if stops.size == 0:
                    continue
                for lo in range(0, here.size, 512):  # 512 x stops (<= 4,096) a block
                    part = here[lo : lo + 512]
                    d = np.abs(rc[part, None, :] - rc[None, stops, :]).sum(axis=2)
                    out[part, k] = stops[np.argmin(d, axis=1)]
        out.setflags(write=False)
        return out

    @cached_property
    def rides_keep_cells(self) -> bool:
        """Whether every ride leaves the row and column as they were (every connection's
        stops stacked, as in a generated building): then a walk's row plus column difference
        is at most its moves."""
        lower, upper = self.rides[:, 0], self.rides[:, 1]
        return bool((self.cells[lower, 1:] == self.cells[upper, 1:]).all())

    def compass_aims(self, targets: IntArray, states: IntArray) -> tuple[IntArray, IntArray]:
        """For each pair (``targets[i]``, ``states[i]``), where someone at the state heading
        for the target as the crow flies makes for on its floor, and the ride it takes there:
        the target itself on the target's floor (no ride, -1); on another floor the nearest
        stop with a way towards the target's floor (:attr:`nearest_stops`; -1 where the
        floor has none) and, once on it, ``U`` or ``D``. The bug's rule
        (app/agents/explorers.py), as guide's compass model reads it."""
        there, here = self.cells[targets, 0], self.cells[states, 0]
        other = there != here
        k = np.where(there > here, 0, 1)
        aim = np.where(other, self.nearest_stops[states, k], targets)
        ride = np.where(other & (aim == states), U + k, -1)
        return aim, ride

    def compass_takes(self, targets: IntArray, states: IntArray, a: int) -> BoolArray:
        """For each pair, whether action ``a`` is one of the state's own moves towards the
        target (:meth:`compass_aims`): the ride at the stop it makes for, else the compass's
        moves on its floor towards where it makes for (:func:`~app.domain.grid.compass_takes`);
        none where its floor has no way towards the target's."""
        aim, ride = self.compass_aims(targets, states)
        if a >= U:
            out: BoolArray = ride == a
            return out
        walk = (ride < 0) & (aim >= 0)
        out = np.zeros(len(states), dtype=np.bool_)
        out[walk] = compass_takes(self.next_state, self.cells[:, 1:], aim[walk], states[walk], a)
        return out

    def distances_to(self, target: int | Iterable[int]) -> IntArray:
        """The fewest actions from every state to ``target`` (a state or several; -1: none)."""
        sources = [target] if isinstance(target, int | np.integer) else list(target)
        return bfs_distances(self.next_state, sources)

    def times_to(self, target: int | Iterable[int]) -> IntArray:
        """The fewest moves of time from every state to ``target`` (``durations``; -1: none)."""
        sources = [target] if isinstance(target, int | np.integer) else list(target)
        return time_distances(self.next_state, self.durations, sources)

    # ---- drawing ------------------------------------------------------------------------
    def render(self, floor: int, marks: dict[int, str] | None = None) -> str:
        """Floor ``floor``'s rows, with ``marks`` (state -> one character) of that floor drawn
        over its cells."""
        grid = [list(r) for r in self.floors[floor].rows]
        for s, ch in (marks or {}).items():
            f, r, c = self.cell(s)
            if f == floor:
                grid[r][c] = ch
        return "\n".join("".join(r) for r in grid)

    def _check_reachable(self) -> None:
        """Every free cell is reachable from the start (on its floor or by connections)."""
        dist = bfs_distances(self.next_state, [self.start])
        lost = np.flatnonzero(dist == UNREACHABLE)
        if lost.size:
            f, r, c = self.cell(int(lost[0]))
            what = "goal" if self.floors[f].rows[r][c] == GOAL else "free cell"
            raise _cell_error(
                self.floors, f, r, c,
                f"{what} unreachable from the start (every free cell must be joined to 'S', on "
                f"its floor or through the connections; {lost.size} are not)",
            )  # fmt: skip


def time_distances(next_state: IntArray, durations: IntArray, sources: Sequence[int]) -> IntArray:
    """The fewest moves of time from every state to the nearest source (-1 if none).

    Dial's shortest paths: the states found at time t are settled together, then each of their
    moves puts its end in the bucket of t plus its time. Every move is reversible at the same
    time (a compass move by the opposite one, a ride up by the ride down), so searching out from
    the sources gives the times *to* them."""
    n = next_state.shape[0]
    dist = np.full(n, UNREACHABLE, dtype=np.int64)
    buckets: dict[int, list[IntArray]] = {0: [np.asarray(sources, dtype=np.int64)]}
    while buckets:
        t = min(buckets)
        front = np.unique(np.concatenate(buckets.pop(t)))
        front = front[dist[front] == UNREACHABLE]
        if not front.size:
            continue
        dist[front] = t
        ends, times = next_state[front], durations[front]
        open_ = dist[ends] == UNREACHABLE
        for w in np.unique(times[open_]).tolist():
            buckets.setdefault(t + w, []).append(ends[open_ & (times == w)])
    return dist


#: a domain of either kind: one floor (four actions) or a building of several (six)
Domain = GridDomain | Building


def n_floors(domain: Domain) -> int:
    """The floors of ``domain`` (1: a one-floor map)."""
    return domain.n_floors if isinstance(domain, Building) else 1


def load_map(text: str, name: str = "maze") -> GridDomain | Building:
    """A map file's text as its domain: a :class:`Building` when it has ``floor:`` lines,
    else a :class:`~app.domain.grid.GridDomain`; :class:`MapError` names where it is wrong."""
    if is_floors_text(text):
        return Building.from_text(text, name=name)
    return GridDomain.from_text(text, name=name)


def load_map_file(path: str | Path, name: str | None = None) -> GridDomain | Building:
    """:func:`load_map` of a file (named by its stem unless ``name``)."""
    p = Path(path)
    return load_map(read_map_text(p), name=name or p.stem)


def domain_of(info: Mapping[str, Any], name: str) -> Domain:
    """The map a service describes (``GET /domains/{name}``'s answer, plain JSON data): a
    building where it has ``floors`` (:func:`building_of`), else a grid of its ``map`` rows
    with its destinations' names; both in its frame, when it has one. How a client of the
    service (the viewer, ``simulate``) walks the map the service serves."""
    if info.get("floors") is not None:
        return building_of(info, name)
    names = [
        NamedCell(int(cell[0]), int(cell[1]), given)
        for cell, given in zip(info["goals"], info.get("goal_names") or (), strict=False)
        if given is not None
    ]
    return GridDomain.from_strings(info["map"], name=name, frame=_frame_of(info), names=names)


def building_of(info: Mapping[str, Any], name: str) -> Building:
    """A building from its ``GET /domains/{name}`` answer: its floors (lowest first), its
    connections (stops ``[floor, row, col]``, floor the index), its goals' names (as
    ``destination:`` lines name them) and its frame, checked as a map text's parts are."""
    floors = [
        Floor(int(f["ordinal"]), f["name"], tuple(f["map"]), f["elevation"]) for f in info["floors"]
    ]
    connections = [
        Connection(
            c["kind"],
            int(c["cost"]),
            tuple((int(f), int(r), int(k)) for f, r, k in c["stops"]),
            c["name"],
        )
        for c in info["connections"]
    ]
    names = [
        FloorName(int(cell[0]), NamedCell(int(cell[1]), int(cell[2]), given))
        for cell, given in zip(info["goals"], info.get("goal_names") or (), strict=False)
        if given is not None
    ]
    return Building.from_parts(floors, connections, names, _frame_of(info), name)


def _frame_of(info: Mapping[str, Any]) -> Frame | None:
    resolution, origin = info.get("resolution"), info.get("origin")
    if resolution is None:
        return None
    return Frame(resolution, tuple(origin) if origin is not None else (0.0, 0.0, 0.0))


# ---- checks ---------------------------------------------------------------------------------
def _cell_error(floors: Sequence[Floor], f: int, r: int, c: int, message: str) -> MapError:
    """An error at a cell: the line and column of its floor's row when the floor was read
    from a text, else the cell itself in the message."""
    floor = floors[f]
    if floor.line is None:
        return MapError(f"cell [{f}, {r}, {c}]: {message}", floor=floor.label)
    return MapError(message, floor.line + 1 + r, c + 1, floor=floor.label)


def _check_floors(floors: Sequence[Floor]) -> tuple[Floor, ...]:
    """The floors with their rows checked (and cleaned: :func:`~app.domain.grid.check_rows`)."""
    if len(floors) < 2:
        line = floors[0].line if floors else None
        raise MapError(
            f"a map of several floors has two floors or more, this one has {len(floors)}: a "
            "one-floor map is written without floor: lines", line, None, True,
        )  # fmt: skip
    if len(floors) > MAX_FLOORS:
        raise MapError(f"{len(floors)} floors: a map has at most {MAX_FLOORS}")
    out: list[Floor] = []
    names: dict[str, Floor] = {}
    for k, floor in enumerate(floors):
        bad = _floor_problem(floor, floors[k - 1] if k else None, names)
        if bad is not None:
            raise MapError(bad, floor.line, None, True, floor=floor.label)
        names[floor.name.casefold()] = floor
        if not floor.rows:
            raise MapError(
                "a floor needs its rows after its floor: line", floor.line, None, True,
                floor=floor.label,
            )  # fmt: skip
        try:
            rows = check_rows(floor.rows)
        except MapError as exc:
            line = floor.line + exc.line if floor.line is not None and exc.line else None
            raise MapError(exc.message, line, exc.column, floor=floor.label) from None
        if out and (len(rows), len(rows[0])) != (len(out[0].rows), len(out[0].rows[0])):
            first = out[0]
            raise MapError(
                f"{len(rows)} rows of {len(rows[0])} where floor {first.label} has "
                f"{len(first.rows)} rows of {len(first.rows[0])}: every floor has the same rows "
                "and columns", floor.line, None, True, floor=floor.label,
            )  # fmt: skip
        if len(floors) * len(rows) * len(rows[0]) > MAX_CELLS:
            raise MapError(
                f"{len(floors)} floors of {len(rows)} x {len(rows[0])} cells: a map of several "
                f"floors holds at most {MAX_CELLS:,} cells (floors x rows x columns)"
            )
        out.append(replace(floor, rows=tuple(rows)))
    _check_marks(out)
    return tuple(out)


def _floor_problem(floor: Floor, below: Floor | None, names: dict[str, Floor]) -> str | None:
    """What is wrong with a floor's ordinal, name or elevation, or None."""
    if not -MAX_ORDINAL <= floor.ordinal <= MAX_ORDINAL:
        return f"ordinal {floor.ordinal}: an ordinal is from -{MAX_ORDINAL} to {MAX_ORDINAL}"
    if below is not None and order_problem(floor, below) is not None:
        return order_problem(floor, below)
    problem = name_problem(floor.name.strip(), "a floor's")
    if problem is not None or floor.name != floor.name.strip():
        return problem or f"the name {floor.name!r} has spaces around it"
    if floor.name.casefold() in names:
        return f"the name {floor.name!r} is given twice: each floor's name must be its own"
    e = floor.elevation
    if e is not None:
        if not (math.isfinite(e) and abs(e) <= MAX_ELEVATION):
            most = f"{MAX_ELEVATION:,.0f}"
            return f"elevation {e!r}: a height in metres from -{most} to {most}"
        low = below
        if low is not None and low.elevation is not None and e <= low.elevation:
            return (
                f"elevation {e:g} m is not above the floor below's ({low.elevation:g} m): "
                "elevations grow with the ordinals"
            )
    return None


def _marked(floors: Sequence[Floor], mark: str) -> list[tuple[int, int, int]]:
    """The cells marked ``mark`` (floor index, row, column), floor by floor, row-major."""
    return [
        (f, r, c)
        for f, floor in enumerate(floors)
        for r, row in enumerate(floor.rows)
        if mark in row
        for c, ch in enumerate(row)
        if ch == mark
    ]


def _check_marks(floors: Sequence[Floor]) -> None:
    """One start in the building, one goal or more."""
    starts = _marked(floors, START)
    if not starts:
        raise MapError("no start: mark exactly one cell of the building with 'S'")
    if len(starts) > 1:
        at = [_cell_error(floors, *cell, "") for cell in starts[:5]]
        where = "; ".join(str(e).removesuffix(": ") for e in at)
        more = f" and {len(starts) - 5} more" if len(starts) > 5 else ""
        raise MapError(
            f"{len(starts)} starts ({where}{more}): mark exactly one cell of the building with 'S'"
        )
    if not any(GOAL in row for floor in floors for row in floor.rows):
        raise MapError("no goal: mark at least one cell of the building with 'G'")


def _check_connections(
    floors: Sequence[Floor], connections: Sequence[Connection]
) -> tuple[Connection, ...]:
    """The connections checked, their stops in the order of the floors."""
    if len(connections) > MAX_CONNECTIONS:
        raise MapError(f"{len(connections)} connections: a map has at most {MAX_CONNECTIONS}")
    n, rows, cols = len(floors), len(floors[0].rows), len(floors[0].rows[0])
    taken: dict[tuple[int, int, int], Connection] = {}
    names: dict[str, Connection] = {}
    out = []
    for conn in connections:

        def error(message: str, k: int | None = None, c: Connection = conn) -> MapError:
            column = c.columns[k] if c.columns is not None and k is not None else None
            return MapError(f"connection {c.name!r}: {message}", c.line, column, True)

        if conn.kind not in KINDS:
            raise error(f"unknown kind {conn.kind!r}: a connection is one of {', '.join(KINDS)}")
        if not (isinstance(conn.cost, int) and 1 <= conn.cost <= MAX_RIDE_COST):
            raise error(f"cost {conn.cost!r}: moves of time per floor, from 1 to {MAX_RIDE_COST}")
        problem = name_problem(conn.name.strip(), "a connection's")
        if problem is not None or conn.name != conn.name.strip():
            problem = problem or f"the name {conn.name!r} has spaces around it"
            raise MapError(problem, conn.line, None, True)
        if conn.name.casefold() in names:
            first = names[conn.name.casefold()]
            said = f" (line {first.line} names it first)" if first.line is not None else ""
            raise error(f"the name is given twice{said}: each connection's name must be its own")
        names[conn.name.casefold()] = conn
        if len(conn.stops) < 2:
            raise error("a connection has two stops or more, on different floors")
        seen: set[int] = set()
        for k, (f, r, c) in enumerate(conn.stops):
            if not 0 <= f < n:
                raise error(f"stop on floor {f}: the map's floors are 0 to {n - 1}", k)
            on = f"on floor {floors[f].label}"
            if f in seen:
                raise error(f"two stops {on}: a connection stops once a floor at most", k)
            seen.add(f)
            if not (0 <= r < rows and 0 <= c < cols):
                raise error(f"stop [{r}, {c}] {on} is off its {rows}x{cols} map", k)
            if floors[f].rows[r][c] == WALL:
                raise error(f"stop [{r}, {c}] {on} is a wall: a stop is a free cell", k)
            if (f, r, c) in taken:
                other = taken[(f, r, c)]
                raise error(
                    f"stop [{r}, {c}] {on} is a stop of {other.name!r} too: a cell is a stop "
                    "of one connection at most", k,
                )  # fmt: skip
            taken[(f, r, c)] = conn
        order = sorted(range(len(conn.stops)), key=lambda k: conn.stops[k][0])
        columns = tuple(conn.columns[k] for k in order) if conn.columns is not None else None
        out.append(replace(conn, stops=tuple(conn.stops[k] for k in order), columns=columns))
    return tuple(out)


def _name_goals(
    floors: Sequence[Floor], names: Sequence[FloorName]
) -> tuple[str | None, ...] | None:
    """Each goal's name (goals in state order: floor by floor, row-major), None when none is
    named; :class:`MapError` for a name of a cell that is not a goal, or given twice."""
    if not names:
        return None
    n, rows, cols = len(floors), len(floors[0].rows), len(floors[0].rows[0])
    placed = []
    for given in names:
        named, f = given.named, given.floor
        if not 0 <= f < n:
            raise named.error(f"floor {f}: the map's floors are 0 to {n - 1}")
        where = f"[{named.row}, {named.col}] on floor {floors[f].label}"
        if not (named.row < rows and named.col < cols):
            raise named.error(f"cell {where} is off its {rows}x{cols} map")
        char = floors[f].rows[named.row][named.col]
        placed.append(Placed(named, (f, named.row, named.col), where, char))
    return names_in_order(_marked(floors, GOAL), placed)


def _rides(
    floors: Sequence[Floor], connections: Sequence[Connection], state_of: IntArray, n: int
) -> tuple[IntArray, IntArray]:
    """The rides up between neighbouring stops of each connection, and each state's connection."""
    rides: list[tuple[int, int, int, int]] = []
    connection_of = np.full(n, -1, dtype=np.int64)
    for i, conn in enumerate(connections):
        states = [int(state_of[f, r, c]) for f, r, c in conn.stops]
        connection_of[states] = i
        for ((fa, _, _), sa), ((fb, _, _), sb) in pairwise(zip(conn.stops, states, strict=True)):
            k = floors[fb].ordinal - floors[fa].ordinal
            rides.append((sa, sb, conn.cost * k, i))
    return np.array(rides, dtype=np.int64).reshape(-1, 4), connection_of
