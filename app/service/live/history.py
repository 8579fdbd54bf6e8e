"""A session's bounded recent history: its path and P(M1 | H) (:class:`Recent`), and the
advice it was given (:class:`AdviceLog`).

Both are rings of fixed size in ``array.array`` buffers (a single event sets an item at a
third of numpy's cost; batches write through numpy views), so a live session's memory does
not grow with its length, and 100,000 sessions hold one each (docs/PERFORMANCE.md, memory).
"""

from __future__ import annotations

from array import array
from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from app.advice.models import AdviceTables
from app.arrays import IntArray

Advice = tuple[float, ...]


def _ring_spans(count: int, k: int, size: int) -> tuple[int, int, int]:
    """Where the last ``m = min(k, size)`` of ``k`` values appended to a ring of ``size``
    after ``count`` items go: ring[start:start + first] gets the first ``first`` of them and
    ring[:m - first] the rest (two slices: no index arrays). Returns (m, start, first)."""
    m = min(k, size)
    start = (count + k - m) % size
    return m, start, min(m, size - start)


class Recent:
    """The last ``size`` numbers pushed, oldest first, in one ring (8 bytes or less a number,
    where a deque of Python numbers costs about 32). The ring is an ``array.array``, whose
    items a single event sets at a third of numpy's cost; batches go through a numpy view."""

    __slots__ = ("_buf", "_count")

    def __init__(self, size: int, dtype: type[np.generic], first: float):
        kind = np.dtype(dtype)
        self._buf: array[Any] = array(kind.char, bytes(kind.itemsize * size))
        self._buf[0] = first
        self._count = 1

    def _view(self) -> npt.NDArray[Any]:
        return np.frombuffer(self._buf, dtype=self._buf.typecode)

    def push(self, value: float) -> None:
        self._buf[self._count % len(self._buf)] = value
        self._count += 1

    def extend(self, values: Sequence[float] | npt.NDArray[Any]) -> None:
        size, k = len(self._buf), len(values)
        if k == 1:  # one event per request: no index arrays
            self.push(values[0])
            return
        m, start, first = _ring_spans(self._count, k, size)
        view, tail = self._view(), values[k - m :]
        view[start : start + first] = tail[:first]
        view[: m - first] = tail[first:]
        self._count += k

    def oldest(self) -> Any:
        """The oldest number kept (no copy: for a check made at every write)."""
        size = len(self._buf)
        return self._buf[(self._count - min(self._count, size)) % size]

    def tolist(self) -> list[Any]:
        out: list[Any] = self.array().tolist()
        return out

    def array(self) -> npt.NDArray[Any]:
        """The numbers kept, oldest first (a copy)."""
        size = len(self._buf)
        m = min(self._count, size)
        return self._view()[np.arange(self._count - m, self._count) % size]

    def __len__(self) -> int:
        return min(self._count, len(self._buf))


ROWS = 4  # an advice log's rows: step, state, tables index, when (ms)


class AdviceLog:
    """The last ``size`` pieces of advice as (step, state, tables that advised), oldest first,
    in one numpy ring (the tables as an index into a short list: they change only when the
    prior does), with when each was given (milliseconds into the session, for the retention
    of where explorers were: :meth:`forget_before`). About 1.7 kB for 50 entries where a deque
    of tuples takes about 7 kB: 100,000 sessions hold one each (docs/PERFORMANCE.md, memory)."""

    __slots__ = ("_buf", "_count", "_done", "_own", "_rows_out", "_tables", "_width", "_written")

    def __init__(self, size: int):
        # rows step, state, index into _tables, when; an array.array, as in Recent
        self._buf = array("q", bytes(8 * ROWS * size))
        self._count = 0
        self._tables: list[AdviceTables] = []
        self._width = 4  # the actions of the tables' domain (6 on a map of several floors)
        # the advice itself, for advisors whose advice is not theta_s (made at the first one)
        self._own: npt.NDArray[np.float64] | None = None
        self._written: dict[str, bytes] | None = None  # what written() gave, while unchanged
        # for written(): each slot's advice written out, for the entries up to ``_done``
        self._rows_out: npt.NDArray[np.float64] | None = None
        self._done = 0

    def extend(
        self, steps: IntArray, states: IntArray, tables: AdviceTables,
        advice: npt.NDArray[np.float64] | None = None, when: int = 0,
    ) -> None:  # fmt: skip
        """Log advice given at ``states`` (arrays) at ``when`` (ms): theta_s of ``tables``, or
        the rows of ``advice`` (one per entry) for advisors whose advice is not theta_s."""
        self._written = None
        k, size = len(steps), len(self._buf) // ROWS
        if not k:
            return
        which, buf = self._index(tables), self._rows()
        m, start, first = _ring_spans(self._count, k, size)
        spans = (
            (slice(start, start + first), slice(0, first)),
            (slice(0, m - first), slice(first, m)),
        )
        tail_steps, tail_states = steps[k - m :], states[k - m :]
        for ring, part in spans:
            buf[0, ring] = tail_steps[part]
            buf[1, ring] = tail_states[part]
            buf[2, ring] = which
            buf[3, ring] = when
        if advice is not None and self._own is None:
            self._own = np.full((size, self._width), np.nan)
        if self._own is not None:  # NaN rows: theta_s of the tables
            rows = np.full((m, self._width), np.nan) if advice is None else advice[k - m :]
            for ring, part in spans:
                self._own[ring] = rows[part]
        self._count += k

    def add(
        self, step: int, state: int, tables: AdviceTables, advice: Advice | None, when: int = 0
    ) -> None:
        """:meth:`extend` for one piece of advice (``advice`` None: theta_s of ``tables``;
        pass it only for advisors whose advice is not theta_s), without index arrays."""
        self._written = None
        which, buf, size = self._index(tables), self._buf, len(self._buf) // ROWS
        at = self._count % size
        buf[at], buf[size + at], buf[2 * size + at] = step, state, which
        buf[3 * size + at] = when
        if advice is not None and self._own is None:
            self._own = np.full((size, self._width), np.nan)
        if self._own is not None:  # NaN row: theta_s of the tables
            self._own[at] = np.nan if advice is None else advice
        self._count += 1

    def _index(self, tables: AdviceTables) -> int:
        """The index of ``tables`` in the list: the last one, appended (after a compaction)
        when it is not already."""
        if not self._tables or self._tables[-1] is not tables:
            self._compact()
            self._tables.append(tables)
            self._width = tables.n_actions
        return len(self._tables) - 1

    def _rows(self) -> npt.NDArray[np.int64]:
        """The ring as a (4, size) numpy view."""
        return np.frombuffer(self._buf, dtype=np.int64).reshape(ROWS, -1)

    def _compact(self) -> None:
        """Forget tables no entry refers to any more (so the list stays short).

        Entries are written oldest first and each table of the list got entries when it was
        appended, so the tables in use are those from the oldest entry's to the last: the
        unused ones are a prefix. (This runs at nearly every piece of advice while the prior
        changes often, e.g. one trajectory per ingest request: O(1), not a set.)"""
        if len(self._tables) < 4:
            return
        size = len(self._buf) // ROWS
        oldest = (self._count - min(self._count, size)) % size
        first = self._buf[2 * size + oldest]
        if first:
            self._rows()[2] -= first  # slots not yet written are never read
            del self._tables[:first]

    def _order(self) -> npt.NDArray[np.int64]:
        size = len(self._buf) // ROWS
        m = min(self._count, size)
        return np.arange(self._count - m, self._count) % size

    def oldest_when(self) -> int | None:
        """When the oldest entry was logged (ms; None: no entry), without index arrays."""
        if not self._count:
            return None
        size = len(self._buf) // ROWS
        return int(self._buf[3 * size + (self._count - min(self._count, size)) % size])

    def forget_before(self, when: int) -> int:
        """Drop the entries logged before ``when`` (ms): how many are left."""
        self._written = None
        order = self._order()
        times = self._rows()[3, order]
        keep = int(np.count_nonzero(times >= when))  # times only grow along the ring
        if keep < len(order):  # the kept ones are the newest: to the start, in order
            newest = order[len(order) - keep :]
            self._rows()[:, :keep] = self._rows()[:, newest]
            if self._own is not None:
                self._own[:keep] = self._own[newest]
            self._count = keep
            self._rows_out = None
        return keep

    def written(self) -> dict[str, bytes]:
        """The entries, oldest first, as arrays of bytes with their advice written out (theta_s
        read now for the entries whose advice is the tables': who reads them back may hold
        other tables). :meth:`read` takes them back. Made again only after a change."""
        if self._written is not None:
            return self._written
        size = len(self._buf) // ROWS
        if self._rows_out is None:  # made (again): every entry kept is new to it
            self._rows_out = np.full((size, self._width), np.nan)
            self._done = self._count - min(self._count, size)
        new = range(max(self._done, self._count - size), self._count)
        if len(new) <= 4:  # one or two since the last call, as a rule: no index arrays
            for i in new:
                at = i % size
                own = None if self._own is None else self._own[at]
                if own is not None and own[0] == own[0]:  # not NaN: the advisor's own advice
                    self._rows_out[at] = own
                else:
                    state, t = self._buf[size + at], self._buf[2 * size + at]
                    self._rows_out[at] = self._tables[t].theta[state]
        else:  # a batch's worth: the same, by arrays
            slots = np.arange(new.start, new.stop) % size
            rows = self._rows()
            which, states = rows[2, slots], rows[1, slots]
            if which[0] == which[-1]:  # one table, as a rule (indices only grow along the ring)
                out = self._tables[int(which[0])].theta[states]
            else:
                out = np.empty((len(slots), self._width))
                for t in np.unique(which).tolist():
                    pick = which == t
                    out[pick] = self._tables[t].theta[states[pick]]
            if self._own is not None:  # the advisor's own advice where it gave it
                own = self._own[slots]
                mine = ~np.isnan(own[:, 0])
                out[mine] = own[mine]
            self._rows_out[slots] = out
        self._done = self._count
        order = self._order()
        rows = self._rows()[:, order]
        advice = self._rows_out[order]
        self._written = {
            "steps": rows[0].tobytes(), "states": rows[1].tobytes(), "when": rows[3].tobytes(),
            "advice": advice.tobytes(),
        }  # fmt: skip
        return self._written

    @classmethod
    def read(cls, size: int, v: dict[str, bytes], tables: AdviceTables) -> AdviceLog:
        """A log of ``size`` entries holding what :meth:`written` wrote (each with its own
        advice; ``tables`` stands for the table index, never read)."""
        log = cls(size)
        steps = np.frombuffer(v["steps"], dtype=np.int64)
        advice = np.frombuffer(v["advice"], dtype=np.float64).reshape(-1, tables.n_actions)
        if len(steps):
            log.extend(
                steps, np.frombuffer(v["states"], dtype=np.int64), tables, advice,
                0,
            )  # fmt: skip
            when = np.frombuffer(v["when"], dtype=np.int64)
            log._rows()[3, : len(when)] = when[-size:]
        return log

    def items(self) -> list[tuple[int, int, AdviceTables | Advice]]:
        order = self._order()
        steps, states, which, _ = self._rows()[:, order].tolist()
        if self._own is None:
            return [(a, s, self._tables[t]) for a, s, t in zip(steps, states, which, strict=True)]
        own = self._own[order].tolist()
        return [
            (a, s, self._tables[t] if o[0] != o[0] else tuple(o))  # NaN: theta
            for a, s, t, o in zip(steps, states, which, own, strict=True)
        ]
