"""Everything the running service holds, opened at start and closed at shutdown.

First start with an empty database: the domain ``default`` is created from the shipped maze and
its prior learned from simulated experts, stored as real trajectories (so a recount from the
database reproduces the counts). A marker in ``service_meta`` keeps this from happening again,
e.g. after an administrator deleted ``default`` on purpose.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from datetime import UTC, datetime

import numpy as np

from app.agents.experts import expert_trajectories
from app.domain.grid import GridDomain
from app.domain.maps import DEFAULT_MAP
from app.service.config import Settings
from app.service.domains import DomainCatalog, DomainNotFound
from app.service.registry import SessionRegistry
from app.service.security import load_admin_key
from app.service.store import POOLED, Store, Trajectory

DEFAULT_DOMAIN = "default"
BOOTSTRAPPED = "bootstrapped"


@dataclass
class ServiceState:
    settings: Settings
    store: Store
    catalog: DomainCatalog
    registry: SessionRegistry
    admin_key: str
    started: float = field(default_factory=time.monotonic)

    def close(self) -> None:
        self.store.close()


def open_state(settings: Settings) -> tuple[ServiceState, list[str]]:
    """Open the store, load domains, create the default one on first start. Returns the state
    and messages for the operator (shown once)."""
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    admin_key, key_message = load_admin_key(settings)
    store = Store(settings.db_url)
    store.create_schema()
    catalog = DomainCatalog(store, settings.max_map_cells)
    catalog.load()
    registry = SessionRegistry(
        settings.max_sessions,
        settings.session_idle_seconds,
        settings.recent_path,
        settings.recent_p_normal,
    )
    messages = [key_message] if key_message else []
    made = bootstrap(catalog, settings)
    if made:
        messages.append(made)
    return ServiceState(settings, store, catalog, registry, admin_key), messages


def bootstrap(catalog: DomainCatalog, settings: Settings) -> str | None:
    """On first start: the default domain with a prior from simulated experts."""
    store = catalog.store
    if store.get_meta(BOOTSTRAPPED) is not None:
        return None
    try:
        state = catalog.get(DEFAULT_DOMAIN)
    except DomainNotFound:
        domain = GridDomain.from_file(DEFAULT_MAP, name=DEFAULT_DOMAIN)
        state, _, _ = catalog.put(DEFAULT_DOMAIN, domain, settings.bootstrap_alpha0)
    message = None
    if state.view.trajectories.get(POOLED, 0) == 0:  # also finishes a first start cut short
        per_goal = settings.bootstrap_per_goal
        rng = np.random.default_rng(settings.bootstrap_seed)
        trajs = expert_trajectories(state.domain, rng, settings.bootstrap_experts, per_goal)
        goals = [g for g in state.domain.goals for _ in range(per_goal)]  # the order they come in
        items = [Trajectory(None, p, g) for p, g in zip(trajs, goals, strict=True)]
        catalog.add_trajectories(state, items)
        message = (
            f"Created domain '{DEFAULT_DOMAIN}' ({DEFAULT_MAP.name}) with a prior from "
            f"{len(items)} simulated expert trajectories ({per_goal} per goal, starting at "
            f"'{settings.bootstrap_experts}', seed {settings.bootstrap_seed})"
        )
    store.set_meta(BOOTSTRAPPED, datetime.now(UTC).isoformat())
    return message
