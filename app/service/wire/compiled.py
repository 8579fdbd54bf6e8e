"""The service's compiled wire code (numba): reading event batches, writing decision batches.

**Reading.** :func:`scan_events` reads the common shape of an event batch, a JSON list of
events written plainly (``[{"state": [28, 0], "action": "E"}, {"state": [28, 1], "next_state":
[27, 1]}]``), once, in a numba loop, straight into arrays, where pydantic-core would build
about 4,000 Python objects for 500 events. It accepts a strict subset of what the schema
(``list[EventIn]``) accepts, with the same meaning:

* keys ``"state"`` (required), ``"action"``, ``"next_state"`` and ``"step"``, each at most
  once, without escapes; JSON whitespace anywhere between tokens;
* a cell is ``[row, col]``: two non-negative integers below 2**31 in plain digits;
* an action is ``"N"``, ``"E"``, ``"S"``, ``"W"``, a digit 0-3, or ``null``; a next state a cell
  or ``null``; a step a positive integer below 2**31 in plain digits.

Anything else (a float, a sign, an escape, an unknown or repeated key, a non-ASCII byte, ...)
makes it answer ``None``, and the caller reads the text with pydantic, which accepts it or
names the error. ``tests/service/wire/test_compiled.py`` checks the two against each other.

**Checking.** :func:`check_moves` turns cells and actions into (s, a, s') and stops at the
first bad event with a reason code (``STATE_OFF`` ... ``AMBIGUOUS``), which
:func:`app.service.wire.events.reason_text` words.

**Writing.** :func:`write_decisions` lays out the JSON text of a batch of decisions; every
number's text comes from orjson (written from the numpy columns without Python floats), so
the bytes are those of the one-event answer, which orjson writes whole.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from app.arrays import BoolArray, ByteArray, IntArray

# byte values
_SPACE, _TAB, _LF, _CR = 32, 9, 10, 13
_QUOTE, _COMMA, _COLON = 34, 44, 58
_LBRACKET, _RBRACKET, _LBRACE, _RBRACE = 91, 93, 123, 125
_ZERO, _NINE = 48, 57
_N, _E, _S, _W = 78, 69, 83, 87
_LOWER_N, _LOWER_U, _LOWER_L = 110, 117, 108
_DOT, _LOWER_E, _UPPER_E = 46, 101, 69
_BAD = -1
_LIMIT = 2**31  # coordinates are below this (schemas.Coordinate)


@njit(cache=True, inline="always")
def _skip(buf: ByteArray, i: int) -> int:  # pragma: no cover - compiled
    n = buf.shape[0]
    while i < n and (buf[i] == _SPACE or buf[i] == _LF or buf[i] == _CR or buf[i] == _TAB):
        i += 1
    return i


@njit(cache=True, inline="always")
def _int(buf: ByteArray, i: int) -> tuple[int, int]:  # pragma: no cover - compiled
    """(value, index after it) of plain digits at ``i``; value -1 if not a plain integer
    below 2**31 (leading zeros, fractions, exponents and signs included)."""
    n = buf.shape[0]
    if i >= n or buf[i] < _ZERO or buf[i] > _NINE:
        return _BAD, i
    if buf[i] == _ZERO and i + 1 < n and _ZERO <= buf[i + 1] <= _NINE:
        return _BAD, i
    v = 0
    k = i
    while k < n and _ZERO <= buf[k] <= _NINE:
        v = v * 10 + (buf[k] - _ZERO)
        k += 1
        if k - i > 10:
            return _BAD, k
    if v >= _LIMIT:
        return _BAD, k
    if k < n and (buf[k] == _DOT or buf[k] == _LOWER_E or buf[k] == _UPPER_E):
        return _BAD, k
    return v, k


@njit(cache=True, inline="always")
def _cell(buf: ByteArray, i: int) -> tuple[int, int, int]:  # pragma: no cover - compiled
    """(row, col, index after) of ``[row, col]`` at ``i``; row -1 if it is not one."""
    n = buf.shape[0]
    if i >= n or buf[i] != _LBRACKET:
        return _BAD, _BAD, i
    r = c = _BAD
    for part in range(2):  # the row then ",", the column then "]"
        v, i = _int(buf, _skip(buf, i + 1))
        i = _skip(buf, i)
        if v < 0 or i >= n or buf[i] != (_COMMA if part == 0 else _RBRACKET):
            return _BAD, _BAD, i
        if part == 0:
            r = v
        else:
            c = v
    return r, c, i + 1


@njit(cache=True, inline="always")
def _null(buf: ByteArray, i: int) -> bool:  # pragma: no cover - compiled
    return bool(
        i + 3 < buf.shape[0]
        and buf[i] == _LOWER_N
        and buf[i + 1] == _LOWER_U
        and buf[i + 2] == _LOWER_L
        and buf[i + 3] == _LOWER_L
    )


@njit(cache=True, inline="always")
def _key(buf: ByteArray, i: int) -> tuple[int, int]:  # pragma: no cover - compiled
    """(0 state, 1 action, 2 next_state, 3 step or -1, index after the closing quote) at
    ``i``."""
    n = buf.shape[0]
    if i >= n or buf[i] != _QUOTE:
        return _BAD, i
    k = i + 1
    while k < n and buf[k] != _QUOTE:
        if buf[k] == 92 or buf[k] >= 128:  # an escape or non-ASCII: not a plain key
            return _BAD, k
        k += 1
    if k >= n:
        return _BAD, k
    length = k - i - 1
    j = i + 1
    if length == 5:  # state
        ok = buf[j] == 115 and buf[j + 1] == 116 and buf[j + 2] == 97 and buf[j + 3] == 116
        if ok and buf[j + 4] == 101:
            return 0, k + 1
    elif length == 6:  # action
        ok = buf[j] == 97 and buf[j + 1] == 99 and buf[j + 2] == 116 and buf[j + 3] == 105
        if ok and buf[j + 4] == 111 and buf[j + 5] == 110:
            return 1, k + 1
    elif length == 4:  # step
        if buf[j] == 115 and buf[j + 1] == 116 and buf[j + 2] == 101 and buf[j + 3] == 112:
            return 3, k + 1
    elif length == 10:  # next_state
        ok = buf[j] == 110 and buf[j + 1] == 101 and buf[j + 2] == 120 and buf[j + 3] == 116
        ok = ok and buf[j + 4] == 95 and buf[j + 5] == 115 and buf[j + 6] == 116
        ok = ok and buf[j + 7] == 97 and buf[j + 8] == 116 and buf[j + 9] == 101
        if ok:
            return 2, k + 1
    return _BAD, k


@njit(cache=True, inline="always")
def _action(buf: ByteArray, i: int) -> tuple[int, int]:  # pragma: no cover - compiled
    """(code 0-3, -1 for null, -2 if not an action, index after) at ``i``."""
    n = buf.shape[0]
    if i >= n:
        return -2, i
    b = buf[i]
    if b == _QUOTE:
        if i + 2 < n and buf[i + 2] == _QUOTE:
            c = buf[i + 1]
            if c == _N:
                return 0, i + 3
            if c == _E:
                return 1, i + 3
            if c == _S:
                return 2, i + 3
            if c == _W:
                return 3, i + 3
        return -2, i
    if _ZERO <= b <= _ZERO + 3:
        if i + 1 < n and (
            _ZERO <= buf[i + 1] <= _NINE
            or buf[i + 1] == _DOT
            or buf[i + 1] == _LOWER_E
            or buf[i + 1] == _UPPER_E
        ):
            return -2, i
        return b - _ZERO, i + 1
    if _null(buf, i):
        return -1, i + 4
    return -2, i


@njit(cache=True, inline="always")
def _after_item(buf: ByteArray, i: int, close: int) -> tuple[int, int]:  # pragma: no cover
    """After an item of an object or a list: (the next item's index, 1) past a comma,
    (the index of ``close``, 0) at the end, or (i, -1) for anything else."""
    i = _skip(buf, i)
    if i >= buf.shape[0]:
        return i, -1
    if buf[i] == _COMMA:
        return _skip(buf, i + 1), 1
    if buf[i] == close:
        return i, 0
    return i, -1


_STATE_KEY = np.frombuffer(b'{"state":', dtype=np.uint8)
_ACTION_KEY = np.frombuffer(b'"action":', dtype=np.uint8)
_STEP_KEY = np.frombuffer(b'"step":', dtype=np.uint8)


@njit(cache=True, inline="always")
def _common(buf: ByteArray, i: int, out: IntArray, count: int) -> int:  # pragma: no cover
    """The most common event, ``{"state":[r,c],"action":"E"}`` (or with ``json.dumps``'s
    default single spaces), with or without a ``"step"`` after the action, read at ``i`` into
    ``out[count]``: the index after its ``}``, or
    -1 when the event is written any other way (the general reader then reads it).

    Written out flat, without the helpers above: each helper call costs a few nanoseconds
    here, which made the general reader about 100 ns an event (measured in
    docs/PERFORMANCE.md); this path reads one in about 15."""
    n = buf.shape[0]
    word = _STATE_KEY
    if i + word.shape[0] + 12 > n:
        return _BAD
    for k in range(word.shape[0]):
        if buf[i + k] != word[k]:
            return _BAD
    i += word.shape[0]
    i += buf[i] == _SPACE
    if buf[i] != _LBRACKET:
        return _BAD
    i += 1
    r = c = 0
    for part in range(2):  # the row then ",", the column then "]": 1-9 plain digits, no
        start = i  # leading zero
        v = 0
        while i < n and _ZERO <= buf[i] <= _NINE and i - start < 9:
            v = v * 10 + (buf[i] - _ZERO)
            i += 1
        end = _COMMA if part == 0 else _RBRACKET
        if i == start or i >= n or buf[i] != end or (buf[start] == _ZERO and i - start > 1):
            return _BAD
        i += 1
        if part == 0:
            r = v
            i += i < n and buf[i] == _SPACE
        else:
            c = v
    if i >= n or buf[i] != _COMMA:
        return _BAD
    i += 1
    i += i < n and buf[i] == _SPACE
    word = _ACTION_KEY
    if i + word.shape[0] + 4 > n:
        return _BAD
    for k in range(word.shape[0]):
        if buf[i + k] != word[k]:
            return _BAD
    i += word.shape[0]
    i += buf[i] == _SPACE
    if i + 3 >= n or buf[i] != _QUOTE or buf[i + 2] != _QUOTE:
        return _BAD
    letter = buf[i + 1]
    if letter == _N:
        a = 0
    elif letter == _E:
        a = 1
    elif letter == _S:
        a = 2
    elif letter == _W:
        a = 3
    else:
        return _BAD
    i += 3
    step = -1
    if buf[i] == _COMMA:  # ``, "step": n`` (a client that retries numbers its events)
        i += 1
        i += i < n and buf[i] == _SPACE
        word = _STEP_KEY
        if i + word.shape[0] + 2 > n:
            return _BAD
        for k in range(word.shape[0]):
            if buf[i + k] != word[k]:
                return _BAD
        i += word.shape[0]
        i += buf[i] == _SPACE
        start = i
        v = 0
        while i < n and _ZERO <= buf[i] <= _NINE and i - start < 9:
            v = v * 10 + (buf[i] - _ZERO)
            i += 1
        if i == start or i >= n or buf[start] == _ZERO:
            return _BAD
        step = v
    if buf[i] != _RBRACE:
        return _BAD
    out[count, 0] = r
    out[count, 1] = c
    out[count, 2] = a
    out[count, 3] = -1
    out[count, 4] = -1
    out[count, 5] = step
    return i + 1


@njit(cache=True)
def _common_run(
    buf: ByteArray, i: int, out: IntArray, count: int
) -> tuple[int, int]:  # pragma: no cover - compiled
    """Common events (:func:`_common`) from ``i`` on, as long as they follow one another the
    way json.dumps writes them: (the index past the last one's ``}`` or -1 if there was
    none, the new count). A function of its own, called once per run of such events: with
    this loop inside :func:`_scan`, 500 events took 21 us instead of 16 (measured)."""
    n = buf.shape[0]
    after = _common(buf, i, out, count)
    if after < 0:
        return _BAD, count
    while True:
        count += 1
        j = after + 1  # past ``,`` and json.dumps's optional space, to the next ``{``
        if j + 1 < n and buf[after] == _COMMA and buf[j] == _SPACE:
            j += 1
        if j >= n or buf[after] != _COMMA or buf[j] != _LBRACE or count >= out.shape[0]:
            return after, count
        nxt = _common(buf, j, out, count)
        if nxt < 0:
            return after, count
        after = nxt


@njit(cache=True)
def _scan(buf: ByteArray, out: IntArray) -> int:  # pragma: no cover - compiled
    """Fill ``out`` rows with (row, col, action, next row, next col, step) per event (-1 for
    an absent action, next state or step); the number of events, or -1 if the text is not of the
    plain form (see the module)."""
    n = buf.shape[0]
    i = _skip(buf, 0)
    if i >= n or buf[i] != _LBRACKET:
        return _BAD
    i = _skip(buf, i + 1)
    count = 0
    while True:
        if i >= n or buf[i] != _LBRACE or count >= out.shape[0]:
            return _BAD
        after, count = _common_run(buf, i, out, count)  # the fast path, for common events
        if after < 0:  # an event written another way: the general reader
            i = _skip(buf, i + 1)
            seen = 0
            r = c = nr = nc = a = step = -1
            while True:
                key, i = _key(buf, i)
                if key < 0 or seen & (1 << key):
                    return _BAD
                seen |= 1 << key
                i = _skip(buf, i)
                if i >= n or buf[i] != _COLON:
                    return _BAD
                i = _skip(buf, i + 1)
                if key == 0:
                    r, c, i = _cell(buf, i)
                    if r < 0:
                        return _BAD
                elif key == 1:
                    a, i = _action(buf, i)
                    if a == -2:
                        return _BAD
                elif key == 3:
                    step, i = _int(buf, i)
                    if step < 1:
                        return _BAD
                elif _null(buf, i):
                    i += 4
                else:
                    nr, nc, i = _cell(buf, i)
                    if nr < 0:
                        return _BAD
                i, more = _after_item(buf, i, _RBRACE)
                if more < 0:
                    return _BAD
                if not more:
                    break
            if not seen & 1:
                return _BAD
            out[count, 0] = r
            out[count, 1] = c
            out[count, 2] = a
            out[count, 3] = nr
            out[count, 4] = nc
            out[count, 5] = step
            count += 1
            after = i + 1
        i, more = _after_item(buf, after, _RBRACKET)
        if more < 0:
            return _BAD
        if not more:
            break
    if _skip(buf, i + 1) != n:
        return _BAD
    return count


def scan_events(
    raw: bytes | str, min_events: int = 1
) -> tuple[IntArray, IntArray, IntArray, IntArray] | None:
    """(cells (n, 2), action codes (n,) with -1 for none, next cells (n, 2) with -1 for none,
    steps (n,) with -1 for none) of a plain JSON list of at least ``min_events`` events, or
    ``None`` when ``raw`` is anything else (then the full parser decides)."""
    data = raw.encode() if isinstance(raw, str) else raw
    # an event takes 16 bytes at least (``{"state":[0,0]}`` and a comma)
    most = len(data) // 16 + 1
    if most < max(min_events, 1):
        return None
    out = np.empty((most, 6), dtype=np.int64)
    n = _scan(np.frombuffer(data, dtype=np.uint8), out)
    if n < max(min_events, 1):
        return None
    rows = out[:n]
    return rows[:, 0:2], rows[:, 2], rows[:, 3:5], rows[:, 5]


#: Why :func:`check_moves` refused an event, in the order an event is checked.
OK, STATE_OFF, STATE_WALL, NEXT_OFF, NEXT_WALL, NO_MOVE, NOT_ONE_MOVE, AMBIGUOUS = range(8)


@njit(cache=True)
def _check(
    state_of: IntArray, next_state: IntArray, cells: IntArray, actions: IntArray,
    nexts: IntArray, out: tuple[IntArray, IntArray, IntArray],
) -> tuple[int, int]:  # pragma: no cover - compiled  # fmt: skip
    """Fills (s, a, s') and returns (-1, OK), or (index, reason) of the first bad event."""
    rows, cols = state_of.shape
    out_s, out_a, out_s2 = out
    for i in range(cells.shape[0]):
        r, c = cells[i, 0], cells[i, 1]
        if r < 0 or r >= rows or c < 0 or c >= cols:
            return i, STATE_OFF
        s = state_of[r, c]
        if s < 0:
            return i, STATE_WALL
        a = actions[i]
        has_next = nexts[i, 0] >= 0
        if has_next:
            r2, c2 = nexts[i, 0], nexts[i, 1]
            if r2 >= rows or c2 < 0 or c2 >= cols:
                return i, NEXT_OFF
            s2 = state_of[r2, c2]
            if s2 < 0:
                return i, NEXT_WALL
        elif a < 0:
            return i, NO_MOVE
        else:
            s2 = next_state[s, a]
        if a < 0 or has_next:
            lands = -1
            for k in range(next_state.shape[1]):
                if next_state[s, k] == s2:
                    lands = k
                    break
            if has_next and s2 != s and lands < 0:
                return i, NOT_ONE_MOVE
            if a < 0:
                if s2 == s:
                    return i, AMBIGUOUS
                a = lands
        out_s[i] = s
        out_a[i] = a
        out_s2[i] = s2
    return -1, OK


def check_moves(
    state_of: IntArray, next_state: IntArray, cells: IntArray, actions: IntArray, nexts: IntArray
) -> tuple[tuple[IntArray, IntArray, IntArray], int, int]:
    """(s, a, s') arrays, and (-1, OK) for events that pass every check, else the index of the
    first bad event and its reason (the arrays then hold only the events before it). Cells
    (n, 2) and next cells (n, 2; -1: none) are as read; action codes -1 where none."""
    n = len(cells)
    out = (np.empty(n, np.int64), np.empty(n, np.int64), np.empty(n, np.int64))
    bad, reason = _check(state_of, next_state, cells, actions, nexts, out)
    return out, bad, reason


# ---- writing ------------------------------------------------------------------------------------
def _literal(text: str) -> ByteArray:
    return np.frombuffer(text.encode(), dtype=np.uint8)


#: the fixed parts of a decision's text, in order (see write_decisions)
PIECES = tuple(
    _literal(t)
    for t in ('{"step":', ',"state":[', ',', '],"advise":false,"advice":null,"kl":',
              '],"advise":true,"advice":{"N":', ',"E":', ',"S":', ',"W":', '},"kl":',
              ',"p_normal":', ',"cost":{"advice_count":', ',"total":', ',"benefit":', '}}')
)  # fmt: skip


@njit(cache=True, inline="always")
def _put(out: ByteArray, at: int, src: ByteArray, lo: int, hi: int) -> int:  # pragma: no cover
    """Copy ``src[lo:hi]`` to ``out[at:]``: a plain loop (a slice assignment per piece cost
    about three times as much for these pieces of a few bytes: measured)."""
    for k in range(lo, hi):
        out[at] = src[k]
        at += 1
    return at


@njit(cache=True, inline="always")
def _put_int(out: ByteArray, at: int, v: int) -> int:  # pragma: no cover - compiled
    """The decimal digits of ``v`` >= 0."""
    k = 1
    rest = v
    while rest >= 10:
        rest //= 10
        k += 1
    for j in range(k - 1, -1, -1):
        out[at + j] = 48 + v % 10
        v //= 10
    return at + k


@njit(cache=True, nogil=True)
def tokens(text: ByteArray) -> tuple[IntArray, IntArray]:  # pragma: no cover - compiled
    """Where each number of orjson's text of lists of numbers (``[[a,b,...],[...],...]`` or
    ``[a,b,...]``) starts and ends, every list in order: (starts, ends). Called from Python
    it lets go of the GIL (theta's text of a large map: tens of milliseconds)."""
    lo = np.empty(text.shape[0] // 2 + 1, np.int64)
    hi = np.empty(text.shape[0] // 2 + 1, np.int64)
    n = 0
    start = -1
    for i in range(text.shape[0]):
        b = text[i]
        if b == 91 or b == 44 or b == 93:  # "[", "," or "]": a number ends or starts here
            if start >= 0:
                lo[n] = start
                hi[n] = i
                n += 1
                start = -1
        elif start < 0:
            start = i
    return lo[:n], hi[:n]


@njit(cache=True)
def _write(
    step0: int, states: IntArray, cells: IntArray, advise: BoolArray, counts: IntArray,
    numbers: ByteArray, advice: tuple[ByteArray, IntArray, IntArray, IntArray],
    pieces: tuple[ByteArray, ...],
) -> ByteArray:  # pragma: no cover - compiled  # fmt: skip
    n = states.shape[0]
    lo, hi = tokens(numbers)
    text, a_lo, a_hi, row = advice
    head, state_key, comma, plain, advised, e_key, s_key, w_key, advised_end = pieces[:9]
    p_key, cost_key, total_key, benefit_key, tail = pieces[9:]
    fixed = 0
    for piece in pieces:
        fixed += piece.shape[0]
    bound = 2 + n * (fixed + 3 * 20) + numbers.shape[0]
    for i in range(n):
        if advise[i]:
            r = 4 * row[i]
            bound += a_hi[r + 3] - a_lo[r]
    out = np.empty(bound, np.uint8)
    out[0] = 91  # "["
    at = 1
    for i in range(n):
        if i:
            out[at] = 44  # ","
            at += 1
        at = _put(out, at, head, 0, head.shape[0])
        at = _put_int(out, at, step0 + i)
        at = _put(out, at, state_key, 0, state_key.shape[0])
        at = _put_int(out, at, cells[states[i], 0])
        at = _put(out, at, comma, 0, 1)
        at = _put_int(out, at, cells[states[i], 1])
        if advise[i]:
            r = 4 * row[i]
            at = _put(out, at, advised, 0, advised.shape[0])
            at = _put(out, at, text, a_lo[r], a_hi[r])
            at = _put(out, at, e_key, 0, e_key.shape[0])
            at = _put(out, at, text, a_lo[r + 1], a_hi[r + 1])
            at = _put(out, at, s_key, 0, s_key.shape[0])
            at = _put(out, at, text, a_lo[r + 2], a_hi[r + 2])
            at = _put(out, at, w_key, 0, w_key.shape[0])
            at = _put(out, at, text, a_lo[r + 3], a_hi[r + 3])
            at = _put(out, at, advised_end, 0, advised_end.shape[0])
        else:
            at = _put(out, at, plain, 0, plain.shape[0])
        at = _put(out, at, numbers, lo[i], hi[i])
        at = _put(out, at, p_key, 0, p_key.shape[0])
        at = _put(out, at, numbers, lo[n + i], hi[n + i])
        at = _put(out, at, cost_key, 0, cost_key.shape[0])
        at = _put_int(out, at, counts[i])
        at = _put(out, at, total_key, 0, total_key.shape[0])
        at = _put(out, at, numbers, lo[2 * n + i], hi[2 * n + i])
        at = _put(out, at, benefit_key, 0, benefit_key.shape[0])
        at = _put(out, at, numbers, lo[3 * n + i], hi[3 * n + i])
        at = _put(out, at, tail, 0, tail.shape[0])
    out[at] = 93  # "]"
    return out[: at + 1]


def write_decisions(
    step0: int, states: IntArray, cells: IntArray, advise: BoolArray, counts: IntArray,
    numbers: bytes, advice: tuple[bytes, IntArray, IntArray, IntArray],
) -> bytes:  # fmt: skip
    """The JSON list of decisions ``step0 + i`` at ``cells[states[i]]``. ``numbers`` is orjson's
    text of four lists, kl, p_normal, total cost and benefit (one number per decision);
    ``advice`` is (a text of advice numbers as orjson wrote them, where each number starts and
    ends (:func:`tokens`), and per decision the row of its advice there: four numbers N, E, S,
    W from ``4 * row``)."""
    text, lo, hi, row = advice
    numbers_text = np.frombuffer(numbers, dtype=np.uint8)
    advice_text = np.frombuffer(text, dtype=np.uint8)
    return _write(
        step0, states, cells, advise, counts, numbers_text, (advice_text, lo, hi, row), PIECES
    ).tobytes()
