"""The compiled loops of the event paths, loaded (or compiled, the first time) before a
request needs them: one floor's at the start (:func:`warm_up`), a building's with the first
map of several floors (:func:`warm_building`)."""

from __future__ import annotations

import functools
import json
from typing import Any

import numpy as np

from app import kernels, strategies
from app.advice.guide import GuideMap
from app.advice.models import AdviceTables
from app.advice.params import StrategyParams
from app.advice.priors import GoalPriors
from app.domain.building import Building, Domain
from app.domain.grid import ACTIONS, GridDomain
from app.service.data.domains import compiled_searches
from app.service.wire.encode import batch_binary, batch_json
from app.service.wire.events import read_moves
from app.strategies import DomainData, compiled_leads

#: a building of two floors and a lift, for :func:`warm_building`: what a building's events run
#: (six actions, guide's batch compiled for six) is loaded before any request needs it
_WARM_BUILDING = """\
connection: lift 1 0:1,1 1:1,1 Lift
floor: 0 Ground
#####
#S.G#
#####
floor: 1 First
#####
#..G#
#####"""


def warm_up() -> None:
    """Load (or compile, the first time) every compiled loop of the event paths (reader,
    checks, every strategy's service advisor, writers) on one floor, so that no request waits
    for it (a building's: :func:`warm_building`)."""
    _warm(GridDomain.from_strings(["#####", "#S.G#", "#####"]))


@functools.cache
def warm_building() -> None:
    """*Worker thread.* :func:`warm_up`'s work in a building (six actions; guide's batch is
    compiled for six apart from four), once, when a map of several floors is first made ready
    (:func:`app.service.wire.warm.warm`: at the start, a PUT or another worker's change), so
    that a service of one floor never compiles it."""
    _warm(Building.from_text(_WARM_BUILDING))


def _warm(grid: Domain) -> None:
    uniform = np.full((grid.n_states, grid.n_actions), 1.0 / grid.n_actions)
    tables = AdviceTables.paper(uniform)
    event = {"state": list(grid.cell(grid.start)), "action": ACTIONS[1]}
    moves, _, _ = read_moves(grid, json.dumps([event] * 3), 3)

    def goals() -> GoalPriors:
        return GoalPriors(grid.n_states, grid.goals, n_actions=grid.n_actions).add(
            [np.array([[0, 1]])], [0]
        )

    data = DomainData(
        tables, goals(),
        GuideMap.of(grid, goals(), searches=compiled_searches, distances=kernels.guide_distances,
                   leads=compiled_leads),
    )  # fmt: skip
    for entry in strategies.STRATEGIES.values():
        # the per-goal window too where a strategy keeps one (goal_aware's beta > 0)
        half: list[dict[str, Any]] = [{p: 0.5} for p in entry.reads]
        swept = [StrategyParams(), *(StrategyParams(**h) for h in half)]
        for params in swept:
            try:
                settings = entry.settings(0.0, 2, params)
            except ValueError:
                continue  # 0.5 is out of this parameter's bounds
            advisor = entry.service_advisor(data, settings)
            advisor.start(grid.start)
            out = advisor.observe_batch(*moves)
            # a prior update (new tables, new goal counts), then one event and a batch
            advisor.use_tables(AdviceTables.paper(uniform.copy()), goals())
            advisor.observe(*(int(m[0]) for m in moves))
            advisor.observe_batch(*moves)
            advisor.goal_beliefs()
            batch_json(out, grid)
            batch_binary(out, grid)
