"""The text of a map of several floors: its parts (:class:`Floor`, :class:`Connection`,
:class:`FloorName`), read from a map file's text and written back (:class:`~app.domain.building.
Building` checks them and makes the domain).

A one-floor map is written as :mod:`app.domain.grid` says, and stays so: a text is a map of
several floors when it has ``floor:`` lines (:func:`is_floors_text`). Such a file is a header,
then each floor's ``floor:`` line followed by its rows::

    resolution: 0.5                                  optional, as for one floor: one frame
    origin: -21.0 -10.5 0.0                          for every floor (the same grid)
    destination: 0 33 25 Radiology                   FLOOR ROW COL NAME
    connection: lift 24 0:9,35 1:9,35 2:9,35 Lift 1  KIND COST FLOOR:ROW,COL ... NAME
    connection: stairs 36 0:1,42 1:1,42 Stairs A
    floor: 0 Ground floor elevation: 0.0             ORDINAL NAME [elevation: METRES]
    ##########
    #S...G...#
    ##########
    floor: 1 First floor elevation: 4.0
    ...

Floors. Two to :data:`MAX_FLOORS`, written in the order of their ordinals, each ordinal greater
than the last. The ordinal is the floor's number in the building, as IMDF has it: 0 the ground
or entrance floor, 1 the one above, -1 the first basement (a whole number from
-:data:`MAX_ORDINAL` to :data:`MAX_ORDINAL`; gaps allowed). Every line of the file names a floor
by its ordinal. The domain numbers its floors from 0 in this order: a cell of the API is
``[floor, row, col]`` with ``floor`` that index, so in a building with one basement the
floor of ordinal 0 is floor 1 of the cells. A floor's name follows the destinations' rule
(:data:`~app.domain.grid.NAME_RULE`; each name once, ignoring case); ``elevation:``, optional,
is the height of the floor's level in metres above the floor of ordinal 0 (negative below),
increasing with the ordinals where given (the viewer stacks floors by it; IMDF writes the
ordinal times a storey height). Every floor has the same rows and columns (an import pads with
walls), the cells of one (row, col) lying above one another; its rows are a one-floor map's
characters (blank lines after a floor's rows are dropped). One ``S`` in the whole building;
``G`` cells on any floor, at least one.

Destinations. ``destination: FLOOR ROW COL NAME``: the floor's ordinal, then the row and column
from 0 as a one-floor map's; names as one floor's, each once in the building.

Connections. ``connection: KIND COST STOP STOP ... NAME``: ``KIND`` one of :data:`KINDS`;
``COST`` the moves of time a ride takes per floor it travels (a whole number from 1 to
:data:`MAX_RIDE_COST`: :class:`~app.domain.building.Building` says what a ride is); each stop
``FLOOR:ROW,COL`` (the floor's ordinal, a free cell of it), at least two, at most one a floor;
then the connection's name (required: the maps' legends and messages name connections by it;
:data:`~app.domain.grid.NAME_RULE`, each once among the connections, ignoring case). A cell is a
stop of one connection at most. At most :data:`MAX_CONNECTIONS` connections.

Header lines come before the first ``floor:`` line (blank lines among them are skipped); every
error names the line and column, and the floor when it is on one
(:class:`~app.domain.grid.MapError`). A building has at most
:data:`~app.domain.building.MAX_CELLS` cells (floors x rows x columns). Writing gives the
frame, the destinations in the order of the goals, the connections in their order (stops by
floor), then the floors, with no blank line: a text so written is read back to the same
building and written again byte for byte (another text is written in this order).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from itertools import pairwise

from app.domain.grid import (
    HEADER_KEYS,
    Frame,
    MapError,
    NamedCell,
    check_name,
    fields_of,
    frame_of,
)

#: the kinds of connection, as a map file writes them
KINDS: tuple[str, ...] = ("stairs", "lift", "escalator", "ramp")
MAX_FLOORS = 256
MAX_ORDINAL = 999
#: the largest absolute elevation, in metres
MAX_ELEVATION = 10_000.0
MAX_CONNECTIONS = 4096
#: the most moves of time a ride may take per floor
MAX_RIDE_COST = 1000
#: seconds a ride takes per floor, by kind, where a map gives no cost (an import, a generated
#: building): stairs, a 4 m storey's 24 steps and a landing; a lift, its travel and doors and a
#: share of the wait; an escalator, 8 m at 0.5 m/s; a ramp, a 4 m rise at 1:12 (48 m) walked
SECONDS_PER_FLOOR = {"stairs": 15.0, "lift": 10.0, "escalator": 16.0, "ramp": 40.0}
#: metres a second of someone walking, one cell a move
WALKING_SPEED = 1.2
#: how many characters of a value from the text an error quotes
QUOTE = 40
#: the keys of a floors header (``floor:`` lines start the floors)
KEYS = (*HEADER_KEYS, "connection")

_FLOOR_LINE = re.compile(r"[ \t]*floor[ \t]*:", re.IGNORECASE)
_ORDINAL = re.compile(r"[+-]?\d{1,3}")
_NUMBER = re.compile(r"[+-]?(\d+(\.\d*)?|\.\d+)([eE][+-]?\d{1,3})?")
_COUNT = re.compile(r"\d{1,9}")
_STOP = re.compile(r"([+-]?\d{1,3}):(\d{1,9}),(\d{1,9})")

FLOOR_USAGE = (
    "write floor: ORDINAL NAME, and elevation: METRES after the name if known (the ordinal a "
    f"whole number from -{MAX_ORDINAL} to {MAX_ORDINAL}: 0 the ground floor, negative below)"
)
DESTINATION_USAGE = (
    "write destination: FLOOR ROW COL NAME (the floor's ordinal; row, column from 0)"
)
CONNECTION_USAGE = (
    f"write connection: KIND COST FLOOR:ROW,COL FLOOR:ROW,COL ... NAME (KIND one of "
    f"{', '.join(KINDS)}; COST the moves of time per floor, 1 to {MAX_RIDE_COST}; each stop a "
    "floor's ordinal and a cell)"
)


def default_cost(kind: str, resolution: float) -> int:
    """A connection's cost (moves of time per floor) where a map gives none: its kind's
    :data:`SECONDS_PER_FLOOR` in moves of someone walking :data:`WALKING_SPEED` across cells of
    ``resolution`` metres, rounded, from 1 to :data:`MAX_RIDE_COST` (at 0.5 m: stairs 36, a
    lift 24, an escalator 38, a ramp 96; at 1 m half that)."""
    moves = round(SECONDS_PER_FLOOR[kind] * WALKING_SPEED / resolution)
    return max(1, min(MAX_RIDE_COST, moves))


def quoted(text: str, limit: int = QUOTE) -> str:
    """``repr(text)``, cut to ``limit`` characters ending in ``...`` when longer."""
    out = repr(text[:limit])
    return out if len(text) <= limit else out[:-1] + "..." + out[-1]


@dataclass(frozen=True)
class Floor:
    """One floor: its ``ordinal`` (0 the ground floor, negative below), ``name``, ``rows`` (a
    one-floor map's characters) and ``elevation`` (metres above the floor of ordinal 0, None
    when not known). ``line``: its ``floor:`` line in a text, for errors (its rows follow)."""

    ordinal: int
    name: str
    rows: tuple[str, ...]
    elevation: float | None = None
    line: int | None = field(default=None, compare=False, repr=False)

    @property
    def label(self) -> str:
        """How errors and titles name it: ``1 'First floor'``."""
        return f"{self.ordinal} {self.name!r}"

    def header(self) -> str:
        """Its ``floor:`` line."""
        elevation = f" elevation: {self.elevation!r}" if self.elevation is not None else ""
        return f"floor: {self.ordinal} {self.name}{elevation}"


@dataclass(frozen=True)
class Connection:
    """Stairs, a lift, an escalator or a ramp between floors: its ``kind`` (:data:`KINDS`),
    ``cost`` (moves of time a ride takes per floor travelled), ``stops`` (each a cell
    ``(floor, row, col)``, ``floor`` the index of the building's floor, not its ordinal; in the
    order of the floors once checked) and ``name``. ``line`` and ``columns`` (each stop's):
    where a text wrote it, for errors."""

    kind: str
    cost: int
    stops: tuple[tuple[int, int, int], ...]
    name: str
    line: int | None = field(default=None, compare=False, repr=False)
    columns: tuple[int, ...] | None = field(default=None, compare=False, repr=False)

    @property
    def floors(self) -> tuple[int, ...]:
        """The floors (indices) of its stops."""
        return tuple(f for f, _, _ in self.stops)


@dataclass(frozen=True)
class FloorName:
    """A destination's name on a floor: ``floor`` is the floor's index, ``named`` the cell of
    that floor and its name, with where a text wrote them."""

    floor: int
    named: NamedCell


@dataclass(frozen=True)
class FloorsText:
    """What a map text of several floors holds, read but not checked."""

    floors: tuple[Floor, ...]
    connections: tuple[Connection, ...]
    names: tuple[FloorName, ...]
    frame: Frame | None


def order_problem(floor: Floor, below: Floor) -> str | None:
    """How ``floor``'s ordinal breaks the floors' order after ``below``, or None."""
    if floor.ordinal <= below.ordinal:
        return (
            f"ordinal {floor.ordinal} after {below.ordinal}: floors are written in the order "
            "of their ordinals, each greater than the last"
        )
    return None


def is_floors_text(text: str) -> bool:
    """Whether a map file's text is of several floors: it has a ``floor:`` line."""
    return any(_FLOOR_LINE.match(line) for line in text.splitlines())


def read_floors(text: str) -> FloorsText:
    """The parts of a map text of several floors, each with where it was written;
    :class:`MapError` names the line and column of a line that cannot be read (what the parts
    must be, :class:`~app.domain.building.Building` checks)."""
    lines = text.splitlines()
    first = next((i for i, line in enumerate(lines) if _FLOOR_LINE.match(line)), None)
    if first is None:
        raise MapError("no floor: line: a map of several floors gives each floor's rows after one")
    values: dict[str, tuple[int, str]] = {}
    destinations: list[tuple[int, int, NamedCell]] = []  # (ordinal, its column, named)
    connections: list[tuple[str, int, list[tuple[int, int, int, int]], str, int, int]] = []
    for n, line in enumerate(lines[:first], start=1):
        if not line.strip():
            continue
        key, colon, value = line.partition(":")
        key = key.strip().lower()
        if not colon:
            raise MapError(
                "a row before the first floor: line: each floor's rows follow its floor: line",
                n, None, True,
            )  # fmt: skip
        if key not in KEYS:
            raise MapError(
                f"unknown header {quoted(key)}: a map of several floors has resolution, origin, "
                "destination and connection lines, then floor: lines", n, None, True,
            )  # fmt: skip
        if key == "destination":
            destinations.append(_destination(line, n))
        elif key == "connection":
            if len(connections) == MAX_CONNECTIONS:
                raise MapError(
                    f"more than {MAX_CONNECTIONS} connections: a map has at most "
                    f"{MAX_CONNECTIONS}", n, None, True,
                )  # fmt: skip
            connections.append(_connection(line, n))
        elif key in values:
            raise MapError(f"{key} given twice", n, None, True)
        else:
            values[key] = (n, value.strip())
    frame = frame_of(values) if values else None
    floors = _floors(lines, first)
    for below, floor in pairwise(floors):  # the ordinals name the floors: each once
        problem = order_problem(floor, below)
        if problem is not None:
            raise MapError(problem, floor.line, None, True, floor=floor.label)
    index = {f.ordinal: i for i, f in enumerate(floors)}
    return FloorsText(
        floors,
        tuple(_resolved(c, index, floors) for c in connections),
        tuple(_named(d, index, floors) for d in destinations),
        frame,
    )


def _floors(lines: Sequence[str], first: int) -> tuple[Floor, ...]:
    """Each ``floor:`` line from ``lines[first]`` on, with its rows."""
    starts = [i for i in range(first, len(lines)) if _FLOOR_LINE.match(lines[i])]
    if len(starts) > MAX_FLOORS:
        raise MapError(
            f"more than {MAX_FLOORS} floors: a map has at most {MAX_FLOORS}",
            starts[MAX_FLOORS] + 1, None, True,
        )  # fmt: skip
    out = []
    for k, i in enumerate(starts):
        end = starts[k + 1] if k + 1 < len(starts) else len(lines)
        rows = [line.rstrip() for line in lines[i + 1 : end]]
        while rows and not rows[-1]:
            rows.pop()
        for j, row in enumerate(rows):
            key = row.partition(":")[0].strip().lower()
            if ":" in row and key in KEYS:
                raise MapError(
                    f"a {key} line among the rows: header lines come before the first floor: "
                    "line", i + j + 2, None, True,
                )  # fmt: skip
        ordinal, name, elevation = _floor_line(lines[i], i + 1)
        out.append(Floor(ordinal, name, tuple(rows), elevation, i + 1))
    return tuple(out)


def _floor_line(line: str, n: int) -> tuple[int, str, float | None]:
    """A ``floor: ORDINAL NAME [elevation: METRES]`` line: (ordinal, name, elevation)."""
    value_at = line.index(":") + 1
    value = line[value_at:]
    # ':' is no name's character: the first 'elevation:' ends the name
    cut = value.lower().find("elevation:")
    main = value if cut < 0 else value[:cut]
    words = [(value_at + m.start() + 1, m.group()) for m in re.finditer(r"\S+", main)]
    if not words:
        raise MapError(f"a floor needs an ordinal and a name: {FLOOR_USAGE}", n, None, True)
    at, text = words[0]
    if not _ORDINAL.fullmatch(text):
        raise MapError(f"{quoted(text)} is not a floor's ordinal: {FLOOR_USAGE}", n, at, True)
    if len(words) < 2:
        raise MapError(f"a floor needs a name: {FLOOR_USAGE}", n, at + len(text), True)
    name_at = words[1][0]
    name = check_name(NamedCell(0, 0, line[name_at - 1 : value_at + len(main)], n, at, name_at))
    elevation = None
    if cut >= 0:
        rest = value[cut + len("elevation:") :]
        e_at = value_at + cut + len("elevation:") + 1 + (len(rest) - len(rest.lstrip()))
        e_text = rest.strip()
        if not _NUMBER.fullmatch(e_text) or abs(float(e_text)) > MAX_ELEVATION:
            raise MapError(
                f"elevation {quoted(e_text)} is not a height in metres (a number from "
                f"-{MAX_ELEVATION:,.0f} to {MAX_ELEVATION:,.0f}): {FLOOR_USAGE}", n, e_at, True,
            )  # fmt: skip
        elevation = float(e_text)
    return int(text), name, elevation


def _at_least(line: str, n: int, count: int, usage: str) -> list[tuple[int, str]]:
    """The fields of header line ``n`` (column, text), at least ``count`` of them; else
    :class:`MapError` saying ``usage`` at the end of the line's last field."""
    fields = fields_of(line)
    if len(fields) < count:
        where = fields[-1][0] + len(fields[-1][1]) if fields else len(line) + 1
        raise MapError(usage, n, where, True)
    return fields


def _destination(line: str, n: int) -> tuple[int, int, NamedCell]:
    """A ``destination: FLOOR ROW COL NAME`` line: (ordinal, its column, the named cell)."""
    fields = _at_least(line, n, 4, "a destination on a map of several floors needs a floor, a "
                       f"row, a column and a name: {DESTINATION_USAGE}")  # fmt: skip
    at, text = fields[0]
    if not _ORDINAL.fullmatch(text):
        raise MapError(f"{quoted(text)} is not a floor's ordinal: {DESTINATION_USAGE}", n, at, True)
    cell = []
    for c_at, c_text in fields[1:3]:
        if not _COUNT.fullmatch(c_text):
            raise MapError(
                f"{quoted(c_text)} is not a row or column number: {DESTINATION_USAGE}", n, c_at,
                True,
            )  # fmt: skip
        cell.append(int(c_text))
    name_at = fields[3][0]
    named = NamedCell(cell[0], cell[1], line[name_at - 1 :], n, fields[1][0], name_at)
    return int(text), at, replace(named, name=check_name(named))


def _connection(
    line: str, n: int
) -> tuple[str, int, list[tuple[int, int, int, int]], str, int, int]:
    """A ``connection:`` line: (kind, cost, stops as (ordinal, row, col, column), name, line,
    the kind's column)."""
    fields = _at_least(line, n, 5, "a connection needs a kind, a cost, two stops or more and a "
                       f"name: {CONNECTION_USAGE}")  # fmt: skip
    (k_at, kind), (c_at, cost) = fields[0], fields[1]
    if kind.lower() not in KINDS:
        raise MapError(f"unknown kind {quoted(kind)}: {CONNECTION_USAGE}", n, k_at, True)
    if not _COUNT.fullmatch(cost) or not 1 <= int(cost) <= MAX_RIDE_COST:
        raise MapError(
            f"cost {quoted(cost)} is not a number of moves from 1 to {MAX_RIDE_COST}: "
            f"{CONNECTION_USAGE}", n, c_at, True,
        )  # fmt: skip
    stops: list[tuple[int, int, int, int]] = []
    k = 2
    while k < len(fields) and ":" in fields[k][1]:  # ':' is no name's character
        s_at, s_text = fields[k]
        m = _STOP.fullmatch(s_text)
        if m is None:
            raise MapError(
                f"{quoted(s_text)} is not a stop: write FLOOR:ROW,COL (the floor's ordinal, row "
                "and column from 0, no spaces)", n, s_at, True,
            )  # fmt: skip
        stops.append((int(m.group(1)), int(m.group(2)), int(m.group(3)), s_at))
        if len(stops) > MAX_FLOORS:  # one a floor at most: refused before more are read
            raise MapError(f"more than {MAX_FLOORS} stops: one a floor at most", n, s_at, True)
        k += 1
    if k == len(fields):
        raise MapError(
            f"a connection's name is missing: {CONNECTION_USAGE}", n, len(line) + 1, True
        )
    name_at = fields[k][0]
    name = check_name(NamedCell(0, 0, line[name_at - 1 :], n, name_at, name_at))
    return kind.lower(), int(cost), stops, name, n, k_at


def _ordinal_index(
    ordinal: int, index: dict[int, int], floors: Sequence[Floor], n: int, at: int, what: str
) -> int:
    if ordinal not in index:
        listed = ", ".join(str(f.ordinal) for f in floors[:12])
        listed += f" and {len(floors) - 12} more" if len(floors) > 12 else ""
        raise MapError(
            f"{what}: no floor of ordinal {ordinal} (the floors' ordinals are {listed})", n, at,
            True,
        )  # fmt: skip
    return index[ordinal]


def _resolved(
    c: tuple[str, int, list[tuple[int, int, int, int]], str, int, int],
    index: dict[int, int],
    floors: Sequence[Floor],
) -> Connection:
    """A connection line's stops on the floors' indices."""
    kind, cost, stops, name, n, _ = c
    cells = tuple(
        (_ordinal_index(o, index, floors, n, at, f"connection {name!r}"), r, col)
        for o, r, col, at in stops
    )
    return Connection(kind, cost, cells, name, n, tuple(at for *_, at in stops))


def _named(
    d: tuple[int, int, NamedCell], index: dict[int, int], floors: Sequence[Floor]
) -> FloorName:
    ordinal, at, named = d
    assert named.line is not None
    return FloorName(_ordinal_index(ordinal, index, floors, named.line, at, "destination"), named)


def floors_text(
    floors: Sequence[Floor],
    connections: Sequence[Connection],
    names: Sequence[tuple[tuple[int, int, int], str]],
    frame: Frame | None,
) -> str:
    """The text of a map of several floors (no trailing newline): ``names`` are the named
    destinations' cells (floor index, row, col) and names, in the order of the goals."""
    head = frame.header() if frame is not None else []
    for (f, r, c), name in names:
        head.append(f"destination: {floors[f].ordinal} {r} {c} {name}")
    for conn in connections:
        stops = " ".join(f"{floors[f].ordinal}:{r},{c}" for f, r, c in conn.stops)
        head.append(f"connection: {conn.kind} {conn.cost} {stops} {conn.name}")
    body = [line for floor in floors for line in (floor.header(), *floor.rows)]
    return "\n".join([*head, *body])
