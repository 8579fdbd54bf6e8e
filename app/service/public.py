"""Internal state shaped into the public response models (no tokens ever leave here)."""

from __future__ import annotations

from typing import Any

import numpy as np

from app import strategies
from app.advice.advisor import Decision
from app.arrays import FloatArray
from app.domain.building import Building, Domain
from app.service.data.domains import DomainState
from app.service.data.store import POOLED
from app.service.live.registry import Aggregate, LiveSession, SessionSnapshot
from app.service.schemas import (
    ConnectionPublic,
    DecisionPublic,
    DomainPublic,
    FloorPublic,
    GoalBelief,
    PriorPublic,
    SessionCreated,
    SessionPublic,
)
from app.service.wire.encode import advice_dict, decision_dict


def domain_public(d: DomainState) -> DomainPublic:
    g = d.domain
    rows, cols = g.shape[-2:]
    floors = connections = None
    if isinstance(g, Building):
        floors = [
            FloorPublic(index=i, ordinal=f.ordinal, name=f.name, elevation=f.elevation,
                        map=list(f.rows))
            for i, f in enumerate(g.floors)
        ]  # fmt: skip
        connections = [
            ConnectionPublic(
                kind=c.kind, name=c.name, cost=c.cost, stops=[list(x) for x in c.stops]
            )
            for c in g.connections
        ]
    return DomainPublic(
        name=d.name, rows=rows, cols=cols,
        map=list(g.floors[0].rows if isinstance(g, Building) else g.rows_text),
        floors=floors, connections=connections,
        resolution=g.frame.resolution if g.frame else None,
        origin=list(g.frame.origin) if g.frame else None, start=list(g.cell(g.start)),
        goals=[list(g.cell(s)) for s in g.goals],
        goal_names=list(g.goal_names or (None,) * len(g.goals)), actions=list(g.actions),
        alpha0=d.view.alpha0, n_states=g.n_states,
        trajectories=d.view.trajectories.get(POOLED, 0),
        agent_types=sorted(k for k in d.view.tables if k != POOLED),
        created_at=d.created_at, updated_at=d.updated_at,
    )  # fmt: skip


def prior_public(d: DomainState, agent_type: str | None) -> PriorPublic:
    view = d.view
    key = view.resolve(agent_type)
    g = d.domain
    grid = theta_grid(g, view.tables[key].theta)
    return PriorPublic(
        domain=d.name, agent_type=agent_type, table=key, actions=list(g.actions),
        alpha0=view.alpha0, trajectories=view.trajectories.get(key, 0), theta=_walls(grid.tolist()),
    )  # fmt: skip


def theta_grid(domain: Domain, theta: FloatArray) -> FloatArray:
    """theta (states x actions) as rows x cols x actions (floors x rows x cols x actions on
    a map of several floors), NaN on walls."""
    grid = np.full((*domain.shape, domain.n_actions), np.nan)
    grid[tuple(domain.cells.T)] = theta
    return grid


def _walls(rows: Any) -> Any:
    """A wall's row (NaNs) as one None, at any depth."""
    if not isinstance(rows[0], list):
        return None if rows[0] != rows[0] else rows
    return [_walls(r) for r in rows]


def decision_public(
    d: Decision, domain: Domain, leads_to: dict[str, Any] | None = None
) -> DecisionPublic:
    out = decision_dict(d, domain)
    if leads_to is not None:
        out["leads_to"] = leads_to
    return DecisionPublic.model_validate(out)


def decision_leads_to(s: LiveSession, d: Decision) -> dict[str, Any] | None:
    """The destination a decision of ``s`` leads to, as its strategy's entry says (None: the
    decision does not advise, or the strategy's advice leads to no destination)."""
    entry = strategies.STRATEGIES.get(s.advisor.strategy)
    if not d.advise or entry is None or entry.leads_to is None:
        return None
    goal = entry.leads_to(s.advisor)
    grid = s.domain.domain
    if goal is None or not 0 <= goal < len(grid.goals):
        return None
    name = grid.goal_names[goal] if grid.goal_names is not None else None
    return destination_dict(goal, grid.cell(grid.goals[goal]), name)


def session_created(s: LiveSession, decision: Decision) -> SessionCreated:
    return SessionCreated(
        session_id=s.id, token=s.token, domain=s.domain.name, agent_type=s.agent_type,
        prior_table=s.table_key, kappa=s.advisor.kappa, window=s.advisor.window,
        strategy=s.advisor.strategy, params=s.advisor.params(),
        decision=decision_public(decision, s.domain.domain, decision_leads_to(s, decision)),
    )  # fmt: skip


def session_public(s: SessionSnapshot) -> SessionPublic:
    return SessionPublic(
        session_id=s.id, domain=s.domain, agent_type=s.agent_type, prior_table=s.table_key,
        kappa=s.kappa, window=s.window, strategy=s.strategy, params=s.params, goals=_goals(s),
        steps=s.steps,
        position=s.position, floor=s.floor, p_normal=s.p_normal,
        advice_count=s.advice_count, total_cost=s.total_cost, benefit=s.benefit,
        advice_per_100=s.advice_per_100, idle_seconds=s.idle_seconds, created_at=s.created_at,
        muted=s.muted, budget=_budget(s), beliefs=beliefs_dict(s),
    )  # fmt: skip


def _session_figures(s: SessionSnapshot) -> dict[str, Any]:
    """What the overview and the viewer's feed show of every live session, as plain data
    (written by orjson: an overview of 1,000 sessions is not built as pydantic models)."""
    return {
        "session_id": s.id, "domain": s.domain, "agent_type": s.agent_type, "kappa": s.kappa,
        "strategy": s.strategy, "goals": _goal_dicts(s), "steps": s.steps,
        "position": s.position, "p_normal": s.p_normal, "advice_count": s.advice_count,
        "total_cost": s.total_cost, "advice_per_100": s.advice_per_100, "path": s.path,
        "p_normal_history": s.p_history, "muted": s.muted, "budget": _budget(s),
        "beliefs": beliefs_dict(s),
    } | ({"floor": s.floor} if s.floor is not None else {})  # fmt: skip


def overview_session(s: SessionSnapshot) -> dict[str, Any]:
    """A live session as the overview lists it (``OverviewSession``)."""
    last = None
    if s.advice:
        step, cell, advice = s.advice[-1]
        last = {"step": step, "state": cell, "advice": advice_dict(advice)}
    return _session_figures(s) | {"last_advice": last}


def viewer_session(s: SessionSnapshot) -> dict[str, Any]:
    """A live session as the viewer's feed gives it (``ViewerSession``)."""
    return _session_figures(s) | {"advice": s.advice}


def beliefs_dict(s: SessionSnapshot) -> dict[str, Any] | None:
    """What the session's advisor believes (``BeliefsPublic``)."""
    b = s.beliefs
    if b is None:
        return None
    figures = [{"name": f.name, "symbol": f.symbol, "p": f.p, "tone": f.tone} for f in b.figures]
    leads = None if s.leads_to is None else destination_dict(*s.leads_to)
    return {"figures": figures, "headline": b.headline, "leads_to": leads}


def destination_dict(goal: int, cell: tuple[int, ...], name: str | None) -> dict[str, Any]:
    """A destination (``DestinationPublic``)."""
    return {"goal": goal, "cell": cell, "name": name}


def _budget(s: SessionSnapshot) -> dict[str, int | None] | None:
    if s.budget is None:
        return None
    left, minute = s.advice_left
    return {
        "total": s.budget.total, "per_minute": s.budget.per_minute, "left": left,
        "left_this_minute": minute,
    }  # fmt: skip


def _goals(s: SessionSnapshot) -> list[GoalBelief] | None:
    if s.goals is None:
        return None
    return [GoalBelief(goal=cell, p=p, ruled_out=out) for cell, p, out in s.goals]


def _goal_dicts(s: SessionSnapshot) -> list[dict[str, Any]] | None:
    if s.goals is None:
        return None
    return [{"goal": cell, "p": p, "ruled_out": out} for cell, p, out in s.goals]


def overview_domain(d: DomainState, agg: Aggregate | None) -> dict[str, Any]:
    """A domain as the overview shows it (``OverviewDomain``): its size, its data, and
    figures over its live sessions (no session's own)."""
    rows, cols = d.domain.shape[-2:]
    agg = agg or Aggregate()
    per_100 = 100.0 * agg.advice / agg.decisions if agg.decisions else 0.0
    return {
        "name": d.name, "rows": rows, "cols": cols, "n_states": d.domain.n_states,
        "trajectories": d.view.trajectories.get(POOLED, 0), "sessions": agg.sessions,
        "steps": agg.steps, "advice_count": agg.advice, "advice_per_100": per_100,
        "looking_lost": agg.looking_lost,
    }  # fmt: skip
