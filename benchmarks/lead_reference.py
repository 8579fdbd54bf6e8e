"""What a lead that knows the walker is lost gets at guide's budget: a reference for guide.

A diagnosis, not a speed measurement. On the visitors experiment's maps and tasks (the same
options), a walker (``random``: any of the actions; ``random-avoid``: any open move;
``corridor``: any open move but back, as the corridor walker, its heading known to the lead)
is led by a simulated lead that knows it is lost (no belief to build) and knows the map:
towards the nearest destination not yet passed (the nearest again once it is passed), or with
``--order floor`` along the order of the floor (the least mean arrival from the start, exact
up to 12 destinations, else the visitors' searched order), or with ``--order legs`` (corridor
walkers, ``--optimal``) the same on the exact spending's own legs (:func:`legs_order`); with
guide's budget (a quarter of a piece a move, at most 8 saved, one at the start). Two ways of
spending it:

* ``first come``: a piece whenever one is saved;
* ``where it loses ground``: a piece where the walker's own move takes it farther from the
  target on average (delta > 0, over its own moves: for the corridor walker those from its
  heading), anywhere only with the budget full;
* ``spent optimally`` (corridor walkers, with ``--optimal``): for each leg (the target as
  above) the spending that minimises the mean moves to the target, exactly: a dynamic
  programme over cell, heading and pieces saved (in quarters, 0 to 8 pieces), solved by
  Gauss-Seidel sweeps in the order of the distance to the target (until no value changes by
  0.01 moves). What a lead that knows the target and the heading can get from the budget on
  each leg (not across legs: the order is the lead's). A piece leads by the first shortest
  move (in the actions' order), or with ``--best-move`` by the shortest move the programme
  finds best (guide leads a walker that never turns back by the one its lead values favour).

Beside them guide itself (compiled, the experiment's own runs of these tasks). The leads'
walkers draw their own moves (``rng_for(seed, "lead-reference", map, walker, task)``), so
they are compared with guide over the tasks, not task by task. Neither lead is a bound on
what an advisor could do (a lead could spend its pieces better still); they show how far
the spending and the order go.

    .venv/bin/python benchmarks/lead_reference.py --buildings 0 --hospitals 3x64 \\
        --hospitals 4x64 --hospitals 5x64 --tasks 100
    .venv/bin/python benchmarks/lead_reference.py --buildings 0 --mazes maps/Paris_0_256.txt \\
        --walker corridor --order floor --tasks 200
    .venv/bin/python benchmarks/lead_reference.py --buildings 0 --hospitals 3x64 \\
        --hospitals 4x64 --hospitals 5x64 --walker corridor --tasks 100 --optimal
    .venv/bin/python benchmarks/lead_reference.py --buildings 0 --hospitals 3x64 \\
        --hospitals 4x64 --hospitals 5x64 --hospitals 3x128 --hospitals 4x128 \\
        --hospitals 5x128 --only hospital-4x128-s139790160 --walker corridor --optimal
    .venv/bin/python benchmarks/lead_reference.py --buildings 0 --mazes maps/brc202d.txt \\
        --walker corridor --tasks 200 --optimal --best-move
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
from numba import njit
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.advice.guide import ADVICE_BURST, ADVICE_RATE
from app.domain.building import Domain
from app.domain.grid import bfs_distances_each
from app.experiments import visitors
from app.experiments.common import rng_for
from app.experiments.suite import map_suite
from benchmarks._report import arguments

LEADS = ("first come", "where it loses ground")
OPTIMAL = "spent optimally"
QUARTERS = 32  # the budget in quarter pieces: at most ADVICE_BURST (8) pieces saved


def corridor_moves(next_state: np.ndarray, open_moves: np.ndarray) -> tuple[np.ndarray, ...]:
    """(S x 4, A) successors (state x 4 + heading) of the corridor walker's own moves from
    each state and heading, and how many: ``own_moves``' moves, a ride keeping the heading."""
    n_states, n_actions = next_state.shape
    nxt = np.zeros((n_states * 4, n_actions), dtype=np.int64)
    cnt = np.zeros(n_states * 4, dtype=np.int64)
    for c in range(n_states):
        for h in range(4):
            moves = own_moves(open_moves, c, "corridor", h)
            for k, a in enumerate(moves):
                u = int(next_state[c, a])
                nxt[c * 4 + h, k] = u * 4 + (int(a) if u != c and a < 4 else h)
            cnt[c * 4 + h] = len(moves)
    return nxt, cnt


def led_moves(
    next_state: np.ndarray, dt: np.ndarray, every: bool = False, anywhere: bool = False
) -> np.ndarray:
    """(S x 4, A) the successors (state x 4 + heading) of the lead's piece from each state and
    heading: the first shortest move, or with ``every`` each shortest move, or with
    ``anywhere`` each move (shortest or not), -1 after the last; the state itself at the
    target or where it cannot be reached."""
    n_states, n_actions = next_state.shape
    out = np.full((n_states * 4, n_actions), -1, dtype=np.int64)
    out[:, 0] = np.arange(n_states * 4)
    for c in range(n_states):
        if dt[c] > 0:
            if anywhere:
                ways = [b for b in range(n_actions) if next_state[c, b] != c]
                ways = [b for b in ways if dt[next_state[c, b]] >= 0]
            else:
                ways = [b for b in range(n_actions) if dt[next_state[c, b]] == dt[c] - 1]
                ways = ways if every else ways[:1]
            for k, a in enumerate(ways):
                u = int(next_state[c, a])
                for h in range(4):
                    out[c * 4 + h, k] = u * 4 + (a if a < 4 else h)
    return out


@njit(cache=True)
def optimal_spending(order, nxt, cnt, led, target, rate, burst, tol, most):  # type: ignore[no-untyped-def]  # pragma: no cover
    """(S x 4, burst + 1): the least mean moves to ``target`` from each state, heading and
    budget (quarters saved before the move's ``rate`` is added); a piece leads to the best of
    ``led``'s successors (a row's -1 ends them)."""
    v = np.zeros((nxt.shape[0], burst + 1))
    for _ in range(most):
        change = 0.0
        for c in order:
            if c == target:
                continue
            for h in range(4):
                i = c * 4 + h
                for q in range(burst + 1):
                    q1 = min(burst, q + rate)
                    own = 0.0
                    for k in range(cnt[i]):
                        own += v[nxt[i, k], q1]
                    best = 1.0 + own / cnt[i]
                    if q1 >= 4:
                        for k in range(led.shape[1]):
                            if led[i, k] < 0:
                                break
                            if 1.0 + v[led[i, k], q1 - 4] < best:
                                best = 1.0 + v[led[i, k], q1 - 4]
                    change = max(change, abs(best - v[i, q]))
                    v[i, q] = best
        if change < tol:
            break
    return v


def own_moves(open_moves: np.ndarray, s: int, walker: str, heading: int) -> np.ndarray:
    """The actions the walker picks its own move from, uniformly (a bump included for
    ``random``); the corridor walker's as :class:`app.agents.explorers.CorridorExplorer`."""
    if walker == "random":
        return np.arange(open_moves.shape[1])
    moves = open_moves[s].copy()
    if walker == "corridor":
        back = (heading + 2) % 4
        moves[back] = False
        if not moves.any():
            return np.array([back if open_moves[s, back] else heading])
    return np.flatnonzero(moves) if moves.any() else np.arange(open_moves.shape[1])


def lead(
    d: Domain, dist: np.ndarray, drift: np.ndarray, goal: int, walker: str, how: str,
    order: list[int] | None, steps: int, rng: np.random.Generator,
    spending: Callable[[int], tuple[np.ndarray, ...]] | None = None,
) -> tuple[bool, int, int]:  # fmt: skip
    """One task: (arrived, moves, pieces). ``order``: the destinations' order (by index), or
    None for the nearest not passed; ``spending``: for ``spent optimally``, a target's
    programme (values, own successors, their count, the lead's successors)."""
    next_state, goals = d.next_state, list(d.goals)
    n_actions = next_state.shape[1]
    at_goal = {c: i for i, c in enumerate(goals)}
    alive = np.ones(len(goals), dtype=bool)
    s, target, saved, pieces = d.start, -1, 1.0, 0
    heading = int(rng.random() * 4) if walker == "corridor" else -1  # as at reset
    for t in range(steps):
        if s == goal:
            return True, t, pieces
        if s in at_goal:
            alive[at_goal[s]] = False
        if target < 0 or not alive[target]:
            if order is not None and alive.any():
                target = next(j for j in order if alive[j])
            else:
                far = np.iinfo(np.int64).max
                target = int(np.argmin(np.where(alive & (dist[:, s] >= 0), dist[:, s], far)))
        saved = min(ADVICE_BURST, saved + ADVICE_RATE)
        own = own_moves(d.open_moves, s, walker, heading)
        here = dist[target, s]
        if how == OPTIMAL:  # the exact programme's choice, the budget in quarters
            assert spending is not None
            v, nxt, cnt, led = spending(target)
            i, q = s * 4 + heading, round(4 * saved)
            own_value = float(np.mean(v[nxt[i, : cnt[i]], q]))
            ways = led[i][led[i] >= 0]
            way = int(ways[int(np.argmin(v[ways, q - 4]))]) if q >= 4 else -1
            give = q >= 4 and float(v[way, q - 4]) < own_value
            if give:
                saved, pieces = saved - 1.0, pieces + 1
                s, heading = divmod(way, 4)
            else:
                s, heading = divmod(int(nxt[i, int(rng.integers(cnt[i]))]), 4)
            continue
        if walker == "corridor":
            loses = here > 0 and float(np.mean(dist[target, next_state[s, own]] - here)) > 0
        else:
            loses = drift[target, s] > 0
        give = saved >= 1.0 and (how == "first come" or loses or saved >= ADVICE_BURST)
        if give:
            saved -= 1.0
            pieces += 1
            a = next(b for b in range(n_actions) if dist[target, next_state[s, b]] == here - 1)
        else:
            a = int(own[int(rng.integers(len(own)))])
        if next_state[s, a] != s and a < 4:  # a ride keeps the heading
            heading = a
        s = int(next_state[s, a])
    return s == goal, steps, pieces


def drifts(next_state: np.ndarray, dist: np.ndarray, walker: str) -> np.ndarray:
    """(G, S): the mean change of the distance to each destination of one of the walker's own
    moves (every action, a bump 0; or the open moves)."""
    change = np.zeros(dist.shape, dtype=np.float64)
    count = np.zeros(dist.shape[1], dtype=np.float64)
    for a in range(next_state.shape[1]):
        moved = next_state[:, a] != np.arange(next_state.shape[0])
        if walker == "random":
            change += dist[:, next_state[:, a]] - dist
            count += 1
        else:
            change += np.where(moved, dist[:, next_state[:, a]] - dist, 0)
            count += moved
    return change / np.maximum(count, 1)


def main() -> None:
    ap = arguments(__doc__)
    ap.add_argument("--buildings", type=int, nargs="*", default=[0], help="as the experiment's")
    ap.add_argument("--hospitals", action="append", default=[], help="FLOORSxSIDE")
    ap.add_argument("--hospital-goals", type=int, default=8)
    ap.add_argument("--imdf", action="store_true")
    ap.add_argument("--mazes", action="append", default=[], type=Path, help="a map file")
    ap.add_argument("--walker", action="append", default=[],
                    help="random, random-avoid or corridor")  # fmt: skip
    ap.add_argument("--order", choices=("nearest", "floor", "legs"), default="nearest",
                    help="the leads' order: nearest first, the floor's, or (corridor "
                         "walkers, with --optimal) the least mean arrival on the "
                         "programme's own legs")  # fmt: skip
    ap.add_argument("--optimal", action="store_true",
                    help="corridor walkers: the budget spent optimally too (slow)")  # fmt: skip
    ap.add_argument("--best-move", action="store_true",
                    help="with --optimal: a piece leads by the best shortest move (the "
                         "programme chooses), not the first")  # fmt: skip
    ap.add_argument("--any-move", action="store_true",
                    help="with --optimal: a piece may lead by any move, shortest or not (the "
                         "programme chooses)")  # fmt: skip
    ap.add_argument("--only", action="append", default=[],
                    help="run only the map of this name (as the table names it; repeat for "
                         "more): the suite's maps and tasks are kept")  # fmt: skip
    ap.add_argument("--tasks", type=int, default=100)
    ap.add_argument("--steps", type=int, default=5000)
    a = ap.parse_args()
    walkers = a.walker or ["random", "random-avoid"]
    if a.order == "legs" and (not a.optimal or walkers != ["corridor"]):
        ap.error("--order legs: the exact programme's legs, so --optimal --walker corridor")
    if any(w not in ("random", "random-avoid", "corridor") for w in walkers):
        ap.error("--walker: random, random-avoid or corridor")
    exp = visitors.Args(
        buildings=tuple(a.buildings) or (0,), hospitals=tuple(a.hospitals),
        hospital_goals=a.hospital_goals, imdf=a.imdf, mazes=tuple(a.mazes), tasks=a.tasks,
        steps=a.steps, visitors=tuple(walkers), progress=False, workers=1,
    )  # fmt: skip
    exp.check()
    guide_config = next(c for c in visitors.configs(exp) if c.advised)
    heads = (*LEADS, OPTIMAL) if a.optimal else LEADS
    print(f"| map | walker | {' | '.join(heads)} | guide |")
    print("|---|---|" + "---|" * (len(heads) + 1))
    specs = map_suite(exp.suite())
    unknown = set(a.only) - {spec.name for spec in specs}
    if unknown:
        ap.error(f"--only: no map {', '.join(sorted(unknown))} in this suite")
    for spec in specs:
        if a.only and spec.name not in a.only:
            continue
        world = visitors.place(exp, spec).world
        d = world.domain
        dist = bfs_distances_each(d.next_state, d.goals)
        order = None
        if a.order == "floor":
            legs = visitors.latency_legs(d)
            found = visitors.min_latency_order(legs) or visitors.searched_latency_order(legs)
            order = found[0] if found else None
        for walker in walkers:
            drift = drifts(d.next_state, dist, walker)
            cells = []
            spend = spending(d, dist, a.best_move, a.any_move) if walker == "corridor" else None
            if a.order == "legs" and spend is not None:
                order = legs_order(d, spend)
            for how in (*LEADS, OPTIMAL) if a.optimal and spend is not None else LEADS:
                runs = [
                    lead(d, dist, drift, goal, walker, how, order, a.steps,
                         rng_for(exp.seed, "lead-reference", spec.index, walker, i), spend)
                    for i, goal in enumerate(tqdm(world.goals, desc=f"{spec.name} {how}",
                                                  leave=False))
                ]  # fmt: skip
                cells.append(run_cell(runs))
            if a.optimal and spend is None:
                cells.append("-")
            runs = []
            for i, goal in enumerate(world.goals):
                r = world.sim.fixed(
                    walker, goal, rng_for(exp.seed, "buildings", spec.index, walker, i),
                    advised=True, strategy=guide_config.strategy, kappa=guide_config.kappa,
                    window=exp.window, params=guide_config.params, max_steps=a.steps,
                    record_p=False,
                )  # fmt: skip
                runs.append((r.success, r.steps, r.advice_count))
            cells.append(run_cell(runs))
            print(f"| {spec.name} | {walker} | {' | '.join(cells)} |", flush=True)


def spending(
    d: Domain, dist: np.ndarray, every: bool = False, anywhere: bool = False
) -> Callable[[int], tuple[np.ndarray, ...]]:
    """Each target's optimal spending (:func:`optimal_spending`), made when first asked; with
    ``every`` a piece leads by the best shortest move, with ``anywhere`` by the best move
    (shortest or not), else by the first shortest move."""
    nxt, cnt = corridor_moves(d.next_state, d.open_moves)
    made: dict[int, tuple[np.ndarray, ...]] = {}

    def of(target: int) -> tuple[np.ndarray, ...]:
        if target not in made:
            dt = dist[target]
            order = np.argsort(np.where(dt >= 0, dt, np.iinfo(np.int64).max), kind="stable")
            led = led_moves(d.next_state, dt, every, anywhere)
            v = optimal_spending(order[dt[order] >= 0], nxt, cnt, led, int(d.goals[target]),
                                 round(4 * ADVICE_RATE), QUARTERS, 0.01, 100_000)  # fmt: skip
            made[target] = (v, nxt, cnt, led)
        return made[target]

    return of


def legs_order(d: Domain, spend: Callable[[int], tuple[np.ndarray, ...]]) -> list[int]:
    """The order of the destinations with the least mean arrival of a walker led along it by
    the exact spending, each leg's moves the programme's mean over the headings (the first
    from the start with one piece saved, the others from the destination before with the
    budget full: the least a leg can take); exact up to the floor's limit, else searched.
    Prints the expected arrivals along it."""
    goals, n = list(d.goals), len(d.goals)
    start = [float(spend(j)[0][d.start * 4 : d.start * 4 + 4, 4].mean()) for j in range(n)]
    leg = [
        [0.0 if i == j else float(spend(j)[0][goals[i] * 4 : goals[i] * 4 + 4, -1].mean())
         for j in range(n)]
        for i in range(n)
    ]  # fmt: skip
    legs = (start, leg)
    found = visitors.min_latency_order(legs) or visitors.searched_latency_order(legs)  # type: ignore[arg-type]
    assert found is not None
    order, arrival = found
    along = ", ".join(f"{arrival[j]:,.0f}" for j in order)
    print(f"expected arrivals along {order} (legs' order): {along}", flush=True)
    return order


def run_cell(runs: list[tuple[bool, int, int]]) -> str:
    """Success (mean moves, a task that did not arrive counting the limit; pieces per 100)."""
    ok = np.array([r[0] for r in runs], dtype=np.float64)
    moves = np.array([r[1] for r in runs], dtype=np.float64)
    pieces = np.array([r[2] for r in runs], dtype=np.float64)
    return (
        f"{100 * ok.mean():.0f}% ({moves.mean():,.0f} moves, "
        f"{100 * pieces.sum() / max(1.0, moves.sum()):.1f} / 100)"
    )


if __name__ == "__main__":
    main()
