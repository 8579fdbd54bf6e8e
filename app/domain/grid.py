"""Grid domains from ASCII maps (docs/METHOD.md, "Domain").

A map is a list of equal-length strings, row 0 at the top::

    #  wall        .  free        S  start (exactly one)        G  goal (one or more)

States are the free cells, numbered in row-major order; ``cells[s]`` is ``(row, col)`` and
``state_of[row, col]`` is the state index (``-1`` for walls). Actions are the four compass
moves ``N, E, S, W`` (0..3). A move into a wall or off the map leaves the state unchanged, so
the whole dynamics is one precomputed table ``next_state[s, a]``.

A map file may begin with header lines ``key: value`` that place the grid in a building's
metric frame (ROS map_server's convention: x to the east, y to the north, the origin being the
lower-left corner of the lower-left cell)::

    resolution: 0.5          metres per cell side
    origin: -12.0 4.5 0.0    x and y of that corner in metres, and the grid's yaw in radians

and name its destinations, one line each (optional, for any of them; row and column from 0,
row 0 the top row, as the API's cells)::

    destination: 3 12 Lecture hall B

A name is 1 to 40 characters: letters, digits, spaces and ``- _ . , ' & ( ) / + #``, starting
with a letter or digit; each cell and each name (ignoring case) at most once; only a ``G``
cell has one. :attr:`GridDomain.goal_names` holds them in the order of ``goals``.

A map of several floors is written with ``floor: ORDINAL NAME`` lines, each followed by its
floor's rows, and ``connection:`` lines between the floors (:mod:`app.domain.floors`); it is a
:class:`~app.domain.building.Building`, and :func:`app.domain.building.load_map` reads either
kind. This module reads one floor and refuses those lines, saying so.
"""

from __future__ import annotations

import copy
import math
import re
from array import array
from collections import deque
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property, partial
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from app.arrays import BoolArray, IntArray

ACTIONS: tuple[str, ...] = ("N", "E", "S", "W")
N, E, S, W = 0, 1, 2, 3
N_ACTIONS = 4
#: (d_row, d_col) of each action, indexed by action.
MOVES = np.array([[-1, 0], [0, 1], [1, 0], [0, -1]], dtype=np.int64)
ARROWS = ("^", ">", "v", "<")

WALL, FREE, START, GOAL = "#", ".", "S", "G"
MAP_CHARACTERS = (WALL, FREE, START, GOAL)
_CHARACTERS = "".join(MAP_CHARACTERS)
UNREACHABLE = -1


class MapError(ValueError):
    """A map that cannot be a domain; ``line``/``column`` are 1-based when known; ``header``:
    the problem is in the header, whose lines count from the text's first (not the rows');
    ``floor``: on a map of several floors, the floor it is on (``1 'First floor'``: its
    ordinal and name, as its ``floor:`` line writes them)."""

    def __init__(
        self, message: str, line: int | None = None, column: int | None = None,
        header: bool = False, *, floor: str | None = None,
    ):  # fmt: skip
        where = f"floor {floor}, " if floor is not None else ""
        if line is not None:
            where += f"line {line}" + (f", column {column}" if column is not None else "")
        where = where.removesuffix(", ")
        super().__init__(f"{where}: {message}" if where else message)
        self.message = message
        self.line = line
        self.column = column
        self.header = header
        self.floor = floor

    def below(self, lines: int) -> MapError:
        """The same problem in a text whose first ``lines`` lines (a header) came before the
        rows this error counted from."""
        if self.line is None or not lines or self.header:
            return self
        return MapError(self.message, self.line + lines, self.column, floor=self.floor)


#: Bytes :func:`packed` copies at a time (a 250,000-cell map's moves are 8 MB)
PACK_SLICE = 1 << 20


def packed(values: npt.NDArray[Any], code: str) -> array[Any]:
    """The numbers of ``values`` (read flat, row-major) in an ``array.array`` of type ``code``
    (``"d"``: float64, ``"q"``: int64, which ``values`` is converted to): for readers that
    index them one at a time (an item of it is several times faster to read than a numpy
    scalar), the same numbers. Not a list (``tolist``): a list of a million numbers takes
    32 MB, ``tolist`` holds the GIL from its start to its end (50 ms to 1 s for a 250,000-cell
    map's tables), freeing it takes as long again, and the garbage collector walks its items
    at every collection; this is one block of 8 bytes a number, copied a slice at a time
    (the GIL let go between slices) and freed at once."""
    dtype = np.float64 if code == "d" else np.int64
    raw = np.ascontiguousarray(values, dtype=dtype).reshape(-1).data.cast("B")
    out = array(code)
    for i in range(0, len(raw), PACK_SLICE):
        out.frombytes(raw[i : i + PACK_SLICE])
    return out


def action_index(action: int | str) -> int:
    """``"N"``/``"n"``/``0`` -> 0 etc.; raises ``ValueError`` naming what is allowed."""
    if isinstance(action, str):
        key = action.strip().upper()
        if key in ACTIONS:
            return ACTIONS.index(key)
    elif (
        isinstance(action, int | np.integer)
        and not isinstance(action, bool)
        and 0 <= int(action) < N_ACTIONS
    ):
        return int(action)
    raise ValueError(f"unknown action {action!r}: use one of N, E, S, W or 0-3")


def bfs_distances(next_state: IntArray, sources: Iterable[int]) -> IntArray:
    """Shortest number of moves from every state to the nearest source (``-1`` if none).

    Moves are reversible on a grid (``next_state`` is symmetric up to walls), so BFS outward
    from the sources over the same table gives distances *to* them.
    """
    n = next_state.shape[0]
    dist = np.full(n, UNREACHABLE, dtype=np.int64)
    frontier = np.unique(np.fromiter(sources, dtype=np.int64))
    dist[frontier] = 0
    d = 0
    while frontier.size:
        d += 1
        nbrs = np.unique(next_state[frontier].ravel())
        frontier = nbrs[dist[nbrs] == UNREACHABLE]
        dist[frontier] = d
    return dist


def bfs_distances_each(next_state: IntArray, targets: Sequence[int]) -> IntArray:
    """``out[i, s]``: :func:`bfs_distances` to ``targets[i]`` alone, for every target at once.

    The searches advance level by level together over (target, state) pairs, so a map with
    many targets costs about one search's numpy calls per level instead of one per target
    and level (a 1,449-cell corridor with 1,447 targets: 11 s one by one)."""
    n = next_state.shape[0]
    dist = np.full((len(targets), n), UNREACHABLE, dtype=np.int64)
    flat_dist = dist.reshape(-1)  # a view: dist is contiguous
    front = np.arange(len(targets), dtype=np.int64) * n + np.asarray(targets, dtype=np.int64)
    flat_dist[front] = 0
    d = 0
    while front.size:
        d += 1
        which, states = np.divmod(front, n)
        nbrs = np.unique((which[:, None] * n + next_state[states]).ravel())
        front = nbrs[flat_dist[nbrs] == UNREACHABLE]
        flat_dist[front] = d
    return dist


@dataclass(frozen=True)
class Frame:
    """Where a grid lies in metres: ``resolution`` (cell side) and ``origin`` (x, y of the
    lower-left corner of the lower-left cell, and the yaw of the grid's columns axis)."""

    resolution: float
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.resolution) and self.resolution > 0):
            raise MapError(f"resolution must be a positive number of metres, got {self.resolution}")
        if len(self.origin) != 3 or not all(math.isfinite(v) for v in self.origin):
            raise MapError(f"origin must be three finite numbers (x, y, yaw), got {self.origin}")
        object.__setattr__(self, "resolution", float(self.resolution))
        object.__setattr__(self, "origin", tuple(float(v) for v in self.origin))

    def cell_at(self, x: float, y: float, n_rows: int) -> tuple[int, int]:
        """The (row, col) holding the point (x, y) on a grid of ``n_rows`` rows (it may lie
        off the map: the caller checks)."""
        ox, oy, yaw = self.origin
        u, v = x - ox, y - oy
        cos, sin = math.cos(yaw), math.sin(yaw)
        lx, ly = cos * u + sin * v, -sin * u + cos * v
        return n_rows - 1 - math.floor(ly / self.resolution), math.floor(lx / self.resolution)

    def centre(self, row: int, col: int, n_rows: int) -> tuple[float, float]:
        """The (x, y) of the centre of cell (row, col)."""
        ox, oy, yaw = self.origin
        lx, ly = (col + 0.5) * self.resolution, (n_rows - 1 - row + 0.5) * self.resolution
        cos, sin = math.cos(yaw), math.sin(yaw)
        return ox + cos * lx - sin * ly, oy + sin * lx + cos * ly

    def header(self) -> list[str]:
        """The map file's header lines."""
        return [f"resolution: {self.resolution!r}", "origin: " + " ".join(map(repr, self.origin))]


#: the longest name of a destination
NAME_MAX = 40
NAME_RULE = (
    f"1 to {NAME_MAX} characters: letters, digits, spaces and - _ . , ' & ( ) / + # "
    "(starting with a letter or digit)"
)
_NAME = re.compile(r"[^\W_][\w .,'&()/+#-]*")
HEADER_KEYS = ("resolution", "origin", "destination")
#: the header keys only a map of several floors has (:mod:`app.domain.floors`)
FLOORS_KEYS = ("floor", "connection")


@dataclass(frozen=True)
class NamedCell:
    """A destination's name as a map file's header (``destination: ROW COL NAME``) or a PUT
    body gives it, with where it was written, for errors: a header's ``line`` and the columns
    of its cell and of its name, or a body's ``label`` (``destinations[2]``)."""

    row: int
    col: int
    name: str
    line: int | None = None
    column: int | None = None
    name_column: int | None = None
    label: str | None = None

    def error(self, message: str, at_name: bool = False) -> MapError:
        if self.label is not None:
            message = f"{self.label}: {message}"
        column = self.name_column if at_name else self.column
        return MapError(message, self.line, column if self.line is not None else None, True)


def check_name(named: NamedCell) -> str:
    """The name, stripped; :class:`MapError` when it breaks :data:`NAME_RULE`."""
    name = named.name.strip()
    problem = name_problem(name)
    if problem is not None:
        raise named.error(problem, at_name=True)
    return name


def name_problem(name: str, what: str = "a destination's") -> str | None:
    """How a name (stripped) breaks :data:`NAME_RULE` (``what``: whose name it is, for a
    missing one), or None."""
    if not name:
        return f"{what} name is missing"
    if len(name) > NAME_MAX:
        return (
            f"the name {name[:NAME_MAX]!r}... is {len(name)} characters long: a name is {NAME_RULE}"
        )
    if not _NAME.fullmatch(name):
        bad = next((c for c in name if not _NAME.fullmatch("a" + c)), None)
        how = f"holds {bad!r}" if bad is not None else f"starts with {name[0]!r}"
        return f"the name {name!r} {how}: a name is {NAME_RULE}"
    return None


@dataclass(frozen=True)
class Header:
    """What a map text's leading ``key: value`` lines give: the frame, the destinations'
    names, and how many lines they are."""

    frame: Frame | None = None
    names: tuple[NamedCell, ...] = ()
    lines: int = 0


def fields_of(line: str) -> list[tuple[int, str]]:
    """The words of a header line's value (after its first ``:``), each with its column
    (1-based, in the line)."""
    value_at = line.index(":") + 1
    return [(value_at + m.start() + 1, m.group()) for m in re.finditer(r"\S+", line[value_at:])]


def _destination(line: str, n: int) -> NamedCell:
    """A ``destination: ROW COL NAME`` line (``n``: its number, 1-based)."""
    fields = fields_of(line)
    usage = "write destination: ROW COL NAME (row and column from 0, as the API's cells)"
    if len(fields) < 3:
        where = fields[-1][0] + len(fields[-1][1]) if fields else len(line) + 1
        raise MapError(f"a destination needs a row, a column and a name: {usage}", n, where, True)
    cell = []
    for at, text in fields[:2]:
        if not (text.isascii() and text.isdigit()) or len(text) > 9:
            raise MapError(f"{text!r} is not a row or column number: {usage}", n, at, True)
        cell.append(int(text))
    name_at = fields[2][0]
    named = NamedCell(cell[0], cell[1], line[name_at - 1 :], n, fields[0][0], name_at)
    return replace(named, name=check_name(named))


def parse_header(lines: Sequence[str]) -> Header:
    """The frame and the destinations' names that a map text's leading ``key: value`` lines
    give, and how many there are."""
    values: dict[str, tuple[int, str]] = {}
    names: list[NamedCell] = []
    n = 0
    for n, line in enumerate(lines):
        if ":" not in line:
            break
        key, _, value = line.partition(":")
        key = key.strip().lower()
        if key in FLOORS_KEYS:
            raise MapError(
                f"{key} lines belong to a map of several floors (floor: lines, each followed by "
                "its rows), which this reads not: it reads one floor (`maze check` reads both)",
                n + 1, None, True,
            )  # fmt: skip
        if key not in HEADER_KEYS:
            raise MapError(
                f"unknown header {key!r}: a map header has resolution, origin and destination "
                "lines", n + 1, None, True,
            )  # fmt: skip
        if key == "destination":
            names.append(_destination(line, n + 1))
            continue
        if key in values:
            raise MapError(f"{key} given twice", n + 1, None, True)
        values[key] = (n + 1, value.strip())
    else:
        n = len(lines)
    if not values:
        return Header(None, tuple(names), n)
    return Header(frame_of(values), tuple(names), n)


def frame_of(values: dict[str, tuple[int, str]]) -> Frame:
    """The frame of a header's ``resolution`` and ``origin`` lines (line, text)."""
    if "resolution" not in values:
        raise MapError(
            "origin without resolution: give the cell side in metres", values["origin"][0],
            None, True,
        )  # fmt: skip
    res_line, res_text = values["resolution"]
    try:
        resolution = float(res_text)
    except ValueError:
        raise MapError(
            f"resolution {res_text!r} is not a number of metres", res_line, None, True
        ) from None
    if not (math.isfinite(resolution) and resolution > 0):
        raise MapError(
            f"resolution must be a positive number of metres, got {res_text}", res_line, None,
            True,
        )  # fmt: skip
    origin: tuple[float, ...] = (0.0, 0.0, 0.0)
    if "origin" in values:
        o_line, o_text = values["origin"]
        bad = MapError(f"origin {o_text!r}: give x y (and yaw) in metres", o_line, None, True)
        try:
            origin = tuple(float(v) for v in o_text.replace(",", " ").split())
        except ValueError:
            raise bad from None
        if len(origin) == 2:
            origin = (*origin, 0.0)
        if len(origin) != 3:
            raise bad
    try:
        return Frame(resolution, (origin[0], origin[1], origin[2]))
    except MapError as exc:
        raise MapError(exc.message, values["origin"][0], None, True) from None


def split_text(text: str) -> tuple[Header, list[str]]:
    """A map file's text as (what its header gives, its rows); :class:`MapError` names a bad
    header line."""
    lines = text.splitlines()
    header = parse_header(lines)
    return header, lines[header.lines :]


def name_goals(rows: Sequence[str], names: Sequence[NamedCell]) -> tuple[str | None, ...] | None:
    """The name of each goal of checked ``rows`` (row-major order; None: unnamed) from
    ``names``, or None when there are none; :class:`MapError` for a name of a cell that is
    not a goal, a cell or a name given twice."""
    if not names:
        return None
    height, width = len(rows), len(rows[0])
    goals = [(r, c) for r, row in enumerate(rows) for c, ch in enumerate(row) if ch == GOAL]
    placed = []
    for named in names:
        where = f"[{named.row}, {named.col}]"
        if not (named.row < height and named.col < width):
            raise named.error(f"cell {where} is off the {height}x{width} map")
        placed.append(Placed(named, (named.row, named.col), where, rows[named.row][named.col]))
    return names_in_order(goals, placed)


@dataclass(frozen=True)
class Placed:
    """A destination's name at a cell on the map (``cell``: its key among the goals), where
    it is in words and the map's character there."""

    named: NamedCell
    cell: tuple[int, ...]
    where: str
    char: str


def names_in_order(
    goals: Sequence[tuple[int, ...]], names: Sequence[Placed]
) -> tuple[str | None, ...]:
    """Each of ``goals``' names (None: unnamed); :class:`MapError` for a name of a cell that
    is not a goal, a cell or a name given twice (a map of one floor or of several)."""
    index = {cell: i for i, cell in enumerate(goals)}
    out: list[str | None] = [None] * len(goals)
    by_cell: dict[tuple[int, ...], NamedCell] = {}
    by_name: dict[str, NamedCell] = {}
    for placed in names:
        named, cell, where = placed.named, placed.cell, placed.where
        name = check_name(named)
        if cell not in index:
            what = {WALL: "a wall", START: "the start"}.get(placed.char, "a free cell")
            raise named.error(
                f"cell {where} is {what}, not a destination: only a 'G' cell has a name"
            )
        if cell in by_cell:
            raise named.error(f"cell {where} is named twice{_first(by_cell[cell])}")
        if name.casefold() in by_name:
            first = by_name[name.casefold()]
            raise named.error(
                f"the name {name!r} is given twice{_first(first)}: each destination's name "
                "must be its own", at_name=True,
            )  # fmt: skip
        by_cell[cell], by_name[name.casefold()] = named, named
        out[index[cell]] = name
    return tuple(out)


def plain_unique(texts: Iterable[str]) -> list[str]:
    """Names from elsewhere (an imported venue's) made into names a map may hold: every
    character :data:`NAME_RULE` does not allow a space, spaces collapsed, what precedes the
    first letter or digit dropped, cut to :data:`NAME_MAX`, a name already given (ignoring
    case) numbered (``Restroom 2``); ``""`` when nothing is left (no name)."""
    out: list[str] = []
    taken: set[str] = set()
    for text in texts:
        words = "".join(c if _NAME.fullmatch("a" + c) else " " for c in text).split()
        name = " ".join(words)
        name = name[next((i for i, c in enumerate(name) if c.isalnum()), len(name)) :]
        name = name[:NAME_MAX].rstrip()
        base, n = name, 1
        while name and name.casefold() in taken:
            n += 1
            name = f"{base[: NAME_MAX - len(str(n)) - 1].rstrip()} {n}"
        if name:
            taken.add(name.casefold())
        out.append(name)
    return out


def plain_names(
    given: Sequence[tuple[tuple[int, int], str]],
) -> tuple[list[NamedCell], list[str]]:
    """The destinations' names from elsewhere made plain (:func:`plain_unique`); a name left
    empty is no name. Returns the names and a note for each one changed."""
    out: list[NamedCell] = []
    notes: list[str] = []
    for ((row, col), text), name in zip(given, plain_unique(t for _, t in given), strict=True):
        if name != text:
            notes.append(
                f"destination [{row}, {col}] {text!r} written "
                + (f"as {name!r}" if name else "without a name")
                + f" (a name is {NAME_RULE})"
            )
        if name:
            out.append(NamedCell(row, col, name))
    return out, notes


def _first(named: NamedCell) -> str:
    if named.line is not None:
        return f" (line {named.line} names it first)"
    return f" ({named.label} names it first)" if named.label else ""


@dataclass(frozen=True, eq=False)
class GridDomain:
    """A grid world D = (S, A, T) shared by many tasks; a task only picks the goal.

    Build it with :meth:`from_strings` or :meth:`from_file`; both validate the map.
    """

    rows_text: tuple[str, ...]
    name: str = "maze"
    frame: Frame | None = None
    #: each goal's name (in the order of ``goals``; None: unnamed), None when none has one
    goal_names: tuple[str | None, ...] | None = None
    walls: BoolArray = field(init=False, repr=False)
    state_of: IntArray = field(init=False, repr=False)
    cells: IntArray = field(init=False, repr=False)
    next_state: IntArray = field(init=False, repr=False)
    start: int = field(init=False)
    goals: tuple[int, ...] = field(init=False)

    def __post_init__(self) -> None:
        grid = np.array([list(r) for r in self.rows_text])
        walls = grid == WALL
        state_of, cells, next_state = moves_table(walls)
        for name, value in (
            ("walls", walls),
            ("state_of", state_of),
            ("cells", cells),
            ("next_state", next_state),
        ):
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        object.__setattr__(self, "start", int(state_of[grid == START][0]))
        goal_cells = np.argwhere(grid == GOAL)
        object.__setattr__(self, "goals", tuple(int(state_of[r, c]) for r, c in goal_cells))
        if self.goal_names is not None and len(self.goal_names) != len(self.goals):
            raise ValueError(f"{len(self.goal_names)} goal names for {len(self.goals)} goals")

    # ---- construction -------------------------------------------------------------------
    @classmethod
    def from_strings(
        cls, rows: Sequence[str], name: str = "maze", frame: Frame | None = None,
        names: Sequence[NamedCell] = (),
    ) -> GridDomain:  # fmt: skip
        """Validate ``rows`` (see :func:`validate_map`) and the destinations' ``names`` (see
        :func:`name_goals`) and build the domain."""
        cleaned = validate_map(rows)
        goal_names = name_goals(cleaned, names)
        return cls(tuple(cleaned), name=name, frame=frame, goal_names=goal_names)

    @classmethod
    def from_text(cls, text: str, name: str = "maze") -> GridDomain:
        """A map file's text: optional header lines (the frame, the destinations' names), then
        the rows."""
        header, rows = split_text(text)
        try:
            return cls.from_strings(rows, name=name, frame=header.frame, names=header.names)
        except MapError as exc:
            raise exc.below(header.lines) from None

    @classmethod
    def from_file(cls, path: str | Path, name: str | None = None) -> GridDomain:
        p = Path(path)
        return cls.from_text(read_map_text(p), name=name or p.stem)

    def with_frame(self, frame: Frame | None) -> GridDomain:
        """This map in ``frame`` (itself when it is its own): its arrays and everything it
        has computed (distances, lists) shared, nothing read or validated again."""
        if frame == self.frame:
            return self
        other = copy.copy(self)  # the instance's dict: its fields and cached properties
        object.__setattr__(other, "frame", frame)
        return other

    def with_names(self, goal_names: tuple[str | None, ...] | None) -> GridDomain:
        """This map with its destinations named ``goal_names`` (checked: :func:`name_goals`),
        shared as :meth:`with_frame` shares it (itself when they are its own)."""
        if goal_names == self.goal_names:
            return self
        if goal_names is not None and len(goal_names) != len(self.goals):
            raise ValueError(f"{len(goal_names)} goal names for {len(self.goals)} goals")
        other = copy.copy(self)
        object.__setattr__(other, "goal_names", goal_names)
        return other

    def to_text(self) -> str:
        """The map file's text (header lines when the grid has a frame or named destinations);
        :meth:`from_text` reads it back."""
        head = self.frame.header() if self.frame is not None else []
        for (row, col), goal_name in zip(self.goal_cells, self.goal_names or (), strict=False):
            if goal_name is not None:
                head.append(f"destination: {row} {col} {goal_name}")
        return "\n".join([*head, *self.rows_text])

    @property
    def goal_cells(self) -> list[tuple[int, int]]:
        """Each goal's (row, col), in the order of ``goals``."""
        return [self.cell(g) for g in self.goals]

    def goal_label(self, index: int) -> str:
        """How the pages name goal ``index``: its name, else ``G<index>`` (as the maps draw
        it); the data keeps no invented name."""
        named = self.goal_names[index] if self.goal_names is not None else None
        return named if named is not None else f"G{index}"

    # ---- shape --------------------------------------------------------------------------
    @property
    def actions(self) -> tuple[str, ...]:
        """The actions' names, ``N E S W`` (a :class:`~app.domain.building.Building` adds
        ``U D``)."""
        return ACTIONS

    @property
    def n_actions(self) -> int:
        return N_ACTIONS

    @property
    def width(self) -> int:
        """A cell's coordinates: 2, ``[row, col]``."""
        return 2

    @property
    def shape(self) -> tuple[int, int]:
        return (len(self.rows_text), len(self.rows_text[0]))

    @property
    def n_states(self) -> int:
        return int(self.cells.shape[0])

    def state(self, row: int, col: int) -> int:
        """State index of a free cell; ``ValueError`` for walls or cells off the map."""
        rows, cols = self.shape
        if not (0 <= row < rows and 0 <= col < cols):
            raise ValueError(f"cell [{row}, {col}] is off the {rows}x{cols} map")
        s = int(self.state_of[row, col])
        if s < 0:
            raise ValueError(f"cell [{row}, {col}] is a wall")
        return s

    def cell(self, state: int) -> tuple[int, int]:
        """(row, col) of ``state``."""
        cells = self._cells_packed
        return cells[2 * state], cells[2 * state + 1]

    @cached_property
    def _cells_packed(self) -> array[int]:
        """Every state's row and column, :func:`packed` (reading two of them is a tenth of a
        numpy row's cost, and the service answers every event with one)."""
        return packed(self.cells, "q")

    def state_at(self, x: float, y: float) -> int:
        """The state holding the point (x, y) in metres; ``ValueError`` if the grid has no
        frame or the point is in a wall or off the map."""
        if self.frame is None:
            raise ValueError(f"domain {self.name!r} has no resolution and origin: send cells")
        row, col = self.frame.cell_at(x, y, self.shape[0])
        try:
            return self.state(row, col)
        except ValueError as exc:
            raise ValueError(f"position ({x:g}, {y:g}) m: {exc}") from None

    def step(self, state: int, action: int) -> int:
        return int(self.next_state[state, action])

    def move_between(self, state: int, next_state: int) -> int | None:
        """The action that takes ``state`` to a *different* ``next_state``, else ``None``."""
        if state == next_state:
            return None
        hits = np.flatnonzero(self.next_state[state] == next_state)
        return int(hits[0]) if hits.size else None

    # ---- structure ----------------------------------------------------------------------
    def distances_to(self, target: int | Iterable[int]) -> IntArray:
        """BFS distance from every state to ``target`` (a state or several)."""
        sources = [target] if isinstance(target, int | np.integer) else list(target)
        return bfs_distances(self.next_state, sources)

    @cached_property
    def goal_distances(self) -> IntArray:
        """``goal_distances[g, s]``: moves from state ``s`` to goal number ``g``."""
        return bfs_distances_each(self.next_state, self.goals)

    @cached_property
    def open_moves(self) -> BoolArray:
        """``open_moves[s, a]``: action ``a`` leaves ``s`` (does not hit a wall or the edge)."""
        out: BoolArray = self.next_state != np.arange(self.n_states)[:, None]
        return out

    @cached_property
    def dead_ends(self) -> IntArray:
        """States with exactly one open neighbour (corridor ends)."""
        return np.flatnonzero(self.open_moves.sum(axis=1) == 1)

    def render(self, marks: dict[int, str] | None = None) -> str:
        """The map as text, with ``marks`` (state -> one character) drawn over free cells."""
        grid = [list(r) for r in self.rows_text]
        for s, ch in (marks or {}).items():
            r, c = self.cell(s)
            grid[r][c] = ch
        return "\n".join("".join(r) for r in grid)

    def __str__(self) -> str:
        return "\n".join(self.rows_text)


def moves_table(walls: BoolArray) -> tuple[IntArray, IntArray, IntArray]:
    """A grid's states and compass moves: ``state_of`` (the grid's shape, ``-1`` for walls),
    ``cells`` (S x 2, the free cells in row-major order) and ``next_state`` (S x 4: the cell a
    move leads to if it is on the map and free, else the state itself)."""
    state_of = np.full(walls.shape, -1, dtype=np.int64)
    free = np.argwhere(~walls).astype(np.int64)
    state_of[free[:, 0], free[:, 1]] = np.arange(len(free))
    target = free[:, None, :] + MOVES[None, :, :]
    rows, cols = walls.shape
    on_map = (
        (target[..., 0] >= 0)
        & (target[..., 0] < rows)
        & (target[..., 1] >= 0)
        & (target[..., 1] < cols)
    )
    tr = np.clip(target[..., 0], 0, rows - 1)
    tc = np.clip(target[..., 1], 0, cols - 1)
    tgt_state = state_of[tr, tc]
    stay = np.arange(len(free))[:, None].repeat(N_ACTIONS, axis=1)
    next_state = np.where(on_map & (tgt_state >= 0), tgt_state, stay).astype(np.int64)
    return state_of, free, next_state


def check_rows(rows: Sequence[str]) -> list[str]:
    """The rows of a grid, checked for shape and characters only (no start, goal or
    reachability: :func:`validate_map` checks those too); :class:`MapError` names the line
    (counted from the first row) and column. Trailing whitespace (and ``\\r``) is ignored;
    blank trailing lines are dropped."""
    if isinstance(rows, str):
        raise MapError("a map is a list of row strings, not one string (split it into lines)")
    cleaned = [str(r).rstrip() for r in rows]
    while cleaned and not cleaned[-1]:
        cleaned.pop()
    if not cleaned:
        raise MapError("the map is empty")
    width = len(cleaned[0])
    if width == 0:
        raise MapError("the first row is empty", line=1)
    for i, row in enumerate(cleaned, start=1):
        if len(row) != width:
            raise MapError(
                f"ragged row: {len(row)} characters where row 1 has {width} "
                "(every row must have the same length)",
                line=i,
            )
        if row.strip(_CHARACTERS):  # a character that is not a map's: find it
            for j, ch in enumerate(row, start=1):
                if ch in MAP_CHARACTERS:
                    continue
                raise MapError(
                    f"unknown character {ch!r}: use '#' wall, '.' free, 'S' start, 'G' goal",
                    line=i,
                    column=j,
                )
    return cleaned


def read_map_text(path: Path) -> str:
    """A map file's text; :class:`MapError` when it cannot be read or is not UTF-8 text."""
    try:
        return path.read_text(encoding="utf-8")
    except OSError as exc:
        raise MapError(f"cannot read map file {path}: {exc.strerror or exc}") from exc
    except UnicodeDecodeError:
        raise MapError(
            f"{path} is not a text map (use `maze import` for images and other formats)"
        ) from None


def validate_map(rows: Sequence[str]) -> list[str]:
    """Check an ASCII map and return its rows; raise :class:`MapError` naming the problem.

    Trailing whitespace (and ``\\r``) is ignored; blank trailing lines are dropped.
    """
    cleaned = check_rows(rows)
    starts = [(i, j) for i, row in enumerate(cleaned) for j, ch in enumerate(row) if ch == START]
    if not starts:
        raise MapError("no start: mark exactly one cell with 'S'")
    if len(starts) > 1:
        where = ", ".join(f"line {i + 1} column {j + 1}" for i, j in starts)
        raise MapError(f"{len(starts)} starts ({where}): mark exactly one cell with 'S'")
    if not any(GOAL in row for row in cleaned):
        raise MapError("no goal: mark at least one cell with 'G'")
    _check_reachable(cleaned, starts[0])
    return cleaned


def _check_reachable(rows: list[str], start: tuple[int, int]) -> None:
    height, width = len(rows), len(rows[0])
    seen = {start}
    queue = deque([start])
    while queue:
        r, c = queue.popleft()
        for dr, dc in MOVES.tolist():
            nr, nc = r + dr, c + dc
            inside = 0 <= nr < height and 0 <= nc < width
            if inside and rows[nr][nc] != WALL and (nr, nc) not in seen:
                seen.add((nr, nc))
                queue.append((nr, nc))
    for i, row in enumerate(rows):
        for j, ch in enumerate(row):
            if ch != WALL and (i, j) not in seen:
                what = "goal" if ch == GOAL else "free cell"
                raise MapError(
                    f"{what} unreachable from the start (every free cell must be connected to 'S')",
                    line=i + 1,
                    column=j + 1,
                )


def compass_moves(next_state: IntArray, cells: IntArray, target: int) -> BoolArray:
    """``out[s, a]``: ``a`` is a move of someone at ``s`` who heads for ``target`` as the crow
    flies (the paper's "bug"): along the axis of the larger row or column difference if that
    way is open, else along the other axis if that way is open and brings it closer; both
    axes when the differences are equal. No move where neither way is open (it then wanders
    among the open moves) and none at ``target``."""
    n = next_state.shape[0]
    states = np.arange(n)
    out = np.zeros((n, 4), dtype=np.bool_)
    for a in range(4):
        out[:, a] = compass_takes(next_state, cells, np.full(n, target), states, a)
    return out


def compass_takes(
    next_state: IntArray, cells: IntArray, targets: IntArray, states: IntArray, a: int
) -> BoolArray:
    """For each pair (``targets[i]``, ``states[i]``): move ``a`` is one of
    :func:`compass_moves` of the state towards the target."""
    dr = cells[targets, 0] - cells[states, 0]
    dc = cells[targets, 1] - cells[states, 1]
    vert = np.where(dr < 0, 0, 2)  # N or S
    horiz = np.where(dc > 0, 1, 3)  # E or W
    v_ok = (dr != 0) & (next_state[states, vert] != states)
    h_ok = (dc != 0) & (next_state[states, horiz] != states)
    tie = np.abs(dr) == np.abs(dc)
    v_major = np.abs(dr) > np.abs(dc)
    take_v = np.where(tie, v_ok, np.where(v_major, v_ok, ~h_ok & v_ok))
    take_h = np.where(tie, h_ok, np.where(v_major, ~v_ok & h_ok, h_ok))
    out: BoolArray = ((vert == a) & take_v) | ((horiz == a) & take_h)
    return out


def compass_detours(next_state: IntArray, cells: IntArray, target: int) -> IntArray:
    """Fewest moves on any way from every state to ``target`` that someone heading there as
    the crow flies (:func:`compass_moves`) would not make by itself (``-1`` if none): the
    moves it must be shown: the one row of :func:`compass_detours_each` for this target."""
    out: IntArray = compass_detours_each(next_state, cells, [target])[0]
    return out


#: the opposite of each action: N S, E W, and in a building of several floors U D
OPPOSITE = (2, 3, 0, 1, 5, 4)
#: (targets, states, a) -> for each pair, whether ``a`` is one of the state's own moves
#: towards the target (:func:`compass_takes` on one floor)
Takes = Callable[[IntArray, IntArray, int], BoolArray]


def compass_detours_each(
    next_state: IntArray, cells: IntArray, targets: Sequence[int], takes: Takes | None = None
) -> IntArray:
    """``out[i, s]``: :func:`compass_detours` to ``targets[i]``, for every target at once.

    A 0-1 breadth-first search outward from each target, level by level: each level first
    takes in every state whose own move leads into the level (cost 0), then the next level
    starts from every free neighbour of it (cost 1). Moves are reversible on a grid: the
    state ``u`` that move ``a`` of ``v`` reaches reaches ``v`` by the opposite move
    (:data:`OPPOSITE`; a ride up is undone by the ride down). The searches advance together
    over (target, state) pairs, as in :func:`bfs_distances_each`. ``takes``: another rule of
    one's own moves (a building's, over its six actions); by default the compass's on one
    floor.
    """
    if takes is None:
        takes = partial(compass_takes, next_state, cells)
    n = next_state.shape[0]
    tgt = np.asarray(targets, dtype=np.int64)
    out = np.full((len(tgt), n), UNREACHABLE, dtype=np.int64)
    flat = out.reshape(-1)  # a view: out is contiguous
    level = 0
    seeds = np.arange(len(tgt), dtype=np.int64) * n + tgt
    while seeds.size:
        flat[seeds] = level
        members = [seeds]
        frontier = seeds
        while frontier.size:  # states whose own move leads into the level
            which, v = np.divmod(frontier, n)
            found = []
            for a in range(next_state.shape[1]):
                u = next_state[v, a]
                back = OPPOSITE[a]  # u's move into the frontier
                pair = which * n + u
                hit = (u != v) & (flat[pair] == UNREACHABLE)
                hit[hit] = takes(tgt[which[hit]], u[hit], back)
                found.append(pair[hit])
            cand = np.unique(np.concatenate(found))
            flat[cand] = level
            members.append(cand)
            frontier = cand
        level += 1
        which, v = np.divmod(np.concatenate(members), n)
        nbrs = np.unique((which[:, None] * n + next_state[v]).ravel())
        seeds = nbrs[flat[nbrs] == UNREACHABLE]
    return out
