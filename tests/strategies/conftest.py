"""The service's fixtures (an app on a temporary data dir, its client and state)."""

from tests.service.conftest import client, service, settings

__all__ = ["client", "service", "settings"]
