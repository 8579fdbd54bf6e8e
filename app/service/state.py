"""Everything the running service holds, opened at start and closed at shutdown (the first
start also creates the default domain: :mod:`app.service.data.bootstrap`)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from app.service.cache import Fresh
from app.service.clients import OPERATOR, ClientKeys
from app.service.config import Settings
from app.service.data.bootstrap import bootstrap
from app.service.data.domains import DomainCatalog
from app.service.data.store import Store
from app.service.live.registry import Limits, SessionRegistry
from app.service.live.sessions import LocalSessions, Sessions
from app.service.security import load_admin_key, load_operator_key
from app.service.wire.warm import warm


@dataclass
class ServiceState:
    settings: Settings
    store: Store
    catalog: DomainCatalog
    registry: SessionRegistry
    admin_key: str
    operator_key: str = ""
    started: float = field(default_factory=time.monotonic)
    client_keys: ClientKeys = field(default_factory=ClientKeys)  # keys that are clients
    fresh: Fresh = field(default_factory=Fresh)  # answers made at most once a second
    sessions: Sessions = None  # type: ignore[assignment]  # the live sessions (below)

    def __post_init__(self) -> None:
        if self.sessions is None:  # the embedded default: the sessions of this process
            self.sessions = LocalSessions(self.registry, self.catalog)

    def close(self) -> None:
        self.store.close()


def open_state(settings: Settings) -> tuple[ServiceState, list[str]]:
    """Open the store, load domains, create the default one on first start. Returns the state
    and messages for the operator (logged once; they name where new keys are kept, never the
    keys)."""
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    admin_key, key_message = load_admin_key(settings)
    operator_key, operator_message = load_operator_key(settings)
    client_keys = quota_keys(settings, admin_key, operator_key)  # before anything is opened
    store = Store(settings.db_url, timeout=settings.database_timeout)
    store.create_schema()
    catalog = DomainCatalog(
        store, settings.max_map_cells, settings.max_domain_memory, ready=warm,
        lead_cells=settings.lead_cells,
    )  # fmt: skip
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
        settings.replay_steps,
    )
    registry.retention = settings.path_retention_seconds
    messages = [m for m in (key_message, operator_message) if m]
    made = bootstrap(catalog, settings)
    if made:
        messages.append(made)
    sessions: Sessions | None = None
    if settings.redis_url:  # sessions in Redis; this registry a cache of those it used
        from app.service.live.shared import SharedSessions

        registry.evicts = True  # within this worker's memory budget; quotas are Redis'
        registry.limits = Limits(settings.max_sessions, settings.max_session_memory)
        registry.replay_steps = 0  # the decisions kept for retries are in Redis
        sessions = SharedSessions(
            registry, catalog, settings.redis_url, settings.redis_prefix,
            settings.replay_steps,
            (settings.max_sessions, settings.max_session_memory,
             settings.client_max_sessions, settings.client_max_session_memory),
            settings.redis_timeout,
        )  # fmt: skip
    state = ServiceState(
        settings, store, catalog, registry, admin_key, operator_key,
        client_keys=client_keys, sessions=sessions,  # type: ignore[arg-type]
    )  # fmt: skip
    kept = state.sessions.restore(store)
    if kept:
        messages.append(f"Restored {kept} live sessions kept at the last shutdown")
    return state, messages


def quota_keys(settings: Settings, admin_key: str, operator_key: str) -> ClientKeys:
    """The keys that are clients of their own for the quotas: the operator key and those of
    ``ADVISOR_CLIENT_KEYS`` (ValueError for one that is the admin or the operator key: it
    would be that key, with its rights, not a client)."""
    named = [(OPERATOR, operator_key)] if operator_key else []
    for name, secret in settings.client_keys.items():
        key = secret.get_secret_value()
        if key in (admin_key, operator_key):
            raise ValueError(
                f"ADVISOR_CLIENT_KEYS: the key of client {name!r} is the admin or the operator "
                "key; give it a key of its own"
            )
        named.append((f"key {name}", key))
    return ClientKeys(named)
