"""A Python client for the advice service (HTTP and websocket only: no server code needed).

``AdvisorClient`` / ``AsyncAdvisorClient`` call the REST API and open a session's websocket;
``advisor_client.gym`` wraps a Gymnasium environment so that each step is reported to the service
and its decision lands in ``info``. A stream opened with ``binary=True`` answers with
``DecisionFrame`` arrays (the frame layout: :mod:`advisor_client.protocol`).
"""

from advisor_client.api import AdvisorError, AdvisorUnreachable, Session
from advisor_client.client import AdvisorClient, AsyncAdvisorClient, AsyncStream, Stream
from advisor_client.protocol import DecisionFrame, FrameError

__all__ = [
    "AdvisorClient",
    "AdvisorError",
    "AdvisorUnreachable",
    "AsyncAdvisorClient",
    "AsyncStream",
    "DecisionFrame",
    "FrameError",
    "Session",
    "Stream",
]
