"""HTTP only: validate, call a function of :mod:`app.service.ops`, shape the answer."""

from app.service.routes import (
    apidocs,
    domains,
    health,
    pages,
    sessions,
    strategies,
    stream,
    viewer,
)

# the event routes first: they are the busiest, and routes are matched in order
ROUTERS = (
    sessions.router, stream.router, health.router, domains.router, strategies.router,
    pages.router, viewer.router, apidocs.router,
)  # fmt: skip
