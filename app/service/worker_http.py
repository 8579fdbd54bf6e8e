"""The HTTP protocol of each worker when ``serve`` runs several (uvicorn's ``http`` option as
an import string, since each worker is a new interpreter): :mod:`app.service.guard`'s bounds,
read from the ``ADVISOR_*`` settings the workers inherit. Imported by the workers only."""

from __future__ import annotations

from app.service.config import Settings
from app.service.guard import connection_cap, guarded_http

_s = Settings()
WorkerHttp = guarded_http(
    _s.max_header_bytes, _s.header_timeout, _s.body_timeout,
    connection_cap(_s.max_connections, _s.log_format),
)  # fmt: skip
