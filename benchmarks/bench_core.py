"""Core speed: one explorer's decision, the compiled form over many explorers, prior fitting.

Targets (issue 2): single decision <= 5 us median; many explorers >= 5 million decisions/s
(10,000 explorers, each advised on its 600 moves in one call of the compiled form a service
runs, ``StreamAdvisor.observe_batch``); fitting >= 5 million transitions/s. Each figure is the
median over ``--repeats`` runs.

    .venv/bin/python benchmarks/bench_core.py [--repeats 7] [--write docs/PERFORMANCE.md]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.advice.advisor import Advisor
from app.advice.models import AdviceTables
from app.advice.priors import ActionPrior
from app.agents.experts import train_prior
from app.domain.building import Domain
from app.domain.grid import GridDomain
from app.domain.maps import DEFAULT_MAP
from app.strategies.stream import StreamAdvisor
from benchmarks._report import command_line, machine, median_of, write_section


def random_walk(domain: Domain, rng: np.random.Generator, n: int) -> tuple[list[int], ...]:
    a = rng.integers(0, domain.n_actions, n)
    s = np.empty(n + 1, dtype=np.int64)
    s[0] = domain.start
    nxt = domain.next_state
    for i in range(n):
        s[i + 1] = nxt[s[i], a[i]]
    return s[:-1].tolist(), a.tolist(), s[1:].tolist()


def bench_single(tables: AdviceTables, domain: Domain, repeats: int) -> tuple[float, float]:
    """(median us per observe+decide over whole runs, median of per-call times in us)."""
    s, a, s2 = random_walk(domain, np.random.default_rng(1), 50_000)

    def run() -> float:
        adv = Advisor(tables)
        adv.start(domain.start)
        obs = adv.observe
        t0 = time.perf_counter()
        for x, y, z in zip(s, a, s2, strict=True):
            obs(x, y, z)
        return (time.perf_counter() - t0) / len(s) * 1e6

    per_run, _ = median_of(run, repeats)
    adv = Advisor(tables)
    adv.start(domain.start)
    clock = time.perf_counter_ns
    calls = []
    for x, y, z in zip(s[:20_000], a, s2, strict=False):
        t0 = clock()
        adv.observe(x, y, z)
        calls.append(clock() - t0)
    return per_run, float(np.median(calls)) / 1000


def compiled_rate(
    tables: AdviceTables, domain: Domain, repeats: int, n: int = 10_000, steps: int = 600,
    window: int = 300, walk: bool = False,
) -> float:  # fmt: skip
    """Decisions per CPU second of the compiled form (the service's ``StreamAdvisor``): ``n``
    explorers, each advised on its ``steps`` moves (random states and actions) in one call.
    With ``walk`` each explorer walks instead (random actions, each state the last one's
    next, as explorers move): the tables are read where the last decision read them."""
    rng = np.random.default_rng(2)
    states = rng.integers(0, domain.n_states, (n, steps + 1))
    actions = rng.integers(0, domain.n_actions, (n, steps))
    if walk:
        for t in range(steps):
            states[:, t + 1] = domain.next_state[states[:, t], actions[:, t]]
    nxt = domain.next_state[states[:, :-1], actions]
    before = np.ascontiguousarray(states[:, :-1])

    def run() -> float:
        advisors = [StreamAdvisor(tables, window=window) for _ in range(n)]
        for adv, s0 in zip(advisors, states[:, 0].tolist(), strict=True):
            adv.start(s0)
        t0 = time.process_time()  # CPU seconds: this machine's other work does not count
        for i, adv in enumerate(advisors):
            adv.observe_batch(before[i], actions[i], nxt[i])
        return steps * n / (time.process_time() - t0)

    return median_of(run, repeats)[0]


def bench_fit(domain: GridDomain, repeats: int, n_traj: int = 5_000, length: int = 1_000) -> float:
    rng = np.random.default_rng(3)
    trajs = [
        np.column_stack(random_walk(domain, rng, length)[:2]).astype(np.int64)
        for _ in range(n_traj)
    ]

    def run() -> float:
        t0 = time.perf_counter()
        ActionPrior().fit(trajs, domain.n_states)
        return n_traj * length / (time.perf_counter() - t0)

    return median_of(run, repeats)[0]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--write", type=Path, help="rewrite this markdown file's core section")
    args = ap.parse_args()
    domain = GridDomain.from_file(DEFAULT_MAP)
    prior = train_prior(domain, np.random.default_rng(0), "anywhere", per_goal=10)
    tables = AdviceTables.paper(prior.theta())
    single_run, single_call = bench_single(tables, domain, args.repeats)
    batch = compiled_rate(tables, domain, args.repeats)
    fit = bench_fit(domain, args.repeats)
    rows = [
        ("single explorer, observe + decide (mean per call, median of runs)",
         f"{single_run:.2f} us", "<= 5 us"),
        ("single explorer, observe + decide (median of 20k timed calls)",
         f"{single_call:.2f} us", "<= 5 us"),
        ("compiled, 10,000 explorers x 600 moves a call, window 300 (per CPU second)",
         f"{batch / 1e6:.2f} M decisions/s", ">= 5 M/s"),
        ("fit from 5,000 trajectories x 1,000 steps",
         f"{fit / 1e6:.2f} M transitions/s", ">= 5 M/s"),
    ]  # fmt: skip
    table = "| measurement | result | target |\n|---|---|---|\n" + "\n".join(
        f"| {a} | {b} | {c} |" for a, b, c in rows
    )
    body = (
        f"## Core library\n\nCommand: `{command_line()}` (median of {args.repeats} runs each)\n\n"
        f"Machine: {machine()}\n\n{table}\n"
    )
    print(body)
    if args.write:
        write_section(args.write, "bench_core", body)


if __name__ == "__main__":
    main()
