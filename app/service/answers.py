"""Large read answers, built off the event loop once per version and kept as bytes.

A 500 x 500 domain's prior is 5.5 MB of JSON; built on the event loop (Python lists, then
pydantic) it held every other client for 2 s. Here each big answer is built in a worker thread
once per version of what it shows, kept as bytes while that version lives (weakly keyed on the
objects that a change replaces), and every reader is served the same bytes; readers arriving
while it is being built wait for that one build (:func:`once`):

* a prior's ``theta``: per :class:`AdviceTables` (a new prior makes new tables);
* a domain's public description: per domain state and prior view (a PUT makes a new state, new
  trajectories a new view);
* the overview: made at most once per ``max_age`` seconds for each kind of reader
  (:class:`~app.service.cache.Fresh`), since it changes with every event.
"""

from __future__ import annotations

import weakref

import orjson

from app.advice.models import AdviceTables
from app.domain.building import Domain
from app.service.cache import once
from app.service.data.domains import DomainState, PriorView
from app.service.public import domain_public, theta_grid

NUMPY = orjson.OPT_SERIALIZE_NUMPY
#: orjson writes NaN as null: a wall's row (4 or 6 actions), never a free cell's
WALLS = {n: b"[" + b",".join([b"null"] * n) + b"]" for n in (4, 6)}

_theta: weakref.WeakKeyDictionary[AdviceTables, bytes] = weakref.WeakKeyDictionary()
_domains: weakref.WeakKeyDictionary[DomainState, tuple[PriorView, bytes]] = (
    weakref.WeakKeyDictionary()
)


def theta_json(grid: Domain, tables: AdviceTables) -> bytes:
    """*Worker thread.* theta as rows x cols x 4 (floors x rows x cols x 6 on a map of
    several floors), ``null`` for walls."""
    full = theta_grid(grid, tables.theta)
    return orjson.dumps(full, option=NUMPY).replace(WALLS[grid.n_actions], b"null")


async def prior(d: DomainState, agent_type: str | None) -> bytes:
    """``GET /domains/{name}/prior`` (``PriorPublic``)."""
    view = d.view
    key = view.resolve(agent_type)
    tables = view.tables[key]
    theta = _theta.get(tables)
    if theta is None:
        theta = await once(("theta", id(tables)), lambda: theta_json(d.domain, tables))
        _theta[tables] = theta
    head = orjson.dumps({
        "domain": d.name, "agent_type": agent_type, "table": key, "actions": list(d.domain.actions),
        "alpha0": view.alpha0, "trajectories": view.trajectories.get(key, 0),
    })  # fmt: skip
    return b"".join((head[:-1], b',"theta":', theta, b"}"))


async def domain(d: DomainState) -> bytes:
    """``GET /domains/{name}`` (``DomainPublic``): the map, its goals and the prior's size."""
    view = d.view
    made = _domains.get(d)
    if made is not None and made[0] is view:
        return made[1]
    text = await once(
        ("domain", id(d), id(view)), lambda: domain_public(d).model_dump_json().encode()
    )
    _domains[d] = (view, text)
    return text


async def domains(states: list[DomainState]) -> bytes:
    """``GET /domains``: every domain's answer, as a list."""
    return b"[" + b",".join([await domain(d) for d in states]) + b"]"
