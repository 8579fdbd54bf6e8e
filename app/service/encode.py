"""Decisions as JSON text, written directly: several times faster than building dicts.

Per state, the part of a decision that depends only on the cell and on whether it advises
(``"state"``, ``"advise"``, ``"advice"``) is precomputed once per prior table; floats are
formatted in Rust (pydantic-core, shortest round-trip text), which is faster than ``repr``.
A batch of more than :data:`SMALL` decisions from the compiled advisor loop is assembled from
those same texts by a numba loop (:func:`_assemble`) instead of one f-string per decision: the
same bytes (``tests/service/test_encode.py``), about five times faster.
"""

from __future__ import annotations

import weakref
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt
import pydantic_core
from numba import njit

from app import protocol
from app.advice.advisor import Decision
from app.advice.models import AdviceTables
from app.domain.grid import GridDomain
from app.service.stream_advisor import DecisionArrays, DecisionColumns

_FRAGMENTS: weakref.WeakKeyDictionary[AdviceTables, tuple[list[str], list[str]]] = (
    weakref.WeakKeyDictionary()
)


def fragments(tables: AdviceTables, cell_json: list[str]) -> tuple[list[str], list[str]]:
    """Per state, the JSON between ``"step"`` and the KL value, without and with advice (the
    advice being theta_s of ``tables``); built once per tables."""
    out = _FRAGMENTS.get(tables)
    if out is None:
        advice = [
            f'{{"N":{n!r},"E":{e!r},"S":{s!r},"W":{w!r}}}' for n, e, s, w in tables.theta.tolist()
        ]
        pairs = zip(cell_json, advice, strict=True)
        out = (
            [f',"state":{c},"advise":false,"advice":null,"kl":' for c in cell_json],
            [f',"state":{c},"advise":true,"advice":{a},"kl":' for c, a in pairs],
        )
        _FRAGMENTS[tables] = out
    return out


IntArray = npt.NDArray[np.int64]
ByteArray = npt.NDArray[np.uint8]
#: Batches up to this size are written by the f-string loop.
SMALL = 8


@dataclass(frozen=True, slots=True)
class Packed:
    """The :func:`fragments` as one byte string: fragment ``k = advise * n_states + state``
    is ``data[offsets[k]:offsets[k + 1]]``."""

    data: ByteArray
    offsets: IntArray


_PACKED: weakref.WeakKeyDictionary[AdviceTables, Packed] = weakref.WeakKeyDictionary()


def packed(tables: AdviceTables, cell_json: list[str]) -> Packed:
    """:func:`fragments` packed for :func:`_assemble`, once per tables."""
    out = _PACKED.get(tables)
    if out is None:
        plain, advised = fragments(tables, cell_json)
        texts = [t.encode() for t in (*plain, *advised)]
        offsets = np.zeros(len(texts) + 1, dtype=np.int64)
        np.cumsum([len(t) for t in texts], out=offsets[1:])
        out = Packed(np.frombuffer(b"".join(texts), dtype=np.uint8), offsets)
        _PACKED[tables] = out
    return out


def _literal(text: str) -> ByteArray:
    return np.frombuffer(text.encode(), dtype=np.uint8)


# the fixed parts of a decision's text, in order (see encode_decisions)
_PIECES = (
    _literal('{"step":'), _literal(',"p_normal":'), _literal(',"cost":{"advice_count":'),
    _literal(',"total":'), _literal(',"benefit":'), _literal("}}"),
)  # fmt: skip


@njit(cache=True)
def _digits(v: int) -> int:  # pragma: no cover - compiled
    k = 1
    while v >= 10:
        v //= 10
        k += 1
    return k


@njit(cache=True)
def _put(out: ByteArray, at: int, src: ByteArray, lo: int, hi: int) -> int:  # pragma: no cover
    out[at : at + hi - lo] = src[lo:hi]
    return at + hi - lo


@njit(cache=True)
def _put_int(out: ByteArray, at: int, v: int) -> int:  # pragma: no cover - compiled
    k = _digits(v)
    for j in range(k - 1, -1, -1):
        out[at + j] = 48 + v % 10
        v //= 10
    return at + k


@njit(cache=True)
def _assemble(
    step0: int,
    states: IntArray,
    advise: npt.NDArray[np.bool_],
    counts: IntArray,
    floats: ByteArray,
    frag: tuple[ByteArray, IntArray, int],
    pieces: tuple[ByteArray, ByteArray, ByteArray, ByteArray, ByteArray, ByteArray],
) -> ByteArray:  # pragma: no cover - compiled
    """The JSON list of decisions ``step0 + i``, floats taken from ``floats``: the JSON text of
    four lists (kl, p_normal, total, benefit) as pydantic-core wrote them."""
    n = states.shape[0]
    data, offsets, n_states = frag
    head, p_key, cost_key, total_key, benefit_key, tail = pieces
    # where each float's text starts and ends in ``floats``: [[a,b,...],[...],[...],[...]]
    lo, hi = np.empty((4, n), np.int64), np.empty((4, n), np.int64)
    i = 1
    for col in range(4):
        i += 1  # the column's "["
        for k in range(n):
            lo[col, k] = i
            while floats[i] != 44 and floats[i] != 93:  # up to "," or "]"
                i += 1
            hi[col, k] = i
            i += 1
        if n == 0:
            i += 1
        i += 1  # the "," between columns
    fixed = (head.shape[0] + p_key.shape[0] + cost_key.shape[0] + total_key.shape[0]
             + benefit_key.shape[0] + tail.shape[0])  # fmt: skip
    size = 1 + max(n - 1, 0) + 1
    for k in range(n):
        f = advise[k] * n_states + states[k]
        size += fixed + _digits(step0 + k) + _digits(counts[k]) + offsets[f + 1] - offsets[f]
        for col in range(4):
            size += hi[col, k] - lo[col, k]
    out = np.empty(size, np.uint8)
    out[0] = 91  # "["
    at = 1
    for k in range(n):
        if k:
            out[at] = 44  # ","
            at += 1
        f = advise[k] * n_states + states[k]
        at = _put(out, at, head, 0, head.shape[0])
        at = _put_int(out, at, step0 + k)
        at = _put(out, at, data, offsets[f], offsets[f + 1])
        at = _put(out, at, floats, lo[0, k], hi[0, k])
        at = _put(out, at, p_key, 0, p_key.shape[0])
        at = _put(out, at, floats, lo[1, k], hi[1, k])
        at = _put(out, at, cost_key, 0, cost_key.shape[0])
        at = _put_int(out, at, counts[k])
        at = _put(out, at, total_key, 0, total_key.shape[0])
        at = _put(out, at, floats, lo[2, k], hi[2, k])
        at = _put(out, at, benefit_key, 0, benefit_key.shape[0])
        at = _put(out, at, floats, lo[3, k], hi[3, k])
        at = _put(out, at, tail, 0, tail.shape[0])
    out[at] = 93  # "]"
    return out


def _float_texts(*columns: list[float]) -> list[list[str]]:
    """Each float as shortest round-trip JSON text, formatted in Rust (pydantic-core), which
    is several times faster than ``repr`` per float."""
    text = pydantic_core.to_json(columns).decode()
    return [col.split(",") for col in text[2:-2].split("],[")]


def encode_decisions(
    cols: DecisionColumns,
    parts: tuple[list[str], list[str]],
    single: bool,
    packed: Packed | None = None,
) -> str:
    """The decisions as JSON (a list, or one object when ``single``); ``parts`` are the
    :func:`fragments` of the tables that made them, ``packed`` the same :func:`packed` (for
    the compiled path: a list of more than :data:`SMALL` decisions from the compiled loop)."""
    if packed is not None and not single and cols.arrays is not None and len(cols) > SMALL:
        states, advise, counts = cols.arrays
        floats = pydantic_core.to_json((cols.kl, cols.p_normal, cols.total_cost, cols.benefit))
        out = _assemble(
            cols.step[0],
            np.ascontiguousarray(states, dtype=np.int64),
            np.ascontiguousarray(advise, dtype=np.bool_),
            np.ascontiguousarray(counts, dtype=np.int64),
            np.frombuffer(floats, dtype=np.uint8),
            (packed.data, packed.offsets, len(parts[0])),
            _PIECES,
        )
        return out.tobytes().decode("ascii")
    kl, p_normal, total, benefit = _float_texts(
        cols.kl, cols.p_normal, cols.total_cost, cols.benefit
    )
    frags: Sequence[Sequence[str]] = parts
    if cols.advice is not None:  # advice that is not theta_s of the tables (goal_aware)
        own = [_with_advice(parts[0][s], a) for s, a in zip(cols.state, cols.advice, strict=True)]
        # decision i now reads fragment i (its own advice), whether advised or not
        frags, cols = (own, own), replace(cols, state=list(range(len(own))))
    texts = [
        f'{{"step":{step}{frags[adv][s]}{k},"p_normal":{p},'
        f'"cost":{{"advice_count":{count},"total":{t},"benefit":{b}}}}}'
        for step, s, adv, k, p, count, t, b in zip(
            cols.step, cols.state, cols.advise, kl, p_normal, cols.advice_count, total, benefit,
            strict=False,  # an empty batch gives one empty text per float column
        )
    ]  # fmt: skip
    if single:
        return texts[0]
    return "[" + ",".join(texts) + "]"


def encode_one(d: Decision, parts: tuple[list[str], list[str]], own_advice: bool) -> str:
    """One decision as JSON: ``encode_decisions(DecisionColumns.of([d], own_advice), parts,
    True)``, the same bytes (``tests/service/test_encode.py``), without building columns.
    ``own_advice``: the advice is ``d.advice`` (goal_aware), not theta_s of the tables."""
    kl, p, total, benefit = (
        pydantic_core.to_json((d.kl, d.p_normal, d.total_cost, d.benefit)).decode()[1:-1].split(",")
    )
    frag = _with_advice(parts[0][d.state], d.advice) if own_advice else parts[d.advise][d.state]
    return (
        f'{{"step":{d.step}{frag}{kl},"p_normal":{p},'
        f'"cost":{{"advice_count":{d.advice_count},"total":{total},"benefit":{benefit}}}}}'
    )


_CELLS: weakref.WeakKeyDictionary[GridDomain, npt.NDArray[np.int32]] = weakref.WeakKeyDictionary()


def encode_binary(out: DecisionArrays, domain: GridDomain) -> bytes:
    """Decisions as one binary frame (:mod:`app.protocol`): the advice of each advising
    decision is theta_s of the tables that decided, or its own (goal_aware)."""
    cells = _CELLS.get(domain)
    if cells is None:
        cells = _CELLS[domain] = domain.cells.astype(np.int32)
    advise = out.advise
    advice = out.advice if out.advice is not None else out.tables.theta[out.state[advise]]
    return protocol.pack(
        out.first_step, out.kappa, out.count_before, out.benefit_before, out.kl, out.p_normal,
        advice, cells[out.state], advise,
    )  # fmt: skip


def _with_advice(fragment: str, advice: tuple[float, float, float, float] | None) -> str:
    """A state's fragment without advice turned into one with ``advice`` (if not None)."""
    if advice is None:
        return fragment
    n, e, so, w = (repr(float(v)) for v in advice)
    text = f'"advise":true,"advice":{{"N":{n},"E":{e},"S":{so},"W":{w}}}'
    return fragment.replace('"advise":false,"advice":null', text)


def decision_dict(d: Decision, domain: GridDomain) -> dict[str, Any]:
    """One decision in the API's shape (for responses built as models, not on the hot path)."""
    return {
        "step": d.step,
        "state": domain.cell(d.state),
        "advise": d.advise,
        "advice": dict(zip("NESW", d.advice, strict=True)) if d.advice else None,
        "kl": d.kl,
        "p_normal": d.p_normal,
        "cost": {"advice_count": d.advice_count, "total": d.total_cost, "benefit": d.benefit},
    }
