"""A Python client for the advice service (HTTP and websocket only: no server code needed).

``AdvisorClient`` / ``AsyncAdvisorClient`` call the REST API and open a session's websocket;
``app.client.gym`` wraps a Gymnasium environment so that each step is reported to the service
and its decision lands in ``info``. A stream opened with ``binary=True`` answers with
``DecisionFrame`` arrays (the frame layout: :mod:`app.protocol`).
"""

from app.client.api import AdvisorError, Session
from app.client.client import AdvisorClient, AsyncAdvisorClient, AsyncStream, Stream
from app.protocol import DecisionFrame, FrameError

__all__ = [
    "AdvisorClient",
    "AdvisorError",
    "AsyncAdvisorClient",
    "AsyncStream",
    "DecisionFrame",
    "FrameError",
    "Session",
    "Stream",
]
