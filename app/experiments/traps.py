"""Being led into the dead end of a goal that is not one's own: a precise, measurable definition.

**Dead end of a goal g**: the corridor g lies in, i.e. g plus every cell reachable from g
without entering a junction (a cell with three or more open moves). For a goal at the end of
a corridor this is its dead-end corridor; for a goal in a bend it is the corridor through it.

**Trapped**: an episode that *failed* and in which the explorer spent at least half of its
final ``last_n`` steps (default 500) inside the dead end of one other goal. The advice at
such a goal's corridor points into it (every expert that entered was going there) and the
goal cell itself has no expert action, so an advised explorer that wanders out is advised
back in; this measures how often that ends a task.
"""

from __future__ import annotations

import numpy as np

from app.arrays import BoolArray, IntArray
from app.domain.grid import GridDomain

TRAP_SHARE = 0.5
LAST_N = 500


def dead_end_masks(domain: GridDomain) -> BoolArray:
    """``out[g, s]``: state ``s`` lies in the dead end of goal number ``g``."""
    degree = domain.open_moves.sum(axis=1)
    out = np.zeros((len(domain.goals), domain.n_states), dtype=bool)
    for gi, goal in enumerate(domain.goals):
        out[gi, goal] = True
        stack = [goal]
        while stack:
            s = stack.pop()
            for t in domain.next_state[s].tolist():
                if not out[gi, t] and degree[t] <= 2:
                    out[gi, t] = True
                    stack.append(t)
    return out


def trap_goal(
    states: IntArray,
    success: bool,
    own_goal_index: int,
    masks: BoolArray,
    last_n: int = LAST_N,
    share: float = TRAP_SHARE,
) -> int:
    """The number of the other goal whose dead end held a failed explorer for at least
    ``share`` of its final ``last_n`` steps; -1 if it succeeded or was not trapped."""
    if success or states.size == 0:
        return -1
    tail = states[-last_n:]
    frac = np.asarray(masks[:, tail].mean(axis=1), dtype=np.float64)
    frac[own_goal_index] = -1.0
    best = int(np.argmax(frac))
    return best if frac[best] >= share else -1


def other_dead_end_share(states: IntArray, own_goal_index: int, masks: BoolArray) -> float:
    """Fraction of all steps spent in the dead end of some other goal."""
    if states.size == 0:
        return 0.0
    others = np.asarray(np.delete(masks, own_goal_index, axis=0).any(axis=0), dtype=bool)
    return float(others[states].mean())
