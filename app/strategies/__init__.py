"""The advising strategies: one entry each, in one table (:mod:`app.strategies.table`), with
what an entry is (:mod:`app.strategies.entry`) and the forms a service runs
(:mod:`app.strategies.stream`)."""

from app.strategies.entry import AdvisorSettings, DomainData, Level, Need, Strategy
from app.strategies.table import (
    STRATEGIES,
    compiled_leads,
    get,
    make_advisor,
    names,
    register,
    unregister,
)

__all__ = [
    "STRATEGIES",
    "AdvisorSettings",
    "DomainData",
    "Level",
    "Need",
    "Strategy",
    "compiled_leads",
    "get",
    "make_advisor",
    "names",
    "register",
    "unregister",
]
