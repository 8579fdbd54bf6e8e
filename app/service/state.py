"""Everything the running service holds, opened at start and closed at shutdown (the first
start also creates the default domain: :mod:`app.service.data.bootstrap`)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from app.service.answers import Fresh
from app.service.clients import Network, networks
from app.service.config import Settings
from app.service.data.bootstrap import bootstrap
from app.service.data.domains import DomainCatalog
from app.service.data.store import Store
from app.service.live.registry import Limits, SessionRegistry
from app.service.security import load_admin_key, load_operator_key


@dataclass
class ServiceState:
    settings: Settings
    store: Store
    catalog: DomainCatalog
    registry: SessionRegistry
    admin_key: str
    operator_key: str = ""
    started: float = field(default_factory=time.monotonic)
    trusted: tuple[Network, ...] = ()  # proxies whose X-Forwarded-For is believed
    fresh: Fresh = field(default_factory=Fresh)  # answers made at most once a second

    def close(self) -> None:
        self.store.close()


def open_state(settings: Settings) -> tuple[ServiceState, list[str]]:
    """Open the store, load domains, create the default one on first start. Returns the state
    and messages for the operator (shown once)."""
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    admin_key, key_message = load_admin_key(settings)
    operator_key, operator_message = load_operator_key(settings)
    store = Store(settings.db_url)
    store.create_schema()
    catalog = DomainCatalog(store, settings.max_map_cells)
    catalog.load()
    limits = Limits(
        settings.max_sessions,
        settings.max_session_memory,
        settings.client_max_sessions,
        settings.client_max_session_memory,
    )
    registry = SessionRegistry(
        limits,
        settings.session_idle_seconds,
        settings.recent_path,
        settings.recent_p_normal,
    )
    registry.retention = settings.path_retention_seconds
    messages = [m for m in (key_message, operator_message) if m]
    made = bootstrap(catalog, settings)
    if made:
        messages.append(made)
    trusted = networks(settings.trusted_proxies)
    state = ServiceState(
        settings, store, catalog, registry, admin_key, operator_key, trusted=trusted
    )
    return state, messages
