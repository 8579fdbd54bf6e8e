"""``GET /strategies``: the advising strategies a session may ask for, from their table
(:mod:`app.strategies`): the pages list them from here."""

from __future__ import annotations

from fastapi import APIRouter

from app import strategies
from app.service.schemas import StrategyPublic

router = APIRouter(tags=["sessions"])


@router.get("/strategies")
async def list_strategies() -> list[StrategyPublic]:
    """Every strategy (``strategy`` of a new session), with what it does, the parameters it
    reads (``params``: defaults, bounds), what it needs of a domain and its range of kappa."""
    return [StrategyPublic.model_validate(e.describe()) for e in strategies.STRATEGIES.values()]
