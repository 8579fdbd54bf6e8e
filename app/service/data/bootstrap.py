"""The first start with an empty database: the domain ``default`` is created from the shipped
maze and its prior learned from simulated experts (:mod:`app.domain.paths`), stored as real
trajectories with their goals (so a recount from the database reproduces the counts, and
goal-aware sessions have the goals). A marker in ``service_meta`` keeps this from happening
again, e.g. after an administrator deleted ``default`` on purpose.
"""

from __future__ import annotations

from datetime import UTC, datetime

import numpy as np

from app.domain.grid import GridDomain
from app.domain.maps import DEFAULT_MAP
from app.domain.paths import expert_trajectories
from app.service.config import Settings
from app.service.data.domains import DomainCatalog, DomainNotFound
from app.service.data.store import POOLED, Trajectory

DEFAULT_DOMAIN = "default"
BOOTSTRAPPED = "bootstrapped"


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
        experts = expert_trajectories(state.domain, rng, settings.bootstrap_experts, per_goal)
        items = [Trajectory(None, e.pairs, e.goal) for e in experts]
        state = catalog.add_trajectories(state, items)
        message = (
            f"Created domain '{DEFAULT_DOMAIN}' ({DEFAULT_MAP.name}) with a prior from "
            f"{len(items)} simulated expert trajectories ({per_goal} per goal, starting at "
            f"'{settings.bootstrap_experts}', seed {settings.bootstrap_seed})"
        )
    catalog.prepare_all(state)  # what the strategies need of it, as a PUT would
    store.set_meta(BOOTSTRAPPED, datetime.now(UTC).isoformat())
    return message
