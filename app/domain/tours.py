"""Walks through a map's destinations: the order to visit them in.

A walk starts somewhere and passes destinations one after another; ``first[j]`` is the moves
from its start to destination j, ``leg[i][j]`` from destination i to j. Two uses share these
functions: guide leads a lost explorer through the destinations not yet ruled out
(:meth:`app.advice.guide.GuideMap.first_of_tour`, beyond the exact programme's reach), and the
visitors experiment bounds the floor above with the same order
(:func:`app.experiments.visitors.searched_latency_order`). The compiled decisions make the
same search (``app.kernels.guide_searched_order``).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from typing import Any

#: the most rounds of :func:`local_search`
MAX_SEARCH_ROUNDS = 32


def arrivals_along(
    order: list[int], first: Sequence[int], leg: Sequence[Sequence[int]]
) -> list[int]:
    """The arrival at each destination (by index) of a walk from its start along ``order``."""
    arrival, t, at = [0] * len(first), 0, -1
    for j in order:
        t += first[j] if at < 0 else leg[at][j]
        arrival[j], at = t, j
    return arrival


def nearest_order(first: Sequence[int], leg: Sequence[Sequence[int]]) -> list[int]:
    """The destinations nearest first: from the start, then from each to the nearest not yet
    reached (ties to the lower index)."""
    order: list[int] = []
    left, at = set(range(len(first))), -1
    while left:
        j = min(left, key=lambda j: (first[j] if at < 0 else leg[at][j], j))
        order.append(j)
        left.remove(j)
        at = j
    return order


def local_search(
    order: list[int], cost: Callable[[list[int]], Any], rounds: int = MAX_SEARCH_ROUNDS
) -> list[int]:
    """``order`` improved while a segment of it reversed, or one of 1-3 destinations moved
    elsewhere, lowers ``cost`` (each change taken as soon as it is found; at most ``rounds``
    rounds, a round being every such change tried once)."""
    n, best = len(order), cost(order)
    for _ in range(rounds):
        before = best
        for i, j in itertools.combinations(range(n), 2):
            o = order[:i] + order[i : j + 1][::-1] + order[j + 1 :]
            if (c := cost(o)) < best:
                order, best = o, c
        for size in (1, 2, 3):
            for i in range(n - size + 1):
                piece, rest = order[i : i + size], order[:i] + order[i + size :]
                for k in range(len(rest) + 1):
                    o = rest[:k] + piece + rest[k:]
                    if (c := cost(o)) < best:
                        order, best = o, c
                        break
        if best == before:
            break
    return order


def searched_order(
    first: Sequence[int], leg: Sequence[Sequence[int]], rounds: int = MAX_SEARCH_ROUNDS
) -> list[int]:
    """An order with a low sum of arrivals (so a low mean arrival, each destination as
    likely): :func:`nearest_order` improved by :func:`local_search` on that sum."""
    return local_search(
        nearest_order(first, leg), lambda o: sum(arrivals_along(o, first, leg)), rounds
    )
