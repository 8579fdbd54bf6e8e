"""The decisions of a session's last steps, kept so that a retried event is answered again
instead of being applied twice.

An event may carry ``"step": n``, the session step it is meant to be (the first event of a
session is step 1). A step the session has already applied is answered from here with the
decision it got, and nothing is applied; a step that is neither applied nor the next one is
refused (409). :class:`Replay` keeps the last ``limit`` decisions in one ring of 53-byte rows
(state, advised, KL, P(M1 | H), the advice; 69 bytes on a map of several floors, six actions'
advice), grown as the session goes up to ``limit``; the
running advice count and benefit of each row follow exactly from the figures before the
oldest row (the advisor adds them up one decision at a time, as ``np.add.accumulate`` does).
"""

from __future__ import annotations

import struct
from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from app.advice.advisor import Decision, DecisionBatch
from app.arrays import Moves

#: a row of each width of advice (the domain's actions: 4, or 6 on a map of several floors)
ROWS = {
    w: np.dtype(
        [("state", "<i4"), ("advise", "u1"), ("kl", "<f8"), ("p", "<f8"), ("advice", "<f8", (w,))]
    )
    for w in (4, 6)
}
ROW = ROWS[4]
#: a row as packed bytes (``ROWS`` have no padding), and the (advise, kl) of one
_PACKED = {w: struct.Struct(f"<iBdd{w}d") for w in ROWS}
_OLD = struct.Struct("<4xBd")
_NO_ADVICE = {w: (np.nan,) * w for w in ROWS}
assert all(_PACKED[w].size == ROWS[w].itemsize for w in ROWS)
DEFAULT_STEPS = 500


class StepConflict(ValueError):
    """An event's ``step`` is not the session's next one, nor one it can answer again."""


class Replay:
    """The last ``limit`` decisions of one session (0: none kept) of ``width`` actions."""

    __slots__ = ("_benefit_base", "_count", "_count_base", "_rows", "limit", "width")

    def __init__(self, limit: int, width: int = 4):
        self.limit = limit
        self.width = width
        self._rows: npt.NDArray[np.void] | None = None  # made at the first decision, then grown
        self._count = 0  # rows written since the ring was made (or grown, or restarted)
        self._count_base = 0  # advice count and benefit before the oldest row kept
        self._benefit_base = 0.0

    @staticmethod
    def footprint(limit: int, width: int = 4) -> int:
        """Bytes a ring of ``limit`` rows takes at most."""
        return ROWS[width].itemsize * limit

    @property
    def kept(self) -> int:
        return 0 if self._rows is None else min(self._count, len(self._rows))

    def _ordered(self) -> npt.NDArray[np.void]:
        rows, m = self._rows, self.kept
        if rows is None or not m:
            return np.zeros(0, dtype=ROWS[self.width])
        return rows[np.arange(self._count - m, self._count) % len(rows)]

    def _room(self, k: int) -> npt.NDArray[np.void]:
        """The ring, grown (up to ``limit`` rows) to keep ``k`` more; the figures of the rows
        that ``k`` more will overwrite moved into the base."""
        rows, kept = self._rows, self.kept
        need = min(self.limit, kept + k)
        if rows is None or len(rows) < need:
            size = min(self.limit, max(need, 2 * (0 if rows is None else len(rows)), 8))
            grown = np.zeros(size, dtype=ROWS[self.width])
            grown[:kept] = self._ordered()
            self._rows = rows = grown
            self._count = kept
        gone = kept + k - len(rows)
        if gone > 0:
            old = rows[np.arange(self._count - kept, self._count - kept + gone) % len(rows)]
            on = old["advise"].astype(bool)
            self._count_base += int(np.count_nonzero(on))
            b = self._benefit_base
            for kl in old["kl"][on].tolist():  # one at a time, as the advisor added them
                b += kl
            self._benefit_base = b
        return rows

    def add_one(self, d: Decision) -> None:
        """Keep one decision (the newest). The row is read and written as packed bytes: a
        numpy row's fields cost about 7 us a decision, this about 1 (one event per request
        is the REST route's common case); the bytes are those numpy would write."""
        limit = self.limit
        if not limit:
            return
        rows, count = self._rows, self._count
        if rows is None or (count >= len(rows) and len(rows) < limit):
            rows = self._room(1)  # made, or grown (the first ``limit`` decisions only)
            count = self._count
        at, packed = count % len(rows), _PACKED[self.width]
        if count >= len(rows):  # full: the oldest row, overwritten, goes into the base
            advised, kl = _OLD.unpack_from(rows, at * packed.size)  # type: ignore[arg-type]
            if advised:
                self._count_base += 1
                self._benefit_base += kl
        advise = bool(d.advise)
        advice = d.advice if advise and d.advice is not None else _NO_ADVICE[self.width]
        row = (d.state, advise, d.kl, d.p_normal, *advice)
        packed.pack_into(rows, at * packed.size, *row)  # type: ignore[arg-type]  # a buffer
        self._count = count + 1

    def add(self, b: DecisionBatch) -> None:
        """Keep a batch of decisions (the newest)."""
        n = len(b)
        if not self.limit or not n:
            return
        if n >= self.limit:  # only its last ``limit`` fit: everything before is the base
            cut = n - self.limit
            self.restart(
                int(b.advice_count[cut - 1]) if cut else b.count_before,
                float(b.benefit[cut - 1]) if cut else b.benefit_before,
            )
            b, n = part(b, cut, n), self.limit
        rows = self._room(n)
        new = np.zeros(n, dtype=ROWS[self.width])
        new["state"], new["advise"], new["kl"], new["p"] = b.state, b.advise, b.kl, b.p_normal
        new["advice"] = np.nan
        new["advice"][b.advise] = b.advice
        rows[np.arange(self._count, self._count + n) % len(rows)] = new
        self._count += n

    def restart(self, count_before: int, benefit_before: float) -> None:
        """Forget every row: the next decision kept follows these figures."""
        self._rows, self._count = None, 0
        self._count_base, self._benefit_base = count_before, benefit_before

    def answer(self, first: int, n: int, last_step: int, kappa: float) -> DecisionBatch | None:
        """The decisions of steps ``first`` .. ``first + n - 1`` (the session's newest
        decision is step ``last_step``), or None when they are not all kept."""
        kept = self.kept
        oldest = last_step - kept + 1
        if not kept or n < 1 or first < oldest or first + n - 1 > last_step:
            return None
        rows = self._ordered()
        on = rows["advise"].astype(bool)
        count = self._count_base + np.cumsum(on, dtype=np.int64)
        gains = np.where(on, rows["kl"], 0.0)
        benefit = np.add.accumulate(np.concatenate([[self._benefit_base], gains]))[1:]
        lo, hi = first - oldest, first - oldest + n
        sl = rows[lo:hi]
        adv = sl["advise"].astype(bool)
        return DecisionBatch(
            first, sl["state"].astype(np.int64), adv, sl["kl"].copy(), sl["p"].copy(),
            count[lo:hi].copy(), benefit[lo:hi].copy(), sl["advice"][adv].copy(), kappa,
            int(count[lo - 1]) if lo else self._count_base,
            float(benefit[lo - 1]) if lo else self._benefit_base, None,
        )  # fmt: skip

    def state(self) -> dict[str, object]:
        """What :meth:`of` takes back (the rows oldest first, and the base)."""
        return {
            "rows": self._ordered().tobytes(), "count_base": self._count_base,
            "benefit_base": self._benefit_base,
        }  # fmt: skip

    @classmethod
    def of(cls, limit: int, state: dict[str, object] | None, width: int = 4) -> Replay:
        """A ring of ``limit`` rows of ``width`` actions holding what :meth:`state` wrote (its
        newest rows, if ``limit`` is smaller now)."""
        r = cls(limit, width)
        if not state or not limit:
            return r
        row = ROWS[width]
        rows = np.frombuffer(state["rows"], dtype=row)  # type: ignore[call-overload]
        r._count_base = int(state["count_base"])  # type: ignore[call-overload]
        r._benefit_base = float(state["benefit_base"])  # type: ignore[arg-type]
        if len(rows) > limit:  # the oldest go into the base
            old = rows[: len(rows) - limit]
            on = old["advise"].astype(bool)
            r._count_base += int(np.count_nonzero(on))
            for kl in old["kl"][on].tolist():
                r._benefit_base += kl
            rows = rows[len(rows) - limit :]
        if len(rows):
            r._rows = np.zeros(min(limit, max(len(rows), 8)), dtype=row)
            r._rows[: len(rows)] = rows
            r._count = len(rows)
        return r


def part(b: DecisionBatch, lo: int, hi: int) -> DecisionBatch:
    """Decisions ``lo`` .. ``hi - 1`` of ``b`` as a batch of their own."""
    first = int(np.count_nonzero(b.advise[:lo]))
    last = first + int(np.count_nonzero(b.advise[lo:hi]))
    return DecisionBatch(
        b.first_step + lo, b.state[lo:hi], b.advise[lo:hi], b.kl[lo:hi], b.p_normal[lo:hi],
        b.advice_count[lo:hi], b.benefit[lo:hi], b.advice[first:last], b.kappa,
        int(b.advice_count[lo - 1]) if lo else b.count_before,
        float(b.benefit[lo - 1]) if lo else b.benefit_before, b.advised_from,
    )  # fmt: skip


def retried(
    session_id: str, steps: int, first_step: int | None, moves: Moves,
    answered: Callable[[int, int], DecisionBatch | None], kept: int,
) -> tuple[DecisionBatch | None, Moves | None]:  # fmt: skip
    """(the decisions of the moves whose steps the session applied already, the moves still to
    apply), for a session that has applied ``steps`` and keeps the decisions of its last
    ``kept`` (``answered(first, n)``: those of steps first .. first + n - 1, or None). A retry
    is answered what it was answered, and nothing is applied twice; StepConflict when the
    first step is beyond the next one, was applied with another move, or was applied and its
    decision is no longer kept."""
    nxt = steps + 1
    if first_step is None or first_step == nxt:
        return None, moves
    if first_step > nxt:
        raise StepConflict(
            f"step {first_step} is not the next step of session {session_id}: it has "
            f"applied {steps} (the next is {nxt}); send the events in between first"
        )
    n = len(moves[0])
    k = min(n, nxt - first_step)
    got = answered(first_step, k)
    if got is None:
        kept_text = f"steps {nxt - kept} to {steps}" if kept else "none"
        raise StepConflict(
            f"step {first_step} was applied already (session {session_id} is at step "
            f"{steps}) and its decision is no longer kept for a retry (kept: {kept_text}); "
            "nothing was applied"
        )
    same = got.state == moves[2][:k]
    if not same.all():
        bad = first_step + int(np.argmin(same))
        raise StepConflict(f"step {bad} was applied already with another move; nothing was applied")
    if k == n:
        return got, None
    return got, (moves[0][k:], moves[1][k:], moves[2][k:])
