"""Expert trajectories from a request body to checked (state, action) arrays.

Each step's cell must be a free cell of the map, and each step must start where the previous
one led (``T(s, a)``, a bump into a wall stays put): a trajectory is a path actually walked.
All steps of all trajectories are checked at once; the first problem is named.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from pydantic import TypeAdapter, ValidationError

from app.arrays import IntArray
from app.domain.building import Domain
from app.service.data.store import Trajectory
from app.service.problems import BadInput, describe_errors
from app.service.schemas import ACTION_CODE, TrajectoriesCreate
from app.service.wire.events import cell_words, floor_change, off_map

BODY = TypeAdapter(TrajectoriesCreate)


def parse_trajectories(raw: bytes) -> TrajectoriesCreate:
    try:
        return BODY.validate_json(raw)
    except ValidationError as exc:
        raise BadInput(describe_errors(exc.errors(include_input=False))) from None


def to_trajectories(domain: Domain, body: TrajectoriesCreate, max_steps: int) -> list[Trajectory]:
    """Checked trajectories; :class:`BadInput` names the first bad step."""
    trajs = body.trajectories
    lengths = np.array([len(t.steps) for t in trajs], dtype=np.int64)
    total = int(lengths.sum())
    if total > max_steps:
        raise BadInput(f"too many steps: {total} in one request, at most {max_steps}", 413)
    ends = np.cumsum(lengths)
    steps = [s for t in trajs for s in t.steps]
    actions = np.array([ACTION_CODE[s["action"]] for s in steps], dtype=np.int64)

    def name(k: int) -> str:
        i = int(np.searchsorted(ends, k, side="right"))
        return f"trajectories[{i}].steps[{k - (ends[i] - lengths[i])}]"

    for k, step in enumerate(steps):
        if len(step["state"]) != domain.width:
            raise BadInput(f"{name(k)}: cell {list(step['state'])}: {cell_words(domain)}")
        if actions[k] >= domain.n_actions:
            raise BadInput(f"{name(k)}: {floor_change(int(actions[k]))}")
    cells = np.array([s["state"] for s in steps], dtype=np.int64).reshape(-1, domain.width)

    states = _states(domain, cells, name)
    led_to = domain.next_state[states, actions]
    jumps = np.flatnonzero(states[1:] != led_to[:-1])
    jumps = jumps[~np.isin(jumps + 1, ends)]  # the first step of a trajectory starts anywhere
    if jumps.size:
        k = int(jumps[0]) + 1
        raise BadInput(
            f"{name(k)}: state {cells[k].tolist()} is not where the previous step leads "
            f"({list(domain.cell(int(led_to[k - 1])))}): send each trajectory as walked"
        )
    out = []
    for i, (t, end) in enumerate(zip(trajs, ends.tolist(), strict=True)):
        lo = end - len(t.steps)
        pairs = np.column_stack([states[lo:end], actions[lo:end]])
        out.append(Trajectory(t.agent_type, pairs, _goal(domain, t.goal, i)))
    return out


def _goal(domain: Domain, goal: list[int] | None, i: int) -> int | None:
    if goal is None:
        return None
    if len(goal) != domain.width:
        raise BadInput(f"trajectories[{i}].goal: {list(goal)}: {cell_words(domain)}")
    return int(_states(domain, np.array([goal]), lambda _: f"trajectories[{i}].goal")[0])


def _states(domain: Domain, cells: IntArray, name: Callable[[int], str]) -> IntArray:
    shape = domain.shape
    off = np.flatnonzero((cells >= np.array(shape)).any(axis=1))
    if off.size:
        k = int(off[0])
        raise BadInput(f"{name(k)}: {off_map(domain, f'cell {cells[k].tolist()}')}")
    states: IntArray = domain.state_of[tuple(cells.T)]
    walls = np.flatnonzero(states < 0)
    if walls.size:
        k = int(walls[0])
        raise BadInput(f"{name(k)}: cell {cells[k].tolist()} is a wall")
    return states
