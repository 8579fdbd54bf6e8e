"""Decisions out: JSON (orjson) and the websocket's binary frames (:mod:`app.protocol`).

* one decision: :func:`decision_json`, a dict written by orjson;
* a batch: :func:`batch_json`, orjson's texts of the numbers (written from the numpy columns,
  no Python floats) laid out by a compiled loop (:func:`app.service.wire.compiled.write_decisions`),
  which is several times faster than orjson over a list of dicts (measured side by side:
  docs/PERFORMANCE.md); the same bytes as :func:`decision_json` decision for decision
  (``tests/service/wire/test_encode.py``);
* binary: :func:`batch_binary`, the same decisions at full precision in columns.

Every number's text is orjson's shortest round-trip form, on every path.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import orjson

from app import protocol
from app.advice.advisor import Decision, DecisionBatch
from app.domain.grid import GridDomain
from app.service.wire.compiled import write_decisions

NUMPY = orjson.OPT_SERIALIZE_NUMPY


def decision_dict(d: Decision, domain: GridDomain) -> dict[str, Any]:
    """One decision in the API's shape (``DecisionPublic``)."""
    return {
        "step": d.step,
        "state": domain.cell(d.state),
        "advise": d.advise,
        "advice": None if d.advice is None else dict(zip("NESW", d.advice, strict=True)),
        "kl": d.kl,
        "p_normal": d.p_normal,
        "cost": {"advice_count": d.advice_count, "total": d.total_cost, "benefit": d.benefit},
    }


def decision_json(d: Decision, domain: GridDomain) -> bytes:
    """One decision as JSON."""
    return orjson.dumps(decision_dict(d, domain))


def batch_json(out: DecisionBatch, domain: GridDomain) -> bytes:
    """A batch of decisions as a JSON list."""
    numbers = orjson.dumps(
        (out.kl, out.p_normal, out.total_cost, out.benefit, out.advice.reshape(-1)), option=NUMPY
    )
    return write_decisions(
        out.first_step, out.state, domain.cells, out.advise, out.advice_count, numbers
    )


def batch_binary(out: DecisionBatch, domain: GridDomain) -> bytes:
    """A batch of decisions as one binary frame."""
    return protocol.pack(
        out.first_step, out.kappa, out.count_before, out.benefit_before, out.kl, out.p_normal,
        out.advice, domain.cells[out.state].astype(np.int32), out.advise,
    )  # fmt: skip
