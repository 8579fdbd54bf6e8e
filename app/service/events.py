"""Events in, decisions out: the service's hot path, shared by REST and the websocket.

An event ``{"state": [r, c], "action": "E", "next_state": [r, c]}`` becomes (s, a, s'):

* without ``next_state`` the domain's transitions give it: ``s' = T(s, a)``;
* without ``action`` it is the move from ``s`` to ``s'``; an unchanged cell is ambiguous (a
  bump into a wall, or standing still) and refused;
* with both, ``s'`` must be ``s`` or one move from it (a client's world may move it
  differently from its intention: the advisor learns from (s, a) and decides for ``s'``).

A batch is checked whole before the advisor sees any of it, so a refused batch changes nothing.
Decisions go back as JSON text written by :mod:`app.service.encode`.
"""

from __future__ import annotations

import re
import weakref
from collections.abc import Sequence
from dataclasses import dataclass
from itertools import chain
from typing import Any

import numpy as np
import numpy.typing as npt
from pydantic import TypeAdapter, ValidationError

from app.domain.grid import GridDomain
from app.service.scan import checked_moves, scan_events
from app.service.schemas import ACTION_BRANCHES, ACTION_RULE, EventIn

IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

EVENT = TypeAdapter(EventIn)
EVENT_LIST = TypeAdapter(list[EventIn])
ACTION_CODE: dict[str | int | None, int] = {
    "N": 0, "E": 1, "S": 2, "W": 3, 0: 0, 1: 1, 2: 2, 3: 3, None: -1,
}  # fmt: skip
NO_CELL = (-1, -1)
#: Batches up to this size are checked event by event in plain Python.
SMALL_EVENTS = 8
AMBIGUOUS = (
    "state and next_state are the same cell and no action is given: ambiguous "
    "(a bump into a wall, or standing still); send the action"
)


class BadInput(ValueError):
    """A client error: ``detail`` says what was wrong; ``status`` is the HTTP code."""

    def __init__(self, detail: str, status: int = 422):
        super().__init__(detail)
        self.detail = detail
        self.status = status


def where(loc: Sequence[int | str]) -> str:
    """A validation error location as a path: ``trajectories[0].steps[3].action``."""
    out = ""
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out or "body"


def describe_errors(errors: Sequence[Any], limit: int = 5) -> str:
    """Pydantic errors in one readable line: ``where: what`` for the first few (the two
    branches of an action's union reported once, as one rule)."""
    parts: list[str] = []
    for e in errors:
        loc = tuple(e["loc"])
        text = f"{where(loc)}: {e['msg']}"
        if loc and loc[-1] in ACTION_BRANCHES:
            text = f"{where(loc[:-1])}: {ACTION_RULE}"
        if text not in parts:
            parts.append(text)
    more = f" (and {len(parts) - limit} more)" if len(parts) > limit else ""
    return "; ".join(parts[:limit]) + more


def parse_events(raw: bytes | str, max_events: int) -> tuple[list[EventIn], bool]:
    """JSON text -> (events, single); single when it was one event object, not a list."""
    head = raw.lstrip()[:1]
    if head in (b"{", "{"):
        adapter: TypeAdapter[Any] = EVENT
    elif head in (b"[", "["):
        adapter = EVENT_LIST
    else:
        raise BadInput('send JSON: an event {"state": [r, c], "action": "N"} or a list of them')
    parsed = _validate(adapter, raw)
    events = [parsed] if adapter is EVENT else parsed
    if len(events) > max_events:
        raise BadInput(f"too many events: {len(events)} in one batch, at most {max_events}", 413)
    return events, adapter is EVENT


def read_move(domain: GridDomain, raw: bytes | str) -> tuple[int, int, int] | None:
    """One event object (JSON text) -> its checked (s, a, s') as plain ints, or None when
    ``raw`` does not start as an object (a list, or not JSON: :func:`read_moves` says why).
    The same checks and errors as :func:`read_moves` gives for it, without arrays: one
    event per request is the REST route's common case."""
    head = raw.lstrip()[:1]
    if head not in (b"{", "{"):
        return None
    plain = _PLAIN_BYTES.fullmatch(raw) if isinstance(raw, bytes) else _PLAIN_TEXT.fullmatch(raw)
    if plain is not None:  # the common form: no parser, no dict
        r, c, letter = plain.groups()
        t = _tables(domain)
        s = _cell_state(t, 0, "state", [int(r), int(c)])
        a = _CODE[letter]
        return s, a, t.next_state[s][a]
    return _one_move(_tables(domain), 0, _validate(EVENT, raw))


# ``{"state": [r, c], "action": "E"}`` as json.dumps writes it, with or without its spaces,
# and JSON whitespace around it: what the parser reads as that event (1-9 plain digits with
# no leading zero make a valid coordinate, below 2**31). tests/service/test_events.py checks
# read_move against the parser on such texts, mutated ones and edge cases.
_PLAIN = (
    r'[ \t\n\r]*\{"state": ?\[(0|[1-9][0-9]{0,8}), ?(0|[1-9][0-9]{0,8})\], ?'
    r'"action": ?"([NESW])"\}[ \t\n\r]*'
)
_PLAIN_TEXT = re.compile(_PLAIN)
_PLAIN_BYTES = re.compile(_PLAIN.encode())
_CODE: dict[str | bytes, int] = {x: ACTION_CODE[x] for x in "NESW"}
_CODE |= {x.encode(): ACTION_CODE[x] for x in "NESW"}


def _validate(adapter: TypeAdapter[Any], raw: bytes | str) -> Any:
    """``adapter.validate_json(raw)``; errors as BadInput, located under ``event(s)``."""
    root = "event" if adapter is EVENT else "events"
    try:
        return adapter.validate_json(raw)
    except ValidationError as exc:
        errors = [{**e, "loc": (root, *e["loc"])} for e in exc.errors(include_input=False)]
        raise BadInput(describe_errors(errors)) from None


def read_moves(
    domain: GridDomain, raw: bytes | str, max_events: int
) -> tuple[tuple[IntArray, IntArray, IntArray], bool]:
    """JSON text -> (checked (s, a, s') arrays, single): :func:`parse_events` then
    :func:`to_moves`, or for a plain list of more than :data:`SMALL_EVENTS` events the
    compiled reader (:mod:`app.service.scan`) and the same checks, with the same results and
    the same errors."""
    head = raw.lstrip()[:1]
    if head in (b"[", "["):
        scanned = scan_events(raw, SMALL_EVENTS + 1)
        if scanned is not None:
            cells, actions, nexts = scanned
            if len(cells) > max_events:
                raise BadInput(
                    f"too many events: {len(cells)} in one batch, at most {max_events}", 413
                )
            moves, bad = checked_moves(domain.state_of, domain.next_state, *scanned)
            if bad >= 0:  # the numpy checks name the first bad event and why
                _checked_moves(domain, cells, actions, nexts)
                raise AssertionError(f"event {bad} passed the numpy checks")  # pragma: no cover
            return moves, False
    events, single = parse_events(raw, max_events)
    return to_moves(domain, events), single


def _cell_states(
    domain: GridDomain, cells: IntArray, given: BoolArray
) -> tuple[IntArray, IntArray]:
    """(state of each cell, problem code): 0 fine, 1 off the map, 2 a wall (given cells only)."""
    rows, cols = domain.shape
    r, c = cells[:, 0], cells[:, 1]
    off = given & ((r < 0) | (r >= rows) | (c < 0) | (c >= cols))
    states = domain.state_of[np.clip(r, 0, rows - 1), np.clip(c, 0, cols - 1)]
    wall = given & ~off & (states < 0)
    problem = np.where(off, 1, np.where(wall, 2, 0))
    return np.where(given & (problem == 0), states, 0), problem


def _reason(domain: GridDomain, what: str, cell: list[int], problem: int) -> str:
    rows, cols = domain.shape
    return (
        f"{what} {cell} is off the {rows}x{cols} map"
        if problem == 1
        else f"{what} {cell} is a wall"
    )


def to_moves(domain: GridDomain, events: list[EventIn]) -> tuple[IntArray, IntArray, IntArray]:
    """Checked (s, a, s') arrays for ``events``; BadInput names the first bad event and why.

    Small batches are checked one event at a time in plain Python (numpy's fixed cost per
    call dominates there); larger ones in one pass of numpy. Both give the same moves and
    the same first error (``tests/service/test_events.py``)."""
    if len(events) <= SMALL_EVENTS:
        moves = [_one_move(_tables(domain), i, e) for i, e in enumerate(events)]
        s, a, s2 = zip(*moves, strict=True) if moves else ((), (), ())
        return (np.array(s, dtype=np.int64), np.array(a, dtype=np.int64),
                np.array(s2, dtype=np.int64))  # fmt: skip
    return _many_moves(domain, events)


@dataclass(frozen=True, slots=True)
class _Lists:
    """A domain's tables as nested lists (Python indexing is fast for one event)."""

    rows: int
    cols: int
    state_of: list[list[int]]
    next_state: list[list[int]]


_LISTS: weakref.WeakKeyDictionary[GridDomain, _Lists] = weakref.WeakKeyDictionary()


def _tables(domain: GridDomain) -> _Lists:
    lists = _LISTS.get(domain)
    if lists is None:
        rows, cols = domain.shape
        lists = _Lists(rows, cols, domain.state_of.tolist(), domain.next_state.tolist())
        _LISTS[domain] = lists
    return lists


def _cell_state(t: _Lists, i: int, what: str, cell: list[int]) -> int:
    r, c = cell
    if r >= t.rows or c >= t.cols:
        raise BadInput(f"event {i}: {what} {list(cell)} is off the {t.rows}x{t.cols} map")
    s = t.state_of[r][c]
    if s < 0:
        raise BadInput(f"event {i}: {what} {list(cell)} is a wall")
    return s


def _one_move(t: _Lists, i: int, e: EventIn) -> tuple[int, int, int]:
    """One event checked in the order it is read (the same order as :func:`_many_moves`)."""
    s = _cell_state(t, i, "state", e["state"])
    nxt = e.get("next_state")
    s2 = None if nxt is None else _cell_state(t, i, "next_state", nxt)
    a = ACTION_CODE[e.get("action")]
    if a < 0 and s2 is None:
        raise BadInput(f"event {i}: give an action, a next_state or both")
    reach = t.next_state[s]
    if s2 is None:
        return s, a, reach[a]
    if s2 != s and s2 not in reach:
        raise BadInput(f"event {i}: {_not_one_move(list(e['state']), list(nxt or ()))}")
    if a < 0:
        if s2 == s:
            raise BadInput(f"event {i}: {AMBIGUOUS}")
        a = reach.index(s2)
    return s, a, s2


def _not_one_move(cell: list[int], nxt: list[int]) -> str:
    return (
        f"next_state {nxt} is not one move from state {cell} "
        "(a move reaches an adjacent open cell or stays put)"
    )


def _many_moves(domain: GridDomain, events: list[EventIn]) -> tuple[IntArray, IntArray, IntArray]:
    n = len(events)
    flat = chain.from_iterable
    cells = np.fromiter(flat(e["state"] for e in events), np.int64, 2 * n).reshape(n, 2)
    actions = np.fromiter((ACTION_CODE[e.get("action")] for e in events), np.int64, n)
    nexts = np.fromiter(flat(e.get("next_state") or NO_CELL for e in events), np.int64, 2 * n)
    return _checked_moves(domain, cells, actions, nexts.reshape(n, 2))


def _checked_moves(
    domain: GridDomain, cells: IntArray, actions: IntArray, nexts: IntArray
) -> tuple[IntArray, IntArray, IntArray]:
    """The checks of :func:`to_moves` on arrays: cells (n, 2), action codes (-1: none) and
    next cells (n, 2; -1: none)."""
    n = len(cells)
    has_action, has_next = actions >= 0, nexts[:, 0] >= 0
    states, bad_state = _cell_states(domain, cells, np.ones(n, dtype=bool))
    given_next, bad_next = _cell_states(domain, nexts, has_next)
    reach = domain.next_state[states]  # (n, 4): where each move leads
    next_states = np.where(has_next, given_next, reach[np.arange(n), np.maximum(actions, 0)])
    lands = reach == next_states[:, None]
    stays = next_states == states
    checks = (  # in the order an event is read; the first bad event is named with its reason
        bad_state > 0,
        bad_next > 0,
        ~has_action & ~has_next,
        has_next & ~stays & ~lands.any(axis=1),
        ~has_action & stays,
    )
    bad: IntArray = np.flatnonzero(np.logical_or.reduce(checks)) if n else np.zeros(0, np.int64)
    if len(bad):
        i = int(bad[0])
        failed = [bool(c[i]) for c in checks]
        why = _why(domain, i, cells[i].tolist(), nexts[i].tolist(), failed, bad_state, bad_next)
        raise BadInput(f"event {i}: {why}")
    actions = np.where(has_action, actions, lands.argmax(axis=1))
    return states, actions, next_states


def _why(
    domain: GridDomain, i: int, cell: list[int], nxt: list[int], failed: list[bool],
    bad_state: IntArray, bad_next: IntArray,
) -> str:  # fmt: skip
    if failed[0]:
        return _reason(domain, "state", cell, int(bad_state[i]))
    if failed[1]:
        return _reason(domain, "next_state", nxt, int(bad_next[i]))
    if failed[2]:
        return "give an action, a next_state or both"
    if failed[3]:
        return _not_one_move(cell, nxt)
    return AMBIGUOUS
