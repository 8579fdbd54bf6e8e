"""What the event paths read of a domain, made before the first event needs it: in the worker
thread that made or changed the domain (an admin's PUT or ingestion, another worker's change
read again, the start), not on the event loop at the first event after the change."""

from __future__ import annotations

from typing import TYPE_CHECKING

from app.domain.building import Building
from app.service.wire.encode import theta_text
from app.service.wire.events import read_move
from app.service.wire.loops import warm_building

if TYPE_CHECKING:
    from app.service.data.domains import DomainState

#: a move from the start: reading it makes the one-event reader's lists of a grid
_START_MOVE = '{{"state": [{}], "action": "N"}}'


def warm(domain: DomainState) -> None:
    """*Worker thread.* The text of theta that batch answers copy their advice from, for each
    table of the domain's current prior, and its grid's lists (each state's cell, for every
    answer; the map as tuples, for the one-event reader): each made once and kept."""
    for tables in domain.view.tables.values():
        theta_text(tables)
    grid = domain.domain
    if isinstance(grid, Building):
        warm_building()
    read_move(grid, _START_MOVE.format(", ".join(map(str, grid.cell(grid.start)))))
