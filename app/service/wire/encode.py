"""Decisions out: JSON (orjson) and the websocket's binary frames (:mod:`advisor_client.protocol`).

* one decision: :func:`decision_json`, a dict written by orjson;
* a batch: :func:`batch_json`, orjson's texts of the numbers (written from the numpy columns,
  no Python floats; theta's once per tables) laid out by a compiled loop
  (:func:`app.service.wire.compiled.write_decisions`),
  which is several times faster than orjson over a list of dicts (measured side by side:
  docs/PERFORMANCE.md); the same bytes as :func:`decision_json` decision for decision
  (``tests/service/wire/test_encode.py``);
* binary: :func:`batch_binary`, the same decisions at full precision in columns.

Every number's text is orjson's shortest round-trip form, on every path.
"""

from __future__ import annotations

import weakref
from collections.abc import Sequence
from typing import Any

import numpy as np
import orjson
from advisor_client import protocol

from app.advice.advisor import Decision, DecisionBatch
from app.advice.models import AdviceTables
from app.arrays import FloatArray, IntArray
from app.domain.building import ACTIONS, Building, Domain
from app.service.wire.compiled import tokens, write_decisions

NUMPY = orjson.OPT_SERIALIZE_NUMPY


def advice_dict(advice: Sequence[float]) -> dict[str, float]:
    """Advice by action: N, E, S, W, and U, D on a map of several floors."""
    return dict(zip(ACTIONS[: len(advice)], advice, strict=True))


def decision_dict(d: Decision, domain: Domain) -> dict[str, Any]:
    """One decision in the API's shape (``DecisionPublic``)."""
    return {
        "step": d.step,
        "state": domain.cell(d.state),
        "advise": d.advise,
        "advice": None if d.advice is None else advice_dict(d.advice),
        "kl": d.kl,
        "p_normal": d.p_normal,
        "cost": {"advice_count": d.advice_count, "total": d.total_cost, "benefit": d.benefit},
    }


def decision_json(d: Decision, domain: Domain, leads_to: Any = None) -> bytes:
    """One decision as JSON; ``leads_to``: the destination its advice leads to (a
    ``DestinationPublic`` as a dict), written only when given."""
    out = decision_dict(d, domain)
    if leads_to is not None:
        out["leads_to"] = leads_to
    return orjson.dumps(out)


def batch_json(out: DecisionBatch, domain: Domain) -> bytes:
    """A batch of decisions as a JSON list (on a map of several floors written by orjson
    from a dict a decision: the compiled layout writes four actions and two coordinates)."""
    if isinstance(domain, Building):
        return orjson.dumps(batch_dicts(out, domain))
    numbers = orjson.dumps((out.kl, out.p_normal, out.total_cost, out.benefit), option=NUMPY)
    if out.advised_from is not None:  # theta_s: the tables' text, made once
        text, lo, hi = theta_text(out.advised_from)
        row = out.state
    else:  # the advisor's own advice: this answer's rows
        text = orjson.dumps(out.advice.reshape(-1), option=NUMPY)
        lo, hi = tokens(np.frombuffer(text, dtype=np.uint8))
        row = np.cumsum(out.advise) - 1
    return write_decisions(
        out.first_step, out.state, domain.cells, out.advise, out.advice_count, numbers,
        (text, lo, hi, row),
    )  # fmt: skip


_THETA_TEXT: weakref.WeakKeyDictionary[AdviceTables, tuple[bytes, IntArray, IntArray]] = (
    weakref.WeakKeyDictionary()
)


#: Numbers orjson writes at a time in :func:`numbers_text`
TEXT_SLICE = 65_536


def numbers_text(values: FloatArray) -> bytes:
    """``orjson.dumps(values)`` of a 1-D array, the same bytes, written a slice at a time:
    orjson holds the GIL from its start to its end (a million numbers, theta of a
    250,000-cell map: 50 ms here), while between slices another thread can run."""
    n = values.shape[0]
    if n <= TEXT_SLICE:
        return orjson.dumps(values, option=NUMPY)
    last = (n - 1) // TEXT_SLICE * TEXT_SLICE
    # each slice's text without its brackets, but the first's "[" and the last's "]": one join
    parts = (
        orjson.dumps(values[i : i + TEXT_SLICE], option=NUMPY)[
            (0 if i == 0 else 1) : (None if i == last else -1)
        ]
        for i in range(0, n, TEXT_SLICE)
    )
    return b",".join(parts)


def theta_text(tables: AdviceTables) -> tuple[bytes, IntArray, IntArray]:
    """theta of every state as orjson writes it, and where each number starts and ends: the
    advice of a batch answer, made once per tables (the service makes it in the worker thread
    that publishes new tables, so no event waits for it)."""
    made = _THETA_TEXT.get(tables)
    if made is None:
        text = numbers_text(tables.theta.reshape(-1))
        made = (text, *tokens(np.frombuffer(text, dtype=np.uint8)))
        _THETA_TEXT[tables] = made
    return made


def batch_dicts(out: DecisionBatch, domain: Domain) -> list[dict[str, Any]]:
    """A batch's decisions in the API's shape (``DecisionPublic``), as :func:`decision_dict`
    writes each."""
    cells = domain.cells[out.state].tolist()
    advice = iter(out.advice.tolist())
    columns = zip(
        cells, out.advise.tolist(), out.kl.tolist(), out.p_normal.tolist(),
        out.advice_count.tolist(), out.total_cost.tolist(), out.benefit.tolist(), strict=True,
    )  # fmt: skip
    return [
        {
            "step": out.first_step + i,
            "state": cell,
            "advise": advise,
            "advice": advice_dict(next(advice)) if advise else None,
            "kl": kl,
            "p_normal": p,
            "cost": {"advice_count": count, "total": total, "benefit": benefit},
        }
        for i, (cell, advise, kl, p, count, total, benefit) in enumerate(columns)
    ]


def batch_binary(out: DecisionBatch, domain: Domain) -> bytes:
    """A batch of decisions as one binary frame (a map of several floors: the frame's wide
    form, :data:`advisor_client.protocol.FLOORS`)."""
    return protocol.pack(
        out.first_step, out.kappa, out.count_before, out.benefit_before, out.kl, out.p_normal,
        out.advice, domain.cells[out.state].astype(np.int32), out.advise,
    )  # fmt: skip
