"""HTTP only: validate, call a function of :mod:`app.service.ops`, shape the answer."""

from app.service.routes import domains, health, pages, sessions, stream

# the event routes first: they are the busiest, and routes are matched in order
ROUTERS = (sessions.router, stream.router, health.router, domains.router, pages.router)
