"""The viewer's feed from a running service, read over HTTP as any client reads it.

``GET /viewer/snapshot`` (with the operator key) gives the domains, each with the version of
its prior, and the most recently active sessions; a domain's map (``GET /domains/{name}``) is
fetched when the domain is new or was PUT again, its prior (``GET /domains/{name}/prior``) when
its version changes. The feed keeps nothing else: it turns answers into the plain snapshots of
:mod:`app.viewer.state`, and a failed read fails that tick only (the pump goes on).

A map of several floors (its answer has ``floors``) is rebuilt as a
:class:`~app.domain.building.Building` from its parts (:func:`app.domain.building.domain_of`:
floors, connections, the destinations' names, the frame), checked as any map is; its cells are
``[floor, row, col]`` and its prior floors x rows x cols x 6.
"""

from __future__ import annotations

from typing import Any

import httpx
import numpy as np
import orjson

from app.domain.building import Domain, domain_of
from app.viewer.state import Destination, DomainView, Figure, SessionView, Snapshot


class RemoteFeed:
    """A :data:`~app.viewer.state.Feed` reading the service at ``http`` (a client whose base
    URL is the service's) with ``key`` (the operator key, or the admin key)."""

    def __init__(self, http: httpx.Client, key: str):
        self.http = http
        self.key = key
        # name -> (updated_at, the domain); (name, prior version) -> the view
        self._grids: dict[str, tuple[str, Domain]] = {}
        self._views: dict[str, DomainView] = {}
        self.last_tick: float | None = None  # sent with the next snapshot request

    def report_tick(self, seconds: float) -> None:
        """The viewer's hook after each tick: its duration goes to the service with the next
        snapshot request (``X-Viewer-Tick``), which counts it in its metrics."""
        self.last_tick = seconds

    def _get(
        self, path: str, params: dict[str, str] | None = None, extra: dict[str, str] | None = None
    ) -> Any:
        headers = {"X-API-Key": self.key, **(extra or {})}
        r = self.http.get(path, params=params, headers=headers)
        r.raise_for_status()
        return orjson.loads(r.content)

    def _grid(self, name: str, updated_at: str) -> Domain:
        """The domain's map: a grid, or a building (its answer has ``floors``)."""
        known = self._grids.get(name)
        if known is not None and known[0] == updated_at:
            return known[1]
        grid = domain_of(self._get(f"/domains/{name}"), name)
        self._grids[name] = (updated_at, grid)
        return grid

    def _view(self, name: str, updated_at: str, version: int) -> DomainView:
        grid = self._grid(name, updated_at)
        known = self._views.get(name)
        if known is not None and known.domain is grid and known.prior_version == version:
            return known
        prior = self._get(f"/domains/{name}/prior")
        view = DomainView(grid, theta_of(grid, prior["theta"]), version)
        self._views[name] = view
        return view

    def __call__(self) -> Snapshot:
        tick = {} if self.last_tick is None else {"X-Viewer-Tick": f"{self.last_tick:.6f}"}
        self.last_tick = None
        snap = self._get("/viewer/snapshot", extra=tick)
        domains = {
            d["name"]: self._view(d["name"], d["updated_at"], d["prior_version"])
            for d in snap["domains"]
        }
        for gone in set(self._grids) - set(domains):
            self._grids.pop(gone, None)
            self._views.pop(gone, None)
        return Snapshot(domains, [session_view(s) for s in snap["sessions"]], snap.get("kappa_max"))


def theta_of(grid: Domain, theta: list[Any]) -> np.ndarray:
    """The prior's rows x cols x 4 answer (floors x rows x cols x 6 on a building; walls
    null) as (free cells, actions), in state order."""
    rows = []
    for cell in grid.cells.tolist():
        at = theta
        for i in cell:
            at = at[i]
        rows.append(at)
    out = np.array(rows, dtype=np.float64)
    return out.reshape(grid.n_states, grid.n_actions)


def _cell(c: list[int]) -> tuple[int, ...]:
    return tuple(int(v) for v in c)


def session_view(s: dict[str, Any]) -> SessionView:
    goals = None
    if s["goals"] is not None:
        goals = [(_cell(g["goal"]), g["p"], g["ruled_out"]) for g in s["goals"]]
    beliefs = s.get("beliefs") or {"figures": [], "headline": 0, "leads_to": None}
    to = beliefs["leads_to"]
    return SessionView(
        session_id=s["session_id"],
        domain=s["domain"],
        steps=s["steps"],
        position=_cell(s["position"]),
        p_normal=s["p_normal"],
        advice_count=s["advice_count"],
        total_cost=s["total_cost"],
        kappa=s["kappa"],
        path=[_cell(c) for c in s["path"]],
        p_normal_history=s["p_normal_history"],
        advice=[(step, _cell(cell), tuple(p)) for step, cell, p in s["advice"]],
        agent_type=s["agent_type"],
        strategy=s["strategy"],
        goals=goals,
        figures=[Figure(f["name"], f["symbol"], f["p"], f["tone"]) for f in beliefs["figures"]],
        headline=beliefs["headline"],
        leads_to=None if to is None else Destination(to["goal"], _cell(to["cell"]), to["name"]),
    )
