"""``experiment all``: the paper's protocol end to end, in one results directory.

The maze's difficulty, then Figure 6 (Q-learning, with and without advice), Table I (which
reuses Figure 6's Q-learning runs for its Q-learning row), Figure 5 and Figure 7. Each part
takes its own arguments (the command line gives them all the same options).
"""

from __future__ import annotations

import time

from app.experiments import difficulty, figure5, figure6, figure7, table1
from app.experiments.output import RunDir

#: the experiments run, in order
PARTS = (difficulty, figure6, table1, figure5, figure7)


def run(
    difficulty_args: difficulty.Args,
    figure6_args: figure6.Args,
    table1_args: table1.Args,
    figure5_args: figure5.Args,
    figure7_args: figure7.Args,
    out: RunDir,
) -> dict[str, float]:
    """Run every part; returns the seconds each took."""
    seconds: dict[str, float] = {}
    t = time.perf_counter()
    difficulty.run(difficulty_args, out)
    seconds["difficulty"] = time.perf_counter() - t
    t = time.perf_counter()
    _, learning = figure6.run(figure6_args, out)
    seconds["figure6"] = time.perf_counter() - t
    t = time.perf_counter()
    table1.run(table1_args, out, learning=learning)
    seconds["table1"] = time.perf_counter() - t
    t = time.perf_counter()
    figure5.run(figure5_args, out)
    seconds["figure5"] = time.perf_counter() - t
    t = time.perf_counter()
    figure7.run(figure7_args, out)
    seconds["figure7"] = time.perf_counter() - t
    return seconds
