"""Events in: JSON text to checked (s, a, s'), with one set of checks and one set of words.

An event ``{"state": [r, c], "action": "E", "next_state": [r, c]}`` becomes (s, a, s'); on a
map of several floors cells are ``[floor, row, col]`` and the actions also ``U`` and ``D``:

* without ``next_state`` the domain's transitions give it: ``s' = T(s, a)``;
* without ``action`` it is the move from ``s`` to ``s'``; an unchanged cell is ambiguous (a
  bump into a wall, or standing still) and refused;
* with both, ``s'`` must be ``s`` or one move from it (a client's world may move it
  differently from its intention: the advisor learns from (s, a) and decides for ``s'``).

Two paths, the same checks and the same errors:

* one event (:func:`read_move`): the common form ``{"state": [r, c], "action": "E"}`` by a
  regular expression and plain ints; any other object through pydantic and the batch checks;
* a batch (:func:`read_moves`): the compiled reader for a plainly written list
  (:func:`app.service.wire.compiled.scan_events`), pydantic for anything else, then the
  compiled checks (:func:`app.service.wire.compiled.check_moves`), whose reason code
  :func:`reason_text` words.

A batch is checked whole before the advisor sees any of it, so a refused batch changes nothing.
"""

from __future__ import annotations

import re
import weakref
from array import array
from dataclasses import dataclass
from itertools import chain
from typing import Any

import numpy as np
from pydantic import TypeAdapter, ValidationError

from app.arrays import IntArray, Moves
from app.domain.building import ACTIONS as FLOOR_ACTIONS
from app.domain.building import Building, Domain
from app.domain.grid import GridDomain, packed
from app.service.problems import BadInput, describe_errors
from app.service.schemas import ACTION_CODE, EventIn
from app.service.wire import compiled
from app.service.wire.compiled import check_moves, scan_events

Scanned = tuple[IntArray, IntArray, IntArray, IntArray]

EVENT = TypeAdapter(EventIn)
EVENT_LIST = TypeAdapter(list[EventIn])
NOT_JSON = 'send JSON: an event {"state": [r, c], "action": "N"} or a list of them'
AMBIGUOUS = (
    "state and next_state are the same cell and no action is given: ambiguous "
    "(a bump into a wall, or standing still); send the action"
)


def reason_text(domain: Domain, reason: int, cell: list[int], nxt: list[int]) -> str:
    """The words for a reason code of :func:`check_moves` about the event at ``cell``."""
    if reason == compiled.STATE_OFF:
        return off_map(domain, f"state {cell}")
    if reason == compiled.STATE_WALL:
        return f"state {cell} is a wall"
    if reason == compiled.NEXT_OFF:
        return off_map(domain, f"next_state {nxt}")
    if reason == compiled.NEXT_WALL:
        return f"next_state {nxt} is a wall"
    if reason == compiled.NO_MOVE:
        return "give an action, a next_state or both"
    if reason == compiled.NOT_ONE_MOVE:
        return (
            f"next_state {nxt} is not one move from state {cell} "
            "(a move reaches an adjacent open cell or stays put)"
        )
    return AMBIGUOUS


def _validate(adapter: TypeAdapter[Any], raw: bytes | str) -> Any:
    """``adapter.validate_json(raw)``; errors as BadInput, located under ``event(s)``."""
    root = "event" if adapter is EVENT else "events"
    try:
        return adapter.validate_json(raw)
    except ValidationError as exc:
        errors = [{**e, "loc": (root, *e["loc"])} for e in exc.errors(include_input=False)]
        raise BadInput(describe_errors(errors)) from None


def cell_words(domain: Domain) -> str:
    """How a cell of ``domain`` is written, for an error about one of another shape."""
    if isinstance(domain, Building):
        return f"this map has {domain.n_floors} floors: a cell is [floor, row, col]"
    return "this map has one floor: a cell is [row, col]"


def off_map(domain: Domain, what: str) -> str:
    """``what`` (a key and a cell) is off this map, in the words of every such error."""
    return f"{what} is off the {'x'.join(map(str, domain.shape))} map"


def floor_change(code: int) -> str:
    """Why action ``code`` (``U`` or ``D``) is refused on a map of one floor."""
    return f"action {FLOOR_ACTIONS[code]!r} changes floor: this map has one floor (N, E, S, W)"


def _arrays(events: list[EventIn], domain: Domain) -> Scanned:
    """Parsed events as the compiled reader gives them: cells (n, k), action codes (n,; -1
    none), next cells (n, k; -1 none), steps (n,; -1 none); ``k`` the domain's coordinates
    (BadInput names the first event whose cell has another number)."""
    n, k = len(events), domain.width
    for i, e in enumerate(events):
        for key in ("state", "next_state"):
            cell: Any = e.get(key)
            if cell is not None and len(cell) != k:
                raise BadInput(f"event {i}: {key} {list(cell)}: {cell_words(domain)}")
    flat = chain.from_iterable
    none = (-1,) * k
    cells = np.fromiter(flat(e["state"] for e in events), np.int64, k * n).reshape(n, k)
    actions = np.fromiter((ACTION_CODE[e.get("action")] for e in events), np.int64, n)
    nexts = np.fromiter(flat(e.get("next_state") or none for e in events), np.int64, k * n)
    steps = np.fromiter((e.get("step", -1) for e in events), np.int64, n)
    return cells, actions, nexts.reshape(n, k), steps


def first_step(steps: IntArray) -> int | None:
    """The step of a batch's first event, from the steps its events carry (-1: none): None
    when none carries one; BadInput (422) when they do not number one after another."""
    given = np.flatnonzero(steps >= 0)
    if not len(given):
        return None
    base = steps[given] - given
    first = int(base[0])
    wrong = (base != first) | (base < 1)
    if wrong.any():
        bad = int(given[np.argmax(wrong)])
        raise BadInput(
            f"event {bad}: step {int(steps[bad])} does not follow the batch's numbering: the "
            "events of one batch are consecutive steps, the first of a session step 1"
        )
    return first


def _checked(domain: Domain, cells: IntArray, actions: IntArray, nexts: IntArray) -> Moves:
    if not len(cells):  # an empty batch, whatever shape the reader gave it
        return np.empty(0, np.int64), np.empty(0, np.int64), np.empty(0, np.int64)
    if cells.shape[1] != domain.width:  # the compiled reader's [row, col] on a building
        raise BadInput(f"event 0: state {cells[0].tolist()}: {cell_words(domain)}")
    wide = np.flatnonzero(actions >= domain.n_actions)
    if len(wide):
        i = int(wide[0])
        raise BadInput(f"event {i}: {floor_change(int(actions[i]))}")
    state_of, flat, flat_next = domain.state_of, cells, nexts
    if isinstance(domain, Building):  # floors stacked as rows: [floor * rows + row, col]
        floors, rows, cols = domain.shape
        state_of = state_of.reshape(floors * rows, cols)
        flat, flat_next = _stacked(cells, rows, floors), _stacked(nexts, rows, floors)
    moves, bad, reason = check_moves(state_of, domain.next_state, flat, actions, flat_next)
    if bad >= 0:
        why = reason_text(domain, reason, cells[bad].tolist(), nexts[bad].tolist())
        raise BadInput(f"event {bad}: {why}")
    return moves


def _stacked(cells: IntArray, rows: int, floors: int) -> IntArray:
    """Cells ``[floor, row, col]`` as cells of the floors stacked into one grid, ``[floor *
    rows + row, col]``: a floor or row off the building a row off the grid (the row -1 for a
    negative one, as the reader's -1 of no cell stays -1; past the last row else)."""
    f, r = cells[:, 0], cells[:, 1]
    inside = (f >= 0) & (f < floors) & (r >= 0) & (r < rows)
    row = np.where(inside, f * rows + r, np.where((f < 0) | (r < 0), -1, floors * rows))
    return np.column_stack((row, cells[:, 2]))


def read_moves(domain: Domain, raw: bytes | str, max_events: int) -> tuple[Moves, bool, int | None]:
    """JSON text (one event or a list) -> (checked (s, a, s') arrays, single, the first
    event's step): single when it was one event object, not a list; the step None when no
    event carries one (:func:`first_step`). BadInput (422, or 413 for too many events) names
    the first problem."""
    head = raw.lstrip()[:1]
    if head in (b"[", "["):
        scanned = scan_events(raw)
        if scanned is None:
            scanned = _arrays(_validate(EVENT_LIST, raw), domain)
        single = False
    elif head in (b"{", "{"):
        scanned, single = _arrays([_validate(EVENT, raw)], domain), True
    else:
        raise BadInput(NOT_JSON)
    if len(scanned[0]) > max_events:
        raise BadInput(
            f"too many events: {len(scanned[0])} in one batch, at most {max_events}", 413
        )
    cells, actions, nexts, steps = scanned
    return _checked(domain, cells, actions, nexts), single, first_step(steps)


def read_move(domain: Domain, raw: bytes | str) -> tuple[int, int, int, int] | None:
    """One event object (JSON text) -> its checked (s, a, s') as plain ints and its step (-1:
    none), or None when ``raw`` does not start as an object (then :func:`read_moves` reads
    it). The same checks and errors as :func:`read_moves` gives for it; the common form costs
    no parser and no arrays: one event per request is the REST route's common case."""
    head = raw.lstrip()[:1]
    if head not in (b"{", "{"):
        return None
    plain = _PLAIN_BYTES.fullmatch(raw) if isinstance(raw, bytes) else _PLAIN_TEXT.fullmatch(raw)
    if plain is None or not isinstance(domain, GridDomain):
        cells, actions, nexts, steps = _arrays([_validate(EVENT, raw)], domain)
        (s,), (a,), (s2,) = _checked(domain, cells, actions, nexts)
        return int(s), int(a), int(s2), int(steps[0])
    r, c, letter, step = plain.groups()
    t = _tables(domain)
    row, col = int(r), int(c)
    s = t.state_of[row * t.cols + col] if row < t.rows and col < t.cols else -1
    if s < 0:
        reason = compiled.STATE_OFF if row >= t.rows or col >= t.cols else compiled.STATE_WALL
        raise BadInput(f"event 0: {reason_text(domain, reason, [row, col], [-1, -1])}")
    a = _CODE[letter]
    return s, a, t.next_state[s * 4 + a], int(step) if step else -1


# ``{"state": [r, c], "action": "E"}``, with an optional ``"step": n`` after the action, as
# json.dumps writes it, with or without its spaces, and JSON whitespace around it: what the
# parser reads as that event (1-9 plain digits with no leading zero make a valid coordinate,
# below 2**31, or a step). tests/service/wire/test_events.py checks read_move against the
# parser on such texts, mutated ones and edge cases.
_PLAIN = (
    r'[ \t\n\r]*\{"state": ?\[(0|[1-9][0-9]{0,8}), ?(0|[1-9][0-9]{0,8})\], ?'
    r'"action": ?"([NESW])"(?:, ?"step": ?([1-9][0-9]{0,8}))?\}[ \t\n\r]*'
)
_PLAIN_TEXT = re.compile(_PLAIN)
_PLAIN_BYTES = re.compile(_PLAIN.encode())
_CODE: dict[str | bytes, int] = {x: ACTION_CODE[x] for x in "NESW"}
_CODE |= {x.encode(): ACTION_CODE[x] for x in "NESW"}


@dataclass(frozen=True, slots=True)
class _Lists:
    """A domain's tables as flat ``array.array`` (Python indexing is fast for one event;
    ``grid.packed``): ``state_of[row * cols + col]``, ``next_state[s * 4 + a]``."""

    rows: int
    cols: int
    state_of: array[int]
    next_state: array[int]


_LISTS: weakref.WeakKeyDictionary[GridDomain, _Lists] = weakref.WeakKeyDictionary()


def share_lists(old: GridDomain, new: GridDomain) -> None:
    """``new`` is ``old``'s map (in another frame, :meth:`GridDomain.with_frame`): the lists
    made of ``old`` serve it too."""
    lists = _LISTS.get(old)
    if lists is not None:
        _LISTS[new] = lists


def _tables(domain: GridDomain) -> _Lists:
    lists = _LISTS.get(domain)
    if lists is None:
        rows, cols = domain.shape
        lists = _Lists(rows, cols, packed(domain.state_of, "q"), packed(domain.next_state, "q"))
        _LISTS[domain] = lists
    return lists
