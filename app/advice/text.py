"""Plain-text views of a prior over a map (for the command line and logs)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from app.domain.grid import ARROWS, N_ACTIONS, GridDomain

UNIFORM_MARK = "·"
TIE_MARK = "+"


def direction_map(domain: GridDomain, theta: npt.ArrayLike, tol: float = 1e-9) -> str:
    """The map with each free cell's most advised direction: ``^ > v <``; ``+`` where several
    directions tie for the most; ``·`` where theta is uniform (no expert data); ``S``/``G`` kept.
    """
    th = np.asarray(theta, dtype=np.float64)
    top = th.max(axis=1, keepdims=True)
    ties = (th >= top - tol).sum(axis=1)
    marks: dict[int, str] = {}
    for s in range(domain.n_states):
        if ties[s] == N_ACTIONS:
            marks[s] = UNIFORM_MARK
        elif ties[s] > 1:
            marks[s] = TIE_MARK
        else:
            marks[s] = ARROWS[int(th[s].argmax())]
    marks[domain.start] = "S"
    for g in domain.goals:
        marks[g] = "G"
    return domain.render(marks)
