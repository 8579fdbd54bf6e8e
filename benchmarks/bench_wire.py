"""The service's wire on one floor, without a server: what reading events and writing answers
cost per event, on the shipped maze (the paper's rule deciding).

* read: a JSON list of 500 events read and checked (``wire.events.read_moves``), per event;
* one event: ``{"state": [r, c], "action": "E"}`` read and checked (``read_move``);
* JSON: a batch of 500 decisions written (``wire.encode.batch_json``), per decision;
* binary: the same batch as one binary frame (``batch_binary``), per decision.

Each figure is the best of ``--repeats`` timings. It imports ``app`` from the current
directory, so that two source trees compare side by side (run it from each tree in turn)::

    cd /work/before && python /path/to/benchmarks/bench_wire.py
    cd /work/after && python /path/to/benchmarks/bench_wire.py
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable

import numpy as np

sys.path.insert(0, ".")  # the tree to measure: the current directory's app

from app.advice.advisor import Advisor
from app.advice.models import AdviceTables
from app.domain.grid import GridDomain
from app.domain.maps import DEFAULT_MAP
from app.service.wire.encode import batch_binary, batch_json
from app.service.wire.events import read_move, read_moves

EVENTS = 500


def best(f: Callable[[], object], calls: int, repeats: int) -> float:
    """Seconds a call of ``f``: the best of ``repeats`` runs of ``calls`` calls."""
    out = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(calls):
            f()
        out = min(out, (time.perf_counter() - t0) / calls)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    g = GridDomain.from_file(DEFAULT_MAP)
    rng = np.random.default_rng(0)
    s, events = g.start, []
    for a in rng.integers(0, 4, EVENTS).tolist():
        events.append({"state": list(g.cell(s)), "action": "NESW"[a]})
        s = int(g.next_state[s, a])
    raw, one = json.dumps(events).encode(), json.dumps(events[0]).encode()
    theta = np.full((g.n_states, 4), 0.2)
    theta[:, 0] = 0.4  # a prior that advises (kappa 0: every decision)
    advisor = Advisor(AdviceTables.paper(theta), kappa=0.0, window=300)
    advisor.start(g.start)
    moves, _, _ = read_moves(g, raw, 10 * EVENTS)
    out = advisor.observe_batch(*moves)
    r = args.repeats
    read = best(lambda: read_moves(g, raw, 10 * EVENTS), 200, r) / EVENTS
    single = best(lambda: read_move(g, one), 5000, r)
    text = best(lambda: batch_json(out, g), 200, r) / EVENTS
    frame = best(lambda: batch_binary(out, g), 500, r) / EVENTS
    print(
        f"read {1e6 * read:.3f} us an event, one event {1e6 * single:.3f} us, "
        f"JSON {1e6 * text:.3f} us a decision, binary {1e6 * frame:.4f} us a decision"
    )


if __name__ == "__main__":
    main()
