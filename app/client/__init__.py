"""A Python client for the advice service (HTTP and websocket only: no server code needed).

``AdvisorClient`` / ``AsyncAdvisorClient`` call the REST API and open a session's websocket;
``app.client.gym`` wraps a Gymnasium environment so that each step is reported to the service
and its decision lands in ``info``.
"""

from app.client.api import AdvisorError, Session
from app.client.client import AdvisorClient, AsyncAdvisorClient, AsyncStream, Stream

__all__ = [
    "AdvisorClient",
    "AdvisorError",
    "AsyncAdvisorClient",
    "AsyncStream",
    "Session",
    "Stream",
]
