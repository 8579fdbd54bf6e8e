"""Plain-text views of a prior over a map (for the command line and logs)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from app.domain.building import Building, Domain
from app.domain.grid import ARROWS

UNIFORM_MARK = "·"
TIE_MARK = "+"
#: a building's up and down (the compass moves are ``ARROWS``)
RIDE_MARKS = ("U", "D")


def direction_marks(domain: Domain, theta: npt.ArrayLike, tol: float = 1e-9) -> dict[int, str]:
    """Each free cell's most advised action as one character: ``^ > v <`` (and ``U D`` up
    and down in a building); ``+`` where several tie for the most; ``·`` where theta is
    uniform (no expert data); ``S``/``G`` at the start and the goals."""
    th = np.asarray(theta, dtype=np.float64)
    if th.shape != (domain.n_states, domain.n_actions):
        raise ValueError(
            f"theta of shape {th.shape} for a domain of {domain.n_states} states and "
            f"{domain.n_actions} actions"
        )
    top = th.max(axis=1, keepdims=True)
    ties = (th >= top - tol).sum(axis=1)
    glyphs = (*ARROWS, *RIDE_MARKS)
    marks: dict[int, str] = {}
    for s in range(domain.n_states):
        if ties[s] == domain.n_actions:
            marks[s] = UNIFORM_MARK
        elif ties[s] > 1:
            marks[s] = TIE_MARK
        else:
            marks[s] = glyphs[int(th[s].argmax())]
    marks[domain.start] = "S"
    for g in domain.goals:
        marks[g] = "G"
    return marks


def direction_map(domain: Domain, theta: npt.ArrayLike, tol: float = 1e-9) -> str:
    """The map with :func:`direction_marks` drawn over it; a building floor by floor, lowest
    first, each under its ordinal and name."""
    marks = direction_marks(domain, theta, tol)
    if not isinstance(domain, Building):
        return domain.render(marks)
    return "\n\n".join(
        f"floor {floor.label}\n{domain.render(f, marks)}" for f, floor in enumerate(domain.floors)
    )
