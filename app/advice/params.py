"""The advising strategies' parameters, defined once: names, defaults, bounds and meaning.

Which strategy reads which is said by each strategy's entry (:mod:`app.strategies`); the
service's request schema and the experiments' options are made from these fields.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np


def _param(default: float, low: float, high: float, doc: str) -> Any:
    return field(default=default, metadata={"low": low, "high": high, "doc": doc})


@dataclass(frozen=True)
class StrategyParams:
    """Parameters of every strategy; each strategy reads only its own."""

    n_steps: int = _param(20, 0, 2**31 - 1, "early: advise at the first n_steps decisions.")
    threshold: float = _param(
        0.5, 0.0, math.inf,
        "importance: advise where KL[theta_s || uniform] >= threshold (nats); mistake: after "
        "an action with theta_s(a) < threshold.",
    )  # fmt: skip
    rate: float = _param(0.1, 0.0, 1.0, "random: P(advise) per decision.")
    beta: float = _param(
        0.0, 0.0, 1.0,
        "goal_aware: weight of each goal's likelihood of the window (0: ruling goals out only).",
    )  # fmt: skip
    seed: int = _param(0, 0, 2**32 - 1, "random: seed of its draws.")
    p_lost: float = _param(
        0.15, 0.001, 0.999,
        "guide: prior probability that an explorer is lost (the rest: heading for a destination).",
    )  # fmt: skip
    slack: float = _param(
        0.5, 0.01, 1.0,
        "guide: how far an explorer heading for a destination may stray: the share of its moves "
        "drawn uniformly (1: no better than lost).",
    )  # fmt: skip
    spread: float = _param(
        0.05, 0.0, 1.0,
        "guide: share of the advice spread evenly over the four actions (0: only moves towards "
        "the destination).",
    )  # fmt: skip

    def check(self) -> None:
        """Raise ValueError naming the first parameter outside its bounds."""
        for f in fields(self):
            v, low, high = getattr(self, f.name), f.metadata["low"], f.metadata["high"]
            whole = f.type == "int"
            if whole and (isinstance(v, bool) or not isinstance(v, int | np.integer)):
                raise ValueError(f"{f.name} must be a whole number, got {v!r}")
            if not (math.isfinite(v) and low <= v <= high):
                kind = "a whole number" if whole else "a finite number"
                bounds = f">= {low}" if high == math.inf else f"from {low} to {high}"
                raise ValueError(f"{f.name} must be {kind} {bounds}, got {v!r}")

    def values(self, names: Iterable[str]) -> dict[str, int | float]:
        """The parameters ``names`` with their values (a strategy's parameters in force)."""
        return {name: getattr(self, name) for name in names}


#: every parameter's name, in the order of the fields
PARAM_NAMES: tuple[str, ...] = tuple(f.name for f in fields(StrategyParams))
